"""Output folders: refused before any work when unusable; a build replaces its own earlier files and never the user's,
and only when it completes: a failed, killed or terminated build leaves the previous one as it was."""

from __future__ import annotations

import json
import os
import signal

import pytest

from kosmap.mapping.config import load_config
from kosmap.mapping.build import BUILD_FILES, build
from kosmap.mapping.runtime.outdir import MANIFEST, OutputError, check_out, claim, commit, discard
from tests.frontend.synthetic_log import room_laser_log
from kosmap.tools.cli import main

SETS = ["build.depth_rate=0"]


@pytest.fixture(scope="module")
def laser_log(tmp_path_factory):
    """2.5 s of the simulated room, its laser, odometry and gyro only (a build of it takes about a second)."""
    return room_laser_log(tmp_path_factory.mktemp("outdir"), seed=2, duration=2.5)


def _snapshot(d):
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def test_an_unusable_out_is_refused_in_one_line(tmp_path, monkeypatch):
    f = tmp_path / "afile"
    f.write_text("mine")
    for bad, msg in (("", "is empty"), (" ", "is empty"), (f, "is a file"), (f / "sub", "is a file, so no folder")):
        with pytest.raises(OutputError, match=msg) as e:
            check_out(bad)
        assert "\n" not in str(e.value)
    assert check_out(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checking makes nothing
    monkeypatch.setattr(os, "access", lambda p, mode: False)  # (root may write anywhere: the check is what is tested)
    with pytest.raises(OutputError, match=f"no permission to write in {tmp_path}"):
        check_out(tmp_path / "new")


def test_claim_refuses_to_replace_files_no_build_wrote(tmp_path):
    (tmp_path / "ground_truth.tum").write_text("0 0 0 0 0 0 0 1\n")
    (tmp_path / "map_office.png").write_bytes(b"png")
    (tmp_path / "notes.txt").write_text("mine")
    before = _snapshot(tmp_path)
    with pytest.raises(OutputError, match=r"holds ground_truth.tum, map_office.png, which `kosmap build` would overwrite"):
        claim(tmp_path, BUILD_FILES)
    assert _snapshot(tmp_path) == before


def test_a_run_replaces_the_previous_builds_files_only_when_it_commits(tmp_path):
    for name in ("map_laser.png", "metrics.json", "report.md", "notes.txt", "map_mine.png"):
        (tmp_path / name).write_text(name)
    (tmp_path / MANIFEST).write_text(json.dumps({"kosmap": "build", "files": ["map_laser.png", "metrics.json", "report.md"]}))
    (tmp_path / ".kosmap-spill-x1y2").mkdir()  # a killed build of an earlier version's leftovers
    (tmp_path / ".kosmap-spill-x1y2" / "scans.bin").write_bytes(b"x")
    (tmp_path / ".kosmap-staging-999999999-abc").mkdir()  # a staging folder of a process that is gone
    with pytest.raises(OutputError, match="holds map_mine.png,"):
        claim(tmp_path, BUILD_FILES)  # map_mine.png matches map_*.png but the manifest does not list it
    (tmp_path / "map_mine.png").rename(tmp_path / "mine.png")
    before = _snapshot(tmp_path)
    stage = claim(tmp_path, BUILD_FILES)
    assert _snapshot(tmp_path) == before  # nothing replaced yet
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_dir()) == [stage.dir.name]  # leftovers gone
    (stage.dir / "metrics.json").write_text("new")
    (stage.dir / "map_kos_obstacle.png").write_text("new map")
    commit(stage)
    assert sorted(p.name for p in tmp_path.iterdir()) == [MANIFEST, "map_kos_obstacle.png", "metrics.json", "mine.png",
                                                          "notes.txt"]  # map_laser.png, report.md: the old build's
    assert (tmp_path / "metrics.json").read_text() == "new" and (tmp_path / "mine.png").read_text() == "map_mine.png"
    assert json.loads((tmp_path / MANIFEST).read_text()) == {"kosmap": "build", "files": ["map_kos_obstacle.png", "metrics.json"]}


