"""A small synthetic log of every record type, for round-trip and error tests."""

from __future__ import annotations

import numpy as np

from kosmap.frontend.records import CameraModel, DepthFrame, Odometry, Scan, Transform, Transforms

DEPTH = "/kinect2/sd/image_depth_rect"
INFO = "/kinect2/sd/camera_info"


def records(n: int = 5, seed: int = 0, width: int = 64, height: int = 48) -> list:
    """Time-ordered records: tf_static, camera info, then depth (16UC1 and 32FC1), scans and odometry."""
    rng = np.random.default_rng(seed)
    t0 = 1_700_000_000_123_456_789  # a real epoch in ns: float seconds would lose the last digits
    cam = CameraModel.from_fov(width, height, np.radians(70.6), np.radians(60), "kinect2_ir_optical_frame")
    out = [
        Transforms(t0, (Transform.from_xyz_rpy("base_link", "kinect2_ir_optical_frame", [0.1, 0, 1.0],
                                               [-np.pi / 2, 0, -np.pi / 2], t0),
                        Transform.from_xyz_rpy("base_link", "laser", [0.2, 0, 0.3], [0, 0, 0], t0)), True, "/tf_static"),
        CameraModel(cam.width, cam.height, cam.K, np.array([0.1, -0.2, 0.0, 0.0, 0.01]), "plumb_bob", cam.frame_id, INFO, t0),
    ]
    for i in range(n):
        t = t0 + (i + 1) * 33_333_333
        img = rng.integers(0, 8000, (height, width), dtype=np.uint16)
        out.append(DepthFrame(t, img, "16UC1", "kinect2_ir_optical_frame", DEPTH))
        f = rng.random((height, width), dtype=np.float32) * 4
        f[0, 0] = np.nan
        out.append(DepthFrame(t + 1, f, "32FC1", "cam2_optical", "/cam2/depth"))
        r = rng.random(1081).astype(np.float32) * 30
        r[::7] = np.inf
        out.append(Scan(t + 2, r, -2.356194490192345, 0.004363323129985824, 0.1, 30.0, "laser", "/scan",
                        rng.random(1081).astype(np.float32)))
        # a robot driving at ~1 m/s with jitter (faster odometry is a glitch the readers bridge: logs/validate.py)
        x, y = 0.03 * i + 0.01 * rng.normal(), 0.01 * rng.normal()
        out.append(Odometry(t + 3, float(x), float(y), float(rng.uniform(-3, 3)), "odom", "base_link", "/odom"))
    return out


def write_mcap(recs, path):
    """The records, in order, as an MCAP at `path` (each on its own topic); returns the path."""
    from kosmap.frontend.logs.writer import McapWriter

    with McapWriter(path) as w:
        for rec in recs:
            w.write(rec)
    return path


def copy_log(src, dst, keep):
    """A log holding the records of `src` for which keep(record) holds."""
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.writer import McapWriter

    with open_log(src) as log, McapWriter(dst) as w:
        for rec in log.read(log.info().types()):
            if keep(rec):
                w.write(rec, rec.topic)
    return dst


def room_laser_log(folder, seed: int, duration: float):
    """`duration` s of the simulated room, its laser, odometry and gyro only (no depth: a build of it is quick)."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    full = folder / "room.mcap"
    simulate(load_world("room"), SimConfig(seed=seed, duration=duration), full)
    return copy_log(full, folder / "laser.mcap", lambda r: not isinstance(r, (DepthFrame, CameraModel)))


def carmen_lines(scans, odom, odom_lines: bool = True) -> list[str]:
    """CARMEN log lines (FLASER, and ODOM when `odom_lines`) of 180° scans and N×3 odometry poses at their stamps:
    the format of the Radish logs (frontend/logs/carmen.py), with the scan pose equal to the odometry."""
    out = ["# CARMEN log written by the kosmap tests"]
    for s, o in zip(scans, odom):
        t = f"{s.stamp_ns * 1e-9:.6f}"
        pose = f"{o[0]:.6f} {o[1]:.6f} {o[2]:.6f}"
        if odom_lines:
            out.append(f"ODOM {pose} 0.0 0.0 0.0 {t} test {t}")
        ranges = " ".join(f"{r:.3f}" if np.isfinite(r) else "80.000" for r in s.ranges)
        out.append(f"FLASER {len(s.ranges)} {ranges} {pose} {pose} {t} test {t}")
    return out
