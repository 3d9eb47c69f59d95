"""Real data (Intel Research Lab, first 80 s): grids from the laser and odometry, and the alignment of two
real maps made from disjoint scans, one of them moved to an arbitrary frame."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.records import Odometry, Scan, Transforms
from kosmap.mapping.compare import CompareConfig, align, apply, compare, occupied_points, se2
from kosmap.mapping.grid import GridConfig, build_grid


def _intel(data_dir, n_scans=400):
    scans, odo, mount = [], [], (0.0, 0.0, 0.0)
    with open_log(data_dir / "laser" / "intel" / "intel.orig.bag") as log:
        for rec in log.read(["/scan", "/odom", "/tf_static"]):
            if isinstance(rec, Scan):
                scans.append(rec)
            elif isinstance(rec, Odometry):
                odo.append((rec.stamp, rec.x, rec.y, rec.yaw))
            elif isinstance(rec, Transforms):
                for tf in rec.transforms:
                    if tf.child == "laser":
                        mount = (tf.translation[0], tf.translation[1], tf.rpy()[2])
            if len(scans) >= n_scans:
                break
    o = np.array(odo)
    t = np.array([s.stamp for s in scans])
    yaw = np.unwrap(o[:, 3])
    poses = np.column_stack((np.interp(t, o[:, 0], o[:, 1]), np.interp(t, o[:, 0], o[:, 2]), np.interp(t, o[:, 0], yaw)))
    return poses, scans, mount


@pytest.mark.data
@pytest.mark.slow
def test_two_real_maps_from_disjoint_scans_realign_from_any_frame(data_dir):
    poses, scans, mount = _intel(data_dir)
    cfg = GridConfig(resolution=0.05)
    a = build_grid(poses[0::2], scans[0::2], mount, cfg)
    truth = (2.0, -1.0, np.radians(127.0))
    moved = np.array([(*apply(se2(*truth), p[None, :2])[0], p[2] + truth[2]) for p in poses[1::2]])
    b = build_grid(moved, scans[1::2], mount, cfg)
    al = align(a, b)
    pa = occupied_points(a, CompareConfig())
    d = np.hypot(*(apply(al.matrix, pa) - apply(se2(*truth), pa)).T)
    assert abs(np.degrees(al.yaw - truth[2])) < 0.5
    assert np.median(d) <= 0.05 and d.max() <= 0.1
    m = compare(a, b, alignment=al).metrics
    assert m["tolerances"]["0.10"]["f1"] > 0.85, m["tolerances"]
    assert m["free"]["agreement"] > 0.95
