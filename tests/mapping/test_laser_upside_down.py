"""A laser mounted upside down (roll 180° in /tf_static) scans the other way round: kosmap reads its scans upright
(mapping/slamfeed.py LaserMount.read) in `slam`, `build` and `localize`, de-skewed like an upright laser's, so the
map and the trajectory are not mirrored."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from kosmap.backend.slam import Slam
from kosmap.frontend.odometry import scan_to_points
from kosmap.frontend.records import Scan, Transforms
from kosmap.mapping.config import Config
from kosmap.mapping.slamfeed import SlamFeed, laser_mount, upright

WARD = Path(__file__).resolve().parents[1] / "worlds" / "ward.yaml"


def _scans(poses: np.ndarray, dt: float):
    """The scans of an upright and an upside-down 240° laser at base_link's origin, beam i cast from poses[i] (or
    all from poses[0] with one pose), each with its mount as /tf_static gives it."""
    from kosmap.tools.simulate import World
    from kosmap.tools.simulate.render import LaserModel, laser_mount as sim_mount, render_laser_geometry

    world, model = World.load(WARD), LaserModel(beams=683, fov_deg=240.0, range_max=5.6)
    out = []
    for rpy in ((0.0, 0.0, 0.0), (math.pi, 0.0, 0.0)):
        tf = sim_mount((0.0, 0.0, 0.35), rpy)
        r, _, _ = render_laser_geometry(world, poses, tf, model)
        scan = Scan(10**9, r.astype(np.float32), model.angle_min, model.angle_increment, model.range_min,
                    model.range_max, "laser", time_increment=dt)
        out.append((scan, laser_mount([Transforms(0, (tf,), True, "/tf_static")], "base_link", "laser")))
    return out


def test_an_upside_down_scan_read_upright_is_the_upright_lasers():
    (level, lm_level), (flipped, lm) = _scans(np.array([[3.0, 6.2, math.radians(30)]]), 1e-5)
    assert lm.flipped and not lm_level.flipped and lm.warning is None and np.allclose(lm.pose, [0.0, 0.0, 0.0])
    up = lm.read(flipped)
    assert np.isclose(up.angle_min, level.angle_min) and np.isclose(up.angle_max, level.angle_max)
    ok = np.isfinite(level.ranges)
    assert np.array_equal(ok, np.isfinite(up.ranges)) and np.abs(up.ranges[ok] - level.ranges[ok]).max() < 1e-4
    assert not np.allclose(flipped.ranges[ok], level.ranges[ok], atol=0.05)  # read as it comes: mirrored
    # the beams' times run backwards from the last one's, now the stamp
    assert up.time_increment == -1e-5 and up.stamp_ns == 10**9 + round(682 * 1e-5 * 1e9)
    bad = upright(Scan(5, np.zeros(0, np.float32), -1.0, 0.01, 0.1, 5.0, "laser", time_increment=float("nan")))
    assert bad.stamp_ns == 5 and bad.time_increment == 0.0  # a scan without beams or times stays where it was


def test_an_upside_down_scan_is_deskewed_as_the_upright_lasers():
    """Turning in place at 90°/s through a 0.1 s scan (9°): each laser's beams de-skewed into the frame at its stamp
    (the upright one's first beam, the upside-down one's last) and turned into the first beam's frame lie on one
    another; not de-skewed, the upside-down scan is centimetres off."""
    w, n = math.radians(90.0), 683
    dt = 0.1 / (n - 1)
    t = np.arange(n) * dt
    poses = np.column_stack((np.full(n, 3.0), np.full(n, 6.2), 0.5 + w * t))
    (level, lm_level), (flipped, lm) = _scans(poses, dt)
    twist = ((0.0, 0.0), w)
    ref = scan_to_points(level, lm_level.pose, 0.1, 5.6, twist)
    up = lm.read(flipped)
    turn = w * (up.stamp_ns - level.stamp_ns) * 1e-9  # the upright reading's frame, turned back to the first beam's
    c, s = math.cos(turn), math.sin(turn)

    def off(p: np.ndarray) -> float:
        p = p @ np.array([[c, s], [-s, c]])
        return float(np.median(cKDTree(ref).query(p)[0]))

    assert off(scan_to_points(up, lm.pose, 0.1, 5.6, twist)) < 0.005
    assert off(scan_to_points(up, lm.pose, 0.1, 5.6, None)) > 0.05
    # SLAM's feed de-skews it as it does the upright laser's: its points wait for the odometry round the stamp
    cfg = Config()
    feed = SlamFeed(Slam(cfg.odometry, cfg.graph), use_odom=True)
    feed.push_laser(up, lm.pose)
    feed.push_laser(level, lm_level.pose)
    assert [p[1] is None and p[2] is not None for p in feed.pending] == [True, True]


@pytest.mark.slow
def test_slam_and_localize_with_an_upside_down_laser(tmp_path):
    from kosmap.mapping.locinput import read_input
    from kosmap.mapping.slam import evaluate, run_slam
    from kosmap.tools.simulate import SimConfig, World, simulate
    from tests.mapping.onplan import share_on_plan

    log = tmp_path / "ward.mcap"
    cfg = SimConfig(seed=9, duration=40.0, depth_rate=1.0, depth_width=64, depth_height=53, compression="lz4",
                    laser_rpy_deg=[180.0, 0.0, 0.0])
    world = World.load(WARD)
    simulate(world, cfg, log)
    m = evaluate(run_slam(log, Config()))
    # the goal is 0.10 m with harsh wheels; read mirrored, the 121 s log of this world measured 4.2 m
    assert m["ate"]["rmse"] <= 0.05 and m["ate"]["rmse"] < 0.5 * m["ate_odometry"]["rmse"], m
    assert share_on_plan(read_input(log, Config(), "laser"), world, every=10) >= 0.9  # the localizer's points
