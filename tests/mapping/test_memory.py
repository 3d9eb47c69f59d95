"""Memory stays flat in the log's length: what the build holds per scan is a few compact numbers, the
keyframes' full scans are not kept once the loop closer has its thinned copy, and the spill keeps no per-point
state. Sizes are counted (array buffers, tracemalloc), never timed."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from kosmap.backend.graph import GraphConfig
from kosmap.frontend.odometry import OdometryConfig, scan_to_points
from kosmap.backend.slam import Slam
from kosmap.mapping.build.spill import Spill
from tests.mapping.synthetic_laser import make_log


@pytest.fixture(scope="module")
def ring():
    """SLAM over one lap of the synthetic corridor ring (181 beams, 5 Hz, drifting odometry)."""
    log = make_log(seed=3, laps=1)
    ocfg = OdometryConfig()
    slam = Slam(ocfg, GraphConfig())
    for scan, odom in zip(log.scans, log.odom):
        slam.add_scan(scan.stamp_ns, scan_to_points(scan, log.mount, ocfg.min_range, ocfg.max_range), odom)
    return log, slam, ocfg


def test_per_scan_state_is_a_few_compact_numbers(ring):
    log, slam, _ = ring
    n = len(log.scans)
    held = [slam.stamps, slam.local, slam.odom, slam.matched, slam.key_of_scan]
    per_scan = sum(a.buffer_info()[1] * a.itemsize for a in held) / n
    assert len(slam.stamps) == n and len(slam.local) == 3 * n
    assert per_scan <= 1.2 * (8 + 24 + 24 + 1 + 8)  # stamp, pose, odometry, matched, keyframe: 65 bytes (+ slack)


def test_keyframes_do_not_keep_their_scans(ring):
    """The loop closer keeps a thinned float32 copy in its submaps; the keyframes' full float64 scans are dropped."""
    log, slam, _ = ring
    assert len(slam.keyframes) > 20
    assert all(len(kf.points) == 0 for kf in slam.keyframes)
    lc = slam.loops
    per_key = lc.nbytes / len(slam.keyframes)  # submap points, open scans and cached fields, all it holds
    points_per_key = sum(sm.nbytes for sm in lc.submaps) / sum(len(sm.node_ids) for sm in lc.submaps)
    assert points_per_key <= 181 * 2 * 4 + 64  # at most one float32 point per beam (thinned: fewer)
    res = slam.finish()  # the result is still complete: a pose for every scan
    assert res.poses.shape == (len(log.scans), 3) and np.isfinite(res.poses).all()
    assert per_key < 200_000


def test_standing_still_adds_no_memory_per_scan(ring):
    """After the lap, 400 more scans at the same place: no keyframe, no submap, so what is held may grow only by
    the per-scan numbers (65 bytes), not by anything per scan that is kept (a list of arrays was ~400)."""
    log, _, ocfg = ring
    slam = Slam(ocfg, GraphConfig())
    scan, odom = log.scans[0], log.odom[0]
    pts = scan_to_points(scan, log.mount, ocfg.min_range, ocfg.max_range)
    t = scan.stamp_ns
    for k in range(50):  # warm up: first keyframe, front-end submap, array growth
        slam.add_scan(t + k * 200_000_000, pts, odom)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        n = 400
        for k in range(50, 50 + n):
            slam.add_scan(t + k * 200_000_000, pts, odom)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert len(slam.keyframes) == 1
    assert grown / n < 150, f"{grown / n:.0f} bytes per scan"


def test_the_spill_keeps_no_per_point_state(tmp_path):
    """Plane clouds go to disk with one index entry each: 200 clouds of 4000 points hold ~nothing in memory."""
    sp = Spill(tmp_path, ["obstacle"])
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(4000, 3))
    cls = rng.integers(0, 3, 4000).astype(np.float32)
    sp.add_cloud(0, pts, cls)  # warm up
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(1, 201):
            sp.add_cloud(k * 1_000_000_000, pts, cls)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    sp.close()
    assert len(sp.planes) == 201 * 4000 and len(sp.planes.stamps) == 0
    assert grown < 200 * 300, f"{grown / 200:.0f} bytes per cloud"  # the index tuple, not 8 bytes a point
    stamp, first, n = sp.cloud_index[57]
    back = sp.planes.reader().block(first, n)
    assert stamp == 57_000_000_000 and np.allclose(back[:, :3], pts.astype(np.float32)) and np.array_equal(back[:, 3], cls)


@pytest.mark.slow
def test_a_republished_tf_static_is_kept_once(tmp_path):
    """A recorder may republish /tf_static every second: the build keeps (and writes) each distinct set once, not
    once per message for the whole run; the maps are those of the log with a single /tf_static."""
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import DepthFrame, Transforms
    from kosmap.mapping.config import load_config
    from kosmap.mapping.mapio import read_map_server
    from kosmap.mapping.build import build
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "room.mcap"
    simulate(load_world("room"), SimConfig(seed=2, duration=1.0), log)
    again = tmp_path / "republished.mcap"
    statics = []
    with open_log(log) as lg, McapWriter(again) as w:
        for rec in lg.read(lg.info().types()):
            if isinstance(rec, Transforms) and rec.static:
                statics.append(rec)
            elif isinstance(rec, DepthFrame) and statics:  # the same /tf_static again before every depth frame
                for s in statics:
                    w.write(Transforms(rec.stamp_ns, s.transforms, True, s.topic), s.topic)
            w.write(rec, rec.topic)
    with open_log(again) as lg:
        assert lg.info().count("/tf_static") > 20
    cfg = load_config(None, ["build.depth_rate=0"])
    a = build(log, tmp_path / "a", cfg, workers=0, report=False)
    b = build(again, tmp_path / "b", cfg, workers=0, report=False)
    with open_log(b.out / "kosmap.mcap") as lg:
        assert lg.info().count("/tf_static") == len(statics)
    for name in a.metrics["maps"]:
        ga, gb = read_map_server(a.out / f"map_{name}.yaml"), read_map_server(b.out / f"map_{name}.yaml")
        assert np.array_equal(ga.data, gb.data), name
