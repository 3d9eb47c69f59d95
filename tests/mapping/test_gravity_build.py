"""`kosmap scan` and `kosmap build` take the depth camera's gravity from where `kosmap planes` does (the mount, the
IMU, the frames) and say which: a camera pitched down and rolled on a robot whose configured mount is level
(simulated room, Kinect v2 noise) keeps the floor out of its KOS scans with gravity from the frames, and its KOS map
matches the laser's as well as with the true mount; with the wrong level mount the floor becomes obstacles."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kosmap.mapping.kosstream import ScanRun, kos_steps
from kosmap.tools import options as O
from kosmap.tools.cli import main

pytestmark = pytest.mark.slow

LEVEL = ('depth.mount="config"', "depth.mount_xyz=[0.1,0,1.0]", "depth.mount_rpy_deg=[0,0,0]")


def _log(tmp_path, name, rpy, seed):
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    path = tmp_path / f"{name}.mcap"
    simulate(load_world("room"), SimConfig(seed=seed, duration=8.0, depth_rate=2.0, camera_rpy_deg=list(rpy),
                                           camera_xyz=[0.1, 0.0, 1.0]), path)
    return path


def _near_laser(path, gravity: str) -> tuple[float, ScanRun]:
    """The share of KOS obstacle points within 10 cm of a laser return of the same step (base_link)."""
    cfg = O.make_config(None, [*LEVEL, f'depth.gravity="{gravity}"'], None, None)
    run, shares = ScanRun(), []
    for step in kos_steps(path, cfg, run):
        sc, las = step.scans["obstacle"], step.laser
        ok = np.isfinite(sc.ranges)
        if las is None or not ok.any():
            continue
        p = np.c_[sc.ranges[ok] * np.cos(sc.angles[ok]), sc.ranges[ok] * np.sin(sc.angles[ok])]
        lo = np.isfinite(las.ranges) & (las.ranges < las.range_max)
        q = np.c_[las.ranges[lo] * np.cos(las.angles[lo]), las.ranges[lo] * np.sin(las.angles[lo]), np.zeros(lo.sum())]
        q = run.laser_mount.apply(q)[:, :2]
        shares.append((np.linalg.norm(p[:, None] - q[None], axis=2).min(axis=1) < 0.10).mean())
    return float(np.mean(shares)), run


def test_scan_takes_gravity_from_the_frames_when_asked(tmp_path, capsys):
    path = _log(tmp_path, "tilted", (2.0, 12.0, 0.0), 3)
    wrong, run0 = _near_laser(path, "mount")
    right, run1 = _near_laser(path, "frames")
    assert run0.gravity.source == "config" and not run0.gravity.mounts
    cam = run1.gravity.cameras["kinect2_ir_optical_frame"]
    assert abs(cam.pitch_deg - 12.0) <= 0.3 and abs(cam.roll_deg - 2.0) <= 0.3 and abs(cam.height_m - 1.0) <= 0.01
    assert cam.differs and any("gravity-aligned mount" in w for w in run1.warnings)
    # level mount: the floor ahead rises into the obstacle band; gravity from the frames: walls only
    assert wrong < 0.2 and right > 0.7, (wrong, right)
    code = main(["scan", str(path), "--out", str(tmp_path / "s"), "--figures", "0",
                 *sum((["--set", s] for s in (*LEVEL, 'depth.gravity="frames"')), [])])
    out = capsys.readouterr().out
    assert code == 0 and "gravity: the frames" in out
    s = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert s["gravity"]["source"] == "frames" and s["gravity"]["cameras"]["kinect2_ir_optical_frame"]["differs"]


def test_build_with_gravity_from_the_frames_maps_like_the_true_mount(tmp_path, capsys):
    path = _log(tmp_path, "pitched", (-1.5, 9.0, 0.0), 5)
    f1 = {}
    for name, sets in (("true", []), ("level", [*LEVEL, 'depth.gravity="mount"']),
                       ("frames", [*LEVEL, 'depth.gravity="frames"'])):
        out = tmp_path / name
        code = main(["build", str(path), "--out", str(out), "--workers", "0", *sum((["--set", s] for s in sets), [])])
        assert code == 0
        m = json.loads((out / "metrics.json").read_text())
        f1[name] = m["comparisons"]["kos_obstacle_vs_laser"]["tolerances"]["0.10"]["f1"]
        if name == "frames":
            g = m["gravity"]
            assert g["source"] == "frames" and "gravity: the frames" in capsys.readouterr().err
            cam = g["cameras"]["kinect2_ir_optical_frame"]
            assert abs(cam["pitch_deg"] - 9.0) <= 0.3 and abs(cam["roll_deg"] + 1.5) <= 0.3
        elif name == "true":
            assert m["gravity"]["source"] == "tf_static"
    assert f1["frames"] >= f1["true"] - 0.03 and f1["frames"] >= f1["level"] + 0.1, f1


def test_scan_takes_gravity_from_the_cameras_imu_without_tf_static(tmp_path, capsys):
    """A log without /tf_static whose IMU sits on the depth camera (a camera's built-in IMU: its samples in the
    optical frame), the camera pitched and rolled, no mount given: `kosmap scan` says it takes gravity from the IMU
    and the mount it gives holds the camera's pitch and roll (the accelerometer's 0.02 m/s² bias is ~0.1°; the
    robot's own accelerations average out over the half second before each frame)."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    path = tmp_path / "imu.mcap"
    simulate(load_world("room"), SimConfig(seed=11, duration=6.0, depth_rate=2.0, camera_rpy_deg=[-2.0, 10.0, 0.0],
                                           camera_xyz=[0.1, 0.0, 1.0], tf_static=False, imu_on_camera=True), path)
    code = main(["scan", str(path), "--out", str(tmp_path / "s"), "--figures", "0"])
    out = capsys.readouterr().out
    assert code == 0 and "gravity: the log's IMU" in out, out
    g = json.loads((tmp_path / "s" / "summary.json").read_text())["gravity"]
    cam = g["cameras"]["kinect2_ir_optical_frame"]
    assert g["source"] == "imu" and cam["frames"] >= 10
    assert abs(cam["pitch_deg"] - 10.0) <= 0.3 and abs(cam["roll_deg"] + 2.0) <= 0.3, cam
