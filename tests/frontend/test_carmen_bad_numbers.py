"""CARMEN logs with impossible numbers: each bad line is skipped and counted (the warning names its line), nothing
non-finite reaches the pipeline, and odometry jumps faster than any robot are bridged, not mapped."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from kosmap.backend.metrics import ate
from kosmap.backend.trajio import read_tum
from kosmap.frontend.logs import open_log
from kosmap.frontend.records import Odometry, Scan
from kosmap.mapping.mapio import read_map_server
from kosmap.tools.cli import main
from tests.frontend.synthetic_log import carmen_lines
from tests.mapping.synthetic_laser import make_log

N = 150  # scans: 30 s of the ring corridor at 5 Hz


@pytest.fixture(scope="module")
def ring():
    log = make_log(seed=3, laps=1, mount=(0.0, 0.0, 0.0))
    return log, carmen_lines(log.scans[:N], log.odom[:N])


def _write(tmp_path, lines, name="bad.clf"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _set_field(line: str, i: int, value: str) -> str:
    f = line.split()
    f[i] = value
    return " ".join(f)


def _odom_line(lines, k):  # the k-th ODOM line's index in `lines` (line number: index + 1)
    return [i for i, ln in enumerate(lines) if ln.startswith("ODOM")][k]


def _laser_line(lines, k):
    return [i for i, ln in enumerate(lines) if ln.startswith("FLASER")][k]


# (which line, how it is changed, scans and odometry records left, words of the warning)
CASES = {
    "stamp inf": ("laser", lambda ln: _set_field(ln, -3, "inf"), N - 1, N, "a time stamp of inf"),
    "stamp 1e300": ("laser", lambda ln: _set_field(ln, -3, "1e300"), N - 1, N, "a time stamp of 1e300"),
    "stamp negative": ("laser", lambda ln: _set_field(ln, -3, "-5"), N - 1, N, "a time stamp of -5"),
    "odometry nan": ("odom", lambda ln: _set_field(ln, 1, "nan"), N, N - 1, "a non-finite odometry pose"),
    "odometry inf": ("odom", lambda ln: _set_field(ln, 3, "inf"), N, N - 1, "a non-finite odometry pose"),
    "ODOM 1 2": ("odom", lambda ln: "ODOM 1 2", N, N - 1, "3 fields where an ODOM line has at least 8"),
    "beams 0": ("laser", lambda ln: "FLASER 0 " + " ".join(ln.split()[183:]), N - 1, N, "a beam count of 0"),
    "beams 1": ("laser", lambda ln: "FLASER 1 " + " ".join(ln.split()[182:]), N - 1, N, "a beam count of 1"),
    "beams -1": ("laser", lambda ln: "FLASER -1 " + " ".join(ln.split()[183:]), N - 1, N, "a beam count of -1"),
    "beams 10^9": ("laser", lambda ln: _set_field(ln, 1, "1000000000"), N - 1, N, "a beam count of 1000000000"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_line_is_skipped_and_named(ring, tmp_path, case):
    _, lines = ring
    kind, edit, n_scans, n_odom, words = CASES[case]
    i = (_laser_line if kind == "laser" else _odom_line)(lines, 40)
    lines = list(lines)
    lines[i] = edit(lines[i])
    with open_log(_write(tmp_path, lines)) as log:
        recs = list(log.read())
    scans = [r for r in recs if isinstance(r, Scan)]
    odom = [r for r in recs if isinstance(r, Odometry)]
    assert (len(scans), len(odom)) == (n_scans, n_odom)
    assert len(log.warnings) == 1
    assert f"skipped 1 malformed line(s), the first at line {i + 1} ({words}" in log.warnings[0]
    assert all(0 < r.stamp_ns < 1 << 62 for r in recs)
    assert all(math.isfinite(o.x) and math.isfinite(o.y) and math.isfinite(o.yaw) for o in odom)
    assert all(len(s.ranges) == 181 and s.angle_increment > 0 for s in scans)


def test_one_malformed_odom_line_does_not_discard_the_laser_lines_odometry(ring, tmp_path):
    """A log whose odometry is in its FLASER lines (no ODOM lines) plus one malformed `ODOM 1 2`: that line does not
    make the log one with ODOM lines of its own, so the laser lines' poses stay its odometry (the reported failure
    kept none: 97 odometry factors became 0)."""
    log, _ = ring
    lines = carmen_lines(log.scans[:N], log.odom[:N], odom_lines=False)
    lines.insert(5, "ODOM 1 2")
    with open_log(_write(tmp_path, lines)) as lg:
        assert lg.info().count("/odom") == N
        odom = [r for r in lg.read(["/odom"]) if isinstance(r, Odometry)]
    assert len(odom) == N
    np.testing.assert_allclose([[o.x, o.y] for o in odom], log.odom[:N, :2], atol=1e-5)
    assert "line 6 (3 fields where an ODOM line has at least 8)" in lg.warnings[0]


def _with_jump(lines, at: int, dx: float) -> list[str]:
    """Every ODOM and FLASER pose from the `at`-th scan on shifted by `dx` metres (a reset or glitch of the wheel
    odometry that stays)."""
    out = list(lines)
    for i in range(_odom_line(lines, at), len(lines)):
        f = out[i].split()
        if f[0] == "ODOM":
            f[1] = f"{float(f[1]) + dx:.6f}"
        out[i] = " ".join(f)
    return out


def _run(tmp_path, path, *extra):
    out = tmp_path / "out"
    return main(["slam", str(path), "--out", str(out), *extra]), out


@pytest.mark.parametrize("dx", [5000.0, 800.0, -30.0])
def test_odometry_jump_is_bridged_in_the_reader(ring, tmp_path, dx):
    log, lines = ring
    with open_log(_write(tmp_path, _with_jump(lines, 60, dx))) as lg:
        odom = np.array([[r.x, r.y, r.yaw] for r in lg.read(["/odom"]) if isinstance(r, Odometry)])
    assert len(odom) == N
    steps = np.hypot(*np.diff(odom[:, :2], axis=0).T)
    true_steps = np.hypot(*np.diff(log.odom[:N, :2], axis=0).T)
    assert steps.max() <= true_steps.max() + 1e-6  # the jump is gone: no step longer than the robot drove
    assert steps[59] == 0.0  # bridged: no motion across it
    assert np.allclose(steps[60:], true_steps[60:], atol=1e-5)  # the odometry after it keeps its increments
    assert len(lg.warnings) == 1
    m = re.search(r"odometry on /odom jumps ([\d.]+) m in 0.200 s", lg.warnings[0])
    assert m and abs(float(m.group(1)) - abs(dx)) < 0.5 and "bridged" in lg.warnings[0]


@pytest.mark.parametrize("dx", [5000.0, 800.0])
def test_slam_over_an_odometry_jump_maps_the_ring_not_kilometres(ring, tmp_path, capsys, dx):
    """The reported failures: a 5 km jump ended in gtsam's indeterminate system, an 800 m one in a 12212×10993
    map. Bridged, the map stays the size of the 20 × 12 m world and the trajectory follows the truth."""
    log, lines = ring
    code, out = _run(tmp_path, _write(tmp_path, _with_jump(lines, 60, dx)))
    stdout, err = capsys.readouterr()
    assert code == 0, err
    assert "jumps" in stdout + err and "bridged" in stdout + err
    grid = read_map_server(out / "map.yaml")
    h, w = grid.data.shape
    assert w * grid.resolution < 40 and h * grid.resolution < 40, (w, h, grid.resolution)
    t, p = read_tum(out / "trajectory.tum")
    e = ate(t, p, log.stamps_ns[:N] * 1e-9, log.truth[:N])
    assert e["n"] == N and e["rmse"] < 0.2


def test_scans_without_times_are_refused_and_the_importer_restamps_them(ring, tmp_path, capsys):
    """A log whose laser lines are all stamped 0 (as some research logs are) would map as one scan: it is refused in
    one line naming the importer, and the importer's re-stamped log maps the whole run."""
    log, lines = ring
    zero = []
    for ln in lines:
        f = ln.split()
        if f[0] == "FLASER":
            f[-3] = f[-1] = "0.000000"
        zero.append(" ".join(f))
    path = _write(tmp_path, [ln for ln in zero if not ln.startswith("ODOM")], "untimed.clf")
    assert main(["slam", str(path), "--source", "laser", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no usable scan times" in err and "kosmap.tools.laserimport" in err, err
    assert not (tmp_path / "out").exists()
    from kosmap.tools.laserimport import main as restamp

    restamp([str(path), str(tmp_path / "stamped.clf"), "--format", "carmen"])
    assert main(["slam", str(tmp_path / "stamped.clf"), "--source", "laser", "--out", str(tmp_path / "ok")]) == 0
    assert len(read_tum(tmp_path / "ok" / "trajectory.tum")[0]) > 0.9 * N
