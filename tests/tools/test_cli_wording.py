"""What `kosmap build` and `kosmap slam` tell the user matches what they do: the logs build reads, its
--blueprint-scale for a plain-image blueprint (which the error about one asks for), every file slam writes."""

from __future__ import annotations

import json

import pytest

from tests.frontend.synthetic_log import write_mcap
from tests.mapping.synthetic_laser import make_log, records
from kosmap.tools.cli import main


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    return write_mcap(records(make_log(seed=1, laps=1)), tmp_path_factory.mktemp("wording") / "ring.mcap")


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A short room log and its blueprint as a plain PNG (5 cm a pixel) beside its map_server YAML."""
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    d = tmp_path_factory.mktemp("wording_room")
    w = load_world("room")
    simulate(w, SimConfig(seed=2, duration=1.5), d / "room.mcap")
    yaml_path = write_map_server(w.blueprint(0.05), d / "bp.yaml", ".png")
    return d / "room.mcap", yaml_path, yaml_path.with_suffix(".png")


def _help(capsys, monkeypatch, command: str) -> str:
    monkeypatch.setenv("COLUMNS", "400")  # one help line per option: nothing wrapped mid-phrase
    assert main([command, "--help"]) == 0
    return " ".join(capsys.readouterr().out.split())


def _one_line_error(capsys, argv) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("kosmap: error: ") and err.count("\n") == 1, err
    return err


def test_build_help_names_carmen_logs_and_the_blueprint_scale(capsys, monkeypatch):
    text = _help(capsys, monkeypatch, "build")
    assert ".mcap (ROS 2) or .bag (ROS 1) with depth images and/or a laser, or .clf (CARMEN: laser and odometry)" in text
    assert "--blueprint-scale" in text and "Metres per pixel of a plain-image blueprint" in text


def test_build_reads_a_carmen_log(tmp_path, capsys):
    """What the help now says: a .clf builds (the laser map alone)."""
    clf = tmp_path / "ring.clf"
    log = make_log(seed=1, laps=1)
    t0 = log.stamps_ns[0]
    with clf.open("w") as f:
        for ts, scan, o in zip(log.stamps_ns[:200], log.scans[:200], log.odom[:200]):
            t = (ts - t0) * 1e-9 + 1000.0
            r = " ".join(f"{v:.3f}" for v in scan.ranges)
            f.write(f"ODOM {o[0]:.4f} {o[1]:.4f} {o[2]:.5f} 0 0 0 {t:.6f} robot {t:.6f}\n")
            f.write(f"FLASER {len(scan.ranges)} {r} {o[0]:.4f} {o[1]:.4f} {o[2]:.5f} {o[0]:.4f} {o[1]:.4f} {o[2]:.5f} "
                    f"{t:.6f} robot {t:.6f}\n")
    out = tmp_path / "out"
    assert main(["build", str(clf), "--out", str(out), "--workers", "0", "--quiet"]) == 0, capsys.readouterr().err
    assert set(json.loads((out / "metrics.json").read_text())["maps"]) == {"laser"}


def test_a_plain_image_blueprint_without_its_scale_asks_for_the_option_build_has(room, tmp_path, capsys, monkeypatch):
    log, _, png = room
    err = _one_line_error(capsys, ["build", str(log), "--blueprint", str(png), "--out", str(tmp_path / "o")])
    assert f"blueprint {png} is a plain image: give its scale in metres per pixel (--blueprint-scale)" in err
    assert "--blueprint-scale" in _help(capsys, monkeypatch, "build")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, words", [
    (["--blueprint-scale", "0.05"], "--blueprint-scale belongs to --blueprint (a plain image's metres per pixel)"),
    (["--blueprint", "YAML", "--blueprint-scale", "0.05"], "is a map_server YAML with its own resolution; drop the blueprint scale"),
    (["--blueprint", "PNG", "--blueprint-scale", "0"], "blueprint scale 0.0 must be a positive number of metres per pixel"),
])
def test_a_blueprint_scale_that_cannot_apply_is_one_line(room, tmp_path, capsys, args, words):
    log, yaml_path, png = room
    argv = ["build", str(log), "--out", str(tmp_path / "o")] + [
        {"YAML": str(yaml_path), "PNG": str(png)}.get(a, a) for a in args]
    assert words in _one_line_error(capsys, argv)
    assert not (tmp_path / "o").exists()  # refused before any work


@pytest.mark.slow
def test_build_compares_with_a_plain_image_blueprint_given_its_scale(room, tmp_path, capsys):
    log, _, png = room
    out = tmp_path / "out"
    code = main(["build", str(log), "--out", str(out), "--blueprint", str(png), "--blueprint-scale", "0.05",
                 "--workers", "0", "--set", "build.mcap_planes_period=0"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    m = json.loads((out / "metrics.json").read_text())
    assert m["sources"]["blueprint"] == str(png) and m["sources"]["blueprint_scale"] == 0.05
    assert {"kos_obstacle_vs_blueprint", "laser_vs_blueprint"} <= set(m["comparisons"])
    assert m["comparisons"]["laser_vs_blueprint"]["tolerances"]["0.10"]["precision"] > 0.5
    assert "F1 at 0.10 m  laser vs blueprint " in cap.out
    assert f"Blueprint: {png} (0.05 m per pixel)." in (out / "report.md").read_text()


def test_slam_lists_every_file_it_wrote(ring, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["slam", str(ring), "--out", str(out)]) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("wrote ")][-1]
    names = line[len("wrote "):].rsplit(" to ", 1)[0].split(", ")
    assert names == ["trajectory.tum", "keyframes.tum", "graph.g2o", "metrics.json", "map.png", "map.pgm", "map.yaml",
                     "config.toml"]
    assert sorted(p.name for p in out.iterdir()) == sorted(names + [".kosmap-outputs"])