@pytest.mark.parametrize("entry", ["writing", "build"])
def test_ctrl_c_right_after_the_staging_folder_is_made_leaves_no_trace(entry, laser_log, tmp_path, monkeypatch):
    """A Ctrl-C that lands in `claim` after the staging folder exists, before the run holds it: the folder goes,
    the previous build's files are as they were."""
    import tempfile

    from kosmap.mapping.runtime import outdir

    out = tmp_path / "out"
    build(laser_log, out, load_config(None, SETS), workers=0, report=False)
    before = _snapshot(out)
    made, mkdtemp = [], tempfile.mkdtemp

    def mkdtemp_then_interrupted(**kw):
        made.append(mkdtemp(**kw))
        raise KeyboardInterrupt

    monkeypatch.setattr(outdir.tempfile, "mkdtemp", mkdtemp_then_interrupted)
    with pytest.raises(KeyboardInterrupt):
        if entry == "build":
            build(laser_log, out, load_config(None, SETS), workers=0, report=False)
        else:
            with outdir.writing(out, BUILD_FILES):
                pass
    assert made and made[0].startswith(str(out / ".kosmap-staging-"))  # the folder was made, then removed
    assert [p.name for p in out.iterdir() if p.is_dir()] == [] and _snapshot(out) == before


def test_a_folder_of_a_build_before_manifests_is_still_a_builds(tmp_path):
    (tmp_path / "metrics.json").write_text(json.dumps({"kosmap": "build"}))
    (tmp_path / "trajectory_kos.tum").write_text("")
    (tmp_path / "notes.txt").write_text("mine")
    commit(claim(tmp_path, BUILD_FILES))  # a run that wrote nothing of those names: the old build's go
    assert sorted(p.name for p in tmp_path.iterdir()) == [MANIFEST, "notes.txt"]


