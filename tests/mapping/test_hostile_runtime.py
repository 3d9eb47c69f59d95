"""The stages themselves stay safe on data the readers let through or that reaches them another way: a camera
whose intrinsics place no bearing, a scan whose angles are not numbers, logs where no scan or depth frame is
usable. Each ends in one line naming the cause, with no output left behind, never a traceback."""

from __future__ import annotations

import re

import numpy as np
import pytest

from kosmap.frontend.errors import LogError
from kosmap.frontend.records import CameraModel, DepthFrame, Odometry, Scan, Transform
from kosmap.tools.cli import main

T0 = 1_700_000_000_000_000_000


def _odom(i: int) -> Odometry:
    return Odometry(T0 + i * 50_000_000 + 3, 0.02 * i, 0.0, 0.0, "odom", "base_link", "/odom")


def _laser_log(path, ranges, inc=0.0043633, n=40):
    from kosmap.frontend.logs.writer import McapWriter

    with McapWriter(path) as w:
        for i in range(n):
            w.write(Scan(T0 + i * 50_000_000, ranges, -2.35, inc, 0.1, 30.0, "laser", "/scan"))
            w.write(_odom(i))
    return path


def _depth_log(path, image, n=8):
    from kosmap.frontend.logs.writer import McapWriter

    with McapWriter(path) as w:
        for i in range(n):
            w.write(DepthFrame(T0 + i * 100_000_000, image, "16UC1", "cam", "/depth"))
            w.write(_odom(i))
    return path


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("kosmap: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("w, h, fx, cx, why", [
    (1, 1, 50.0, 0.0, "an image size of 1×1"),
    (64, 48, float("inf"), 32.0, "non-finite intrinsics"),
    (64, 48, float("nan"), 32.0, "non-finite intrinsics"),
    (64, 48, 50.0, 1e12, "a principal point (1e+12, 24) far outside its 64×48 image"),
    (64, 48, -50.0, 32.0, "focal lengths fx=-50"),
])
def test_the_kos_refuses_a_camera_whose_intrinsics_place_no_bearing(w, h, fx, cx, why):
    """Column bearings are atan((u − cx) / fx) over width − 1 columns: each case divided by zero, took the atan
    of NaN or spanned nothing."""
    from kosmap.frontend.kos import bearings_for

    K = np.array([[fx, 0, cx], [0, 50.0, 24], [0, 0, 1]])
    cam = CameraModel(w, h, K, np.zeros(5), "plumb_bob", "cam", "/camera_info")
    with pytest.raises(LogError, match=f"/camera_info: the KOS cannot use a camera with {why}".replace("(", r"\(")
                       .replace(")", r"\)").replace("+", r"\+")):
        bearings_for([(cam, Transform.identity("base_link", "cam"))])
    good = CameraModel.from_fov(64, 48, np.radians(70.6), np.radians(60), "cam")
    b = bearings_for([(good, Transform.identity("base_link", "cam"))])
    assert b.n == 64 and 69.0 < np.degrees((b.n - 1) * b.angle_increment) < 70.6  # the column centres' span


def test_a_scan_whose_angles_are_not_numbers_adds_nothing_to_a_grid():
    """A NaN angle_increment (or pose) makes every beam end NaN: the grid skips those beams instead of casting
    NaN to a cell index; the next good scan maps as on a fresh grid."""
    from kosmap.mapping.grid import GridBuilder, GridConfig

    good = Scan(0, np.full(181, 2.0, np.float32), -np.pi / 2, np.pi / 180, 0.1, 10.0, "laser", "/scan")
    bad = Scan(0, np.full(181, 2.0, np.float32), -np.pi / 2, float("nan"), 0.1, 10.0, "laser", "/scan")
    for engine in ("numba", "numpy"):
        ref = GridBuilder(GridConfig(), engine=engine)
        ref.add((0.0, 0.0, 0.0), good)
        g = GridBuilder(GridConfig(), engine=engine)
        g.add((0.0, 0.0, 0.0), bad)
        g.add((float("nan"), 0.0, 0.0), good)
        assert not g.seen.any()
        g.add((0.0, 0.0, 0.0), good)
        a, b = g.to_occupancy(), ref.to_occupancy()
        assert a.origin == b.origin and np.array_equal(a.data, b.data) and (a.data >= 65).sum() > 100


@pytest.mark.parametrize("cmd", [["build", "-j", "0", "-q"], ["slam", "-q"]])
@pytest.mark.parametrize("case, words", [
    ("empty", r"none of the (20|40) scans had 10 or more returns"),  # every scan without a beam (build: 10 Hz of 20)
    ("nan", "non-finite angle_min or angle_increment"),  # the reader's reason, not "0 scans"
])
def test_a_log_without_a_usable_scan_is_one_line_naming_why(tmp_path, capsys, cmd, case, words):
    ranges = np.zeros(0, np.float32) if case == "empty" else np.full(1081, 3.0, np.float32)
    log = _laser_log(tmp_path / f"log_{case}.mcap", ranges, inc=float("nan") if case == "nan" else 0.0043633)
    out = tmp_path / "out"
    assert main([cmd[0], str(log), "--out", str(out), *cmd[1:]]) == 2
    err = _one_line(capsys)
    assert re.search(words, err) and "nothing to map" in err
    assert not out.exists()


@pytest.mark.parametrize("cmd", [["scan"], ["build", "-j", "0", "-q"], ["slam", "--source", "kos", "-q"]])
def test_a_log_whose_depth_frames_are_all_unusable_is_one_line_and_leaves_nothing(tmp_path, capsys, cmd):
    """1×1 depth images: skipped by the reader; scan, build and slam then stop with one line that says why, and the
    run leaves no output folder (no kos.mcap, summary.json or manifest)."""
    log = _depth_log(tmp_path / "one_px.mcap", np.full((1, 1), 2000, np.uint16))
    out = tmp_path / "out"
    assert main([cmd[0], str(log), "--out", str(out), *cmd[1:]]) == 2
    err = _one_line(capsys)
    assert "a depth image of 1×1 pixels" in err and ("no depth frame gave a KOS scan" in err or "reached SLAM" in err)
    assert not out.exists()
