"""Stopping a run: Ctrl-C and SIGTERM are honoured from the moment `kosmap` starts, with one line; a run stopped,
killed outright or failed at any moment leaves the previous complete build byte for byte as it was, and a first
run leaves no folder."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kosmap.mapping.build import BUILD_FILES, BuildInterrupted, build
from kosmap.mapping.config import load_config
from kosmap.mapping.runtime import outdir
from kosmap.mapping.runtime.outdir import BACKUP_PREFIX, MANIFEST, STAGE_PREFIX, claim
from kosmap.tools.cli import main
from tests.frontend.synthetic_log import room_laser_log

SETS = ["build.depth_rate=0"]
KOSMAP = Path(sys.executable).with_name("kosmap")


@pytest.fixture(scope="module")
def laser_log(tmp_path_factory):
    """3 s of the simulated room, its laser, odometry and gyro only (a build of it takes about a second)."""
    return room_laser_log(tmp_path_factory.mktemp("interrupts"), seed=3, duration=3.0)


@pytest.fixture(scope="module")
def previous(laser_log, tmp_path_factory):
    """A complete build to be kept: (its folder, its files' bytes)."""
    out = tmp_path_factory.mktemp("prev") / "out"
    build(laser_log, out, load_config(None, SETS), workers=0)
    (out / "notes.txt").write_text("the user's")
    return out, _snapshot(out)


def _snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def _leftovers(d: Path) -> list[Path]:
    """Staging folders, or a previous run's files set aside, left in `d`."""
    return list(d.glob(STAGE_PREFIX + "*")) + list(d.glob(BACKUP_PREFIX + "*"))


def _catches(pid: int, sig: int) -> bool:
    """Whether process `pid` has a handler for `sig` now (/proc/PID/status SigCgt)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    except FileNotFoundError:
        pass
    return False


def _start(args: list[str], ignore_sigint: bool = False) -> subprocess.Popen:
    cmd = [str(KOSMAP)] if KOSMAP.exists() else [sys.executable, "-m", "kosmap.tools.cli"]
    pre = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None
    return subprocess.Popen(cmd + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=pre)


def _wait_for(p: subprocess.Popen, ready, what: str) -> None:
    t = time.monotonic()
    while not ready():
        assert p.poll() is None, f"kosmap ended before {what}: {p.stderr.read()}"
        assert time.monotonic() - t < 120, f"never reached {what}"
        time.sleep(0.002)


def _staged(out: Path, name: str | None = None):
    return lambda: any((s / name).exists() if name else True for s in out.glob(STAGE_PREFIX + "*"))


needs_proc = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc to see a handler appear")


@needs_proc
@pytest.mark.slow
@pytest.mark.parametrize("ignored", [True, False], ids=["started-with-sigint-ignored", "default"])
def test_ctrl_c_from_the_first_instant_stops_a_build_with_one_line_and_no_folder(laser_log, tmp_path, ignored):
    """SIGINT as soon as kosmap's own handlers are in place (its libraries not yet imported): exit 130, one line,
    no --out made. A shell starts a background job with SIGINT ignored; kosmap honours it all the same (it used to
    be ignored until reading began, and the build ran to the end with exit 0)."""
    out = tmp_path / "new" / "out"
    p = _start(["build", str(laser_log), "--out", str(out), "--set", SETS[0], "-j", "0", "-q"], ignore_sigint=ignored)
    _wait_for(p, lambda: _catches(p.pid, signal.SIGTERM) and _catches(p.pid, signal.SIGINT), "its handlers")
    p.send_signal(signal.SIGINT)
    err = p.communicate(timeout=120)[1]
    assert p.returncode == 130 and err == "kosmap: interrupted\n", err
    assert list(tmp_path.iterdir()) == []


@needs_proc
@pytest.mark.slow
@pytest.mark.parametrize("sig, moment", [
    (signal.SIGTERM, "start"),  # handlers in place, libraries loading
    (signal.SIGINT, "staging"),  # the staging folder made: reading the log
    (signal.SIGKILL, "staging"),
    (signal.SIGTERM, "metrics"),  # metrics.json staged: the report, then the move into place
])
def test_a_rerun_stopped_or_killed_at_any_moment_keeps_the_previous_build(laser_log, previous, sig, moment):
    out, before = previous
    p = _start(["build", str(laser_log), "--out", str(out), "--set", SETS[0], "-j", "0", "-q"])
    if moment == "start":
        _wait_for(p, lambda: _catches(p.pid, signal.SIGTERM), "its handlers")
    else:
        _wait_for(p, _staged(out, None if moment == "staging" else "metrics.json"), f"a staged {moment}")
    p.send_signal(sig)
    err = p.communicate(timeout=120)[1]
    assert p.returncode == (-9 if sig == signal.SIGKILL else 128 + sig), err
    if sig != signal.SIGKILL:
        assert err.strip() in ("kosmap: interrupted", "kosmap: terminated"), err
        assert not _leftovers(out)  # its staging folder removed
    assert _snapshot(out) == before  # byte for byte
    outdir.discard(claim(out, BUILD_FILES))  # a killed run's staging folder is the next run's to clear
    assert _snapshot(out) == before and not _leftovers(out)


@pytest.mark.slow
def test_sigterm_while_the_files_are_moved_in_puts_the_previous_ones_back(laser_log, previous, monkeypatch, capsys):
    out, before = previous
    real, moved = os.replace, []

    def replace(a, b):  # SIGTERM arrives when three files have been moved into place or aside
        real(a, b)
        if Path(a).parent.name.startswith(STAGE_PREFIX) and Path(b).parent == out or \
                Path(b).parent.name.startswith(BACKUP_PREFIX):
            moved.append(b)
            if len(moved) == 3:
                os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(outdir.os, "replace", replace)
    assert main(["build", str(laser_log), "--out", str(out), "--set", SETS[0], "-j", "0", "-q"]) == 128 + signal.SIGTERM
    assert "kosmap: terminated" in capsys.readouterr().err
    assert len(moved) > 3 and _snapshot(out) == before and not _leftovers(out)


KILL_MID_MOVE = """
import os, signal, sys
from pathlib import Path
from kosmap.mapping.runtime import outdir
out, k = Path(sys.argv[1]), int(sys.argv[2])
stage = outdir.claim(out, tuple(sys.argv[3:]))
for n in ("metrics.json", "map_laser.png", "map_new.png", "report.md"):
    (stage.dir / n).write_text("new " + n)
real, moved = os.replace, []
def replace(a, b):
    real(a, b)
    moved.append(b)
    if len(moved) == k:
        os.kill(os.getpid(), signal.SIGKILL)
outdir.os.replace = replace
outdir.commit(stage)
"""


@pytest.mark.parametrize("k", [1, 3, 6, 8, 10])  # 1: the journal; 2-6: the old files aside; 7-10: the new ones in
def test_a_run_killed_outright_while_moving_its_files_in_is_undone_by_the_next(tmp_path, k):
    """SIGKILL cannot be held off: the moves are journalled in the manifest, and the next run puts the previous
    files back before anything else (k: the rename after which it dies)."""
    out = tmp_path / "out"
    out.mkdir()
    for n in ("metrics.json", "map_laser.png", "map_old.png", "report.md", "stats.csv"):
        (out / n).write_text("old " + n)
    (out / "notes.txt").write_text("the user's")
    (out / MANIFEST).write_text(json.dumps({"kosmap": "build", "files": ["map_laser.png", "map_old.png",
                                                                          "metrics.json", "report.md", "stats.csv"]}))
    before = _snapshot(out)
    r = subprocess.run([sys.executable, "-c", KILL_MID_MOVE, str(out), str(k), *BUILD_FILES], capture_output=True)
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert _snapshot(out) != before  # caught in the middle
    outdir.discard(claim(out, BUILD_FILES))
    assert _snapshot(out) == before and not _leftovers(out)


@pytest.mark.slow
def test_ctrl_c_of_a_rerun_keeps_the_complete_build_rather_than_a_partial_one(laser_log, previous, tmp_path):
    out, before = previous
    n = []

    def stop_after_10(p):
        n.append(p.scans)
        if len(n) == 10:
            raise KeyboardInterrupt

    with pytest.raises(BuildInterrupted, match=f"the complete build already in {out} is kept"):
        build(laser_log, out, load_config(None, SETS), workers=0, on_progress=stop_after_10)
    assert _snapshot(out) == before and not _leftovers(out)
    n.clear()  # with no complete build there, what was read is mapped and kept, marked partial
    res = build(laser_log, tmp_path / "first", load_config(None, SETS), workers=0, on_progress=stop_after_10)
    assert res.partial and json.loads((tmp_path / "first" / MANIFEST).read_text())["partial"] is True
    assert res.metrics["frames"]["laser_scans_used"] == 10


@needs_proc
@pytest.mark.slow
def test_a_slam_rerun_stopped_midway_keeps_its_previous_files(laser_log, tmp_path):
    """The same staging for the other commands that write a folder (scan, compare, localize: `outdir.writing`):
    SIGTERM once the re-run has staged files."""
    out = tmp_path / "out"
    args = ["slam", str(laser_log), "--out", str(out), "-q"]
    assert main(args) == 0
    before = _snapshot(out)
    assert {"trajectory.tum", "map.pgm", "metrics.json", MANIFEST} <= set(before)
    p = _start(args)
    _wait_for(p, lambda: any(any(s.iterdir()) for s in out.glob(STAGE_PREFIX + "*")), "a staged file")
    p.send_signal(signal.SIGTERM)
    err = p.communicate(timeout=120)[1]
    assert p.returncode == 128 + signal.SIGTERM and err.strip() == "kosmap: terminated", err
    assert _snapshot(out) == before and not _leftovers(out)