@pytest.mark.slow
def test_a_build_replaces_its_own_files_keeps_the_users_and_refuses_to_overwrite_theirs(laser_log, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    res = build(laser_log, out, load_config(None, SETS), workers=0)
    listed = set(json.loads((out / MANIFEST).read_text())["files"])
    assert listed == {p.name for p in out.iterdir() if p.is_file()} - {"notes.txt", MANIFEST}
    assert {"metrics.json", "report.html", "map_laser.png", "config.toml", "trajectory_laser.tum"} <= listed
    assert res.metrics["timing"]["total_s"] > 0
    build(laser_log, out, load_config(None, SETS), workers=0)  # again: its own files replaced
    assert (out / "notes.txt").read_text() == "mine" and (out / "map_laser.png").is_file()

    other = tmp_path / "other"
    other.mkdir()
    (other / "ground_truth.tum").write_text("0 1 2 3 0 0 0 1\n")
    before = _snapshot(other)
    assert main(["build", str(laser_log), "--out", str(other), "--set", SETS[0], "-j", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("kosmap: error: --out") and "ground_truth.tum" in err and "\n" not in err
    assert _snapshot(other) == before and [p.name for p in other.iterdir()] == ["ground_truth.tum"]


@pytest.mark.slow
def test_a_failed_build_leaves_the_previous_one_as_it_was_and_a_failed_first_one_no_folder(laser_log, tmp_path):
    def fail(_p):
        raise RuntimeError("disk on fire")

    out = tmp_path / "new" / "out"
    with pytest.raises(RuntimeError, match="disk on fire"):
        build(laser_log, out, load_config(None, SETS), workers=0, on_progress=fail)
    assert list(tmp_path.iterdir()) == []  # neither --out nor the folder made for it
    build(laser_log, out, load_config(None, SETS), workers=0)  # a good result
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert "map_laser.png" in before and MANIFEST in before
    with pytest.raises(RuntimeError, match="disk on fire"):
        build(laser_log, out, load_config(None, SETS), workers=0, on_progress=fail)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # byte for byte, and no staging folder left


@pytest.mark.slow
def test_sigterm_stops_a_build_and_removes_what_it_wrote(laser_log, tmp_path, monkeypatch, capsys):
    import kosmap.mapping.build.run as run

    warm = run.warm_grid

    def terminate_now():  # SIGTERM arrives mid-build, once the temporary folder exists
        warm()
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(run, "warm_grid", terminate_now)
    out = tmp_path / "out"
    (tmp_path / "out").mkdir()
    (out / "notes.txt").write_text("mine")
    before = signal.getsignal(signal.SIGTERM)
    assert main(["build", str(laser_log), "--out", str(out), "--set", SETS[0], "-j", "2"]) == 128 + signal.SIGTERM
    assert "kosmap: terminated" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["notes.txt"]  # no spill folder, no config, no maps
    assert signal.getsignal(signal.SIGTERM) == before  # main() put the handler back


def test_every_command_that_writes_a_folder_refuses_an_unusable_out_first(laser_log, tmp_path, capsys):
    import numpy as np

    from kosmap.mapping.grid import OccupancyGrid
    from kosmap.mapping.mapio import write_map_server

    f = tmp_path / "afile"
    f.write_text("mine")
    grid = OccupancyGrid(np.full((20, 20), -1, np.int8), 0.05, (0.0, 0.0, 0.0))
    a = write_map_server(grid, tmp_path / "a.yaml", ".png")
    for argv in (["scan", str(laser_log)], ["compare", str(a), str(a)], ["build", str(laser_log)],
                 ["slam", str(laser_log)], ["planes", str(laser_log)]):
        assert main(argv + ["--out", str(f / "sub")]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err == f"kosmap: error: --out {f / 'sub'}: {f} is a file, so no folder can be made in it; give another folder"
    assert f.read_text() == "mine"


def test_the_files_of_a_build_killed_outright_are_the_next_builds(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / MANIFEST).write_text(json.dumps({"kosmap": "build", "in_progress": True}))  # (as builds writing in
    for name in ("config.toml", "trajectory_kos.tum", "stats.csv", "stats.csv.partial"):  # place left it)
        (tmp_path / name).write_text(name)
    stage = claim(tmp_path, BUILD_FILES)  # the next build takes them as a build's
    assert not (tmp_path / "stats.csv.partial").exists()
    commit(stage)
    assert sorted(p.name for p in tmp_path.iterdir()) == [MANIFEST, "notes.txt"]
    discard(claim(tmp_path / "a" / "b", BUILD_FILES))  # a run that made its folder and failed: the folders go
    assert sorted(p.name for p in tmp_path.iterdir()) == [MANIFEST, "notes.txt"]


def test_a_file_the_build_reads_is_never_one_it_replaces(tmp_path):
    cfg = tmp_path / "config.toml"
    cfg.write_text("[build]\n")
    (tmp_path / MANIFEST).write_text(json.dumps({"kosmap": "build", "files": ["config.toml"]}))
    with pytest.raises(OutputError, match=r"config.toml is read by this run but is one of the files it writes"):
        claim(tmp_path, BUILD_FILES, inputs=(tmp_path / "sub" / ".." / "config.toml",))
    assert cfg.read_text() == "[build]\n"


def test_out_given_empty_or_as_a_dangling_link_is_refused(laser_log, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["build", str(laser_log), "--out", ""]) == 2
    assert "is empty" in capsys.readouterr().err and list(tmp_path.iterdir()) == []
    (tmp_path / "dl").symlink_to(tmp_path / "gone")
    with pytest.raises(OutputError, match="is a link to .*gone, which does not exist"):
        check_out(tmp_path / "dl")


def test_another_commands_folder_is_named_in_the_refusal(tmp_path):
    (tmp_path / "metrics.json").write_text(json.dumps({"source": "laser"}))  # as `kosmap slam` writes it
    (tmp_path / "config.toml").write_text("")
    with pytest.raises(OutputError, match=r"holds config.toml, metrics.json, .*another kosmap command's folder.*move them"):
        claim(tmp_path, BUILD_FILES)


def test_slam_scan_and_compare_keep_to_their_own_files_and_folders(laser_log, tmp_path, capsys):
    from kosmap.tools.commands.compare import COMPARE_FILES
    from kosmap.tools.commands.slam import SLAM_FILES

    out = tmp_path / "slam"
    out.mkdir()
    (out / "map.png").write_bytes(b"my own picture")
    assert main(["slam", str(laser_log), "--out", str(out)]) == 2  # would overwrite the user's map.png
    assert "map.png, which `kosmap slam` would overwrite" in capsys.readouterr().err
    assert (out / "map.png").read_bytes() == b"my own picture" and len(list(out.iterdir())) == 1
    (out / "map.png").unlink()
    assert main(["slam", str(laser_log), "--out", str(out)]) == 0
    assert main(["slam", str(laser_log), "--out", str(out)]) == 0  # its own earlier files: replaced
    assert set(json.loads((out / MANIFEST).read_text())["files"]) == set(SLAM_FILES)
    assert main(["compare", str(out / "map.yaml"), str(out / "map.yaml"), "--out", str(out)]) == 2  # slam's folder
    assert "holds the results of `kosmap slam`" in capsys.readouterr().err

    cmp = tmp_path / "cmp"
    assert main(["compare", str(out / "map.yaml"), str(out / "map.yaml"), "--out", str(cmp)]) == 0
    assert json.loads((cmp / "compare.json").read_text())["tolerances"]["0.10"]["f1"] == pytest.approx(1.0)
    assert set(json.loads((cmp / MANIFEST).read_text())["files"]) == set(COMPARE_FILES)
    assert main(["build", str(laser_log), "--out", str(cmp), "-j", "0", "--set", SETS[0]]) == 2
    assert "holds the results of `kosmap compare`" in capsys.readouterr().err
