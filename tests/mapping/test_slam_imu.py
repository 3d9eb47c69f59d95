"""SLAM with a gyro on the synthetic corridor ring (tests/mapping/synthetic_laser.py) seen by a narrow
Kinect-like scan (70°, ≤ 4.5 m): gyro yaw factors, the gyro bias and the odometry scale as graph variables; a gyro
stream with gaps and a stuck stretch, read from a log file, still runs with warnings; no IMU works as before."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.backend.graph import GraphConfig
from kosmap.backend.metrics import ate, rpe
from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.odometry import OdometryConfig, scan_points_base
from kosmap.frontend.records import Imu
from kosmap.mapping.config import Config
from kosmap.backend.kosprofile import KOS_FRONTEND
from kosmap.backend.slam import Slam
from kosmap.mapping.slam import evaluate, run_slam, summary
from tests.mapping.synthetic_laser import make_log, records

SCALE = 0.03  # the injected wheel-odometry scale error
BIAS = math.radians(0.02)  # gyro turn-on bias, rad/s
# wheel odometry σ close to the truth of make_log (1 % per √m would do; the [graph] defaults are for slipping laser
# benchmark robots): the scale is observable only if the wheels are not declared worse than they are
HONEST = {"odom_sigma_xy": 0.005, "odom_sigma_xy_per_m": 0.02, "imu_frontend": True}  # imu_frontend: as for KOS


@pytest.fixture(scope="module")
def narrow():
    return make_log(seed=1, laps=2, beams=121, fov_deg=70.0, max_range=4.5, odom_scale=SCALE)


def gyro_stream(log, seed: int = 0, hz: float = 400.0, gap=None, stuck=None):
    """(stamps ns, yaw rates): the truth's yaw rate (constant between scans) + white noise 0.005 °/s/√Hz + BIAS."""
    rng = np.random.default_rng(seed)
    t = (log.stamps_ns - log.stamps_ns[0]) * 1e-9
    yaw = np.unwrap(log.truth[:, 2])
    tg = np.arange(0.0, t[-1], 1.0 / hz) + 0.5 / hz
    i = np.clip(np.searchsorted(t, tg) - 1, 0, len(t) - 2)
    w = (yaw[i + 1] - yaw[i]) / (t[i + 1] - t[i]) + BIAS + math.radians(0.005) * math.sqrt(hz) * rng.standard_normal(len(tg))
    keep = np.ones(len(tg), bool)
    if gap is not None:
        keep &= ~((tg >= gap[0]) & (tg < gap[1]))
    if stuck is not None:
        m = (tg >= stuck[0]) & (tg < stuck[1])
        w[m] = w[np.argmax(m)]
    return log.stamps_ns[0] + np.round(tg[keep] * 1e9).astype(np.int64), w[keep]


def _run(log, gyro=None, ahead_ns: int = 20_000_000, **graph):
    slam = Slam(OdometryConfig(**KOS_FRONTEND), GraphConfig(**{**HONEST, **graph}))
    k = 0
    for scan, o in zip(log.scans, log.odom):
        if gyro is not None:  # the gyro arrives ahead of the scan, as in a log
            while k < len(gyro[0]) and gyro[0][k] <= scan.stamp_ns + ahead_ns:
                slam.add_imu(int(gyro[0][k]), float(gyro[1][k]))
                k += 1
        slam.add_scan(scan.stamp_ns, scan_points_base(scan.ranges, scan.angles, scan.valid(), log.mount, 0.1, 4.5), o)
    r = slam.finish()
    return r, ate(r.stamps, r.poses, r.stamps, log.truth)["rmse"]


@pytest.mark.slow
def test_gyro_factors_on_a_narrow_corridor_ring(narrow):
    r0, a0 = _run(narrow)
    r1, a1 = _run(narrow, gyro_stream(narrow))
    s0, s1 = summary(r0), summary(r1)
    h0 = rpe(r0.stamps, r0.poses, r0.stamps, narrow.truth, delta=50)["rot_rmse_deg"]  # heading over 10 s
    h1 = rpe(r1.stamps, r1.poses, r1.stamps, narrow.truth, delta=50)["rot_rmse_deg"]
    assert h1 < 0.5 * h0, (h1, h0)  # measured 0.088° vs 0.270°
    # measured 0.135 vs 0.130 m: along-track (the 3 % scale, see the next test) dominates here, not heading
    assert a1 <= a0 + 0.01 and a1 <= 0.15, (a1, a0)
    assert s1["imu"]["factors"] >= len(r1.keyframes) - 2 and s1["factors"]["gyro"] == s1["imu"]["factors"]
    assert s1["gyro_bias_deg_s"] == pytest.approx(0.02, abs=0.005)  # measured 0.0203
    assert s1["odometry_scale"] > 1.01  # measured 1.0139: towards the injected 1.03, see the next test
    assert s0["gyro_bias_deg_s"] is None and not r0.imu_stats["factors"]  # no IMU: as before
    assert not r1.warnings


@pytest.mark.slow
def test_how_far_the_gyro_runs_ahead_of_the_scans_changes_nothing(narrow):
    # kosmap build reads the log ahead of the scans the worker pool returns, further with more workers: the gyro
    # factors are settled at scan times, so serial and parallel runs solve the same graph (they once differed:
    # office KOS SLAM ATE 0.032 vs 0.036 m from two identical parallel runs)
    g = gyro_stream(narrow)
    r1, a1 = _run(narrow, g, ahead_ns=20_000_000)
    r2, a2 = _run(narrow, g, ahead_ns=3_000_000_000)
    assert np.array_equal(r1.poses, r2.poses) and a1 == a2


@pytest.mark.slow
def test_calibrating_while_running_feeds_the_scale_to_the_front_end(narrow):
    # the front end pulls its along-track position towards the wheels' prediction (a 70° scan sees nothing along a
    # corridor), so an uncorrected 3 % scale biases the matches and the final estimate towards 1; re-estimating it
    # every 50 nodes and correcting the prediction halves the error
    r, a = _run(narrow, gyro_stream(narrow), calibrate_every=50)
    s = summary(r)
    assert a <= 0.08, a  # measured 0.060 m (0.126 m without)
    assert abs(s["odometry_scale"] - (1 + SCALE)) <= 0.01, s["odometry_scale"]  # measured 1.0224


@pytest.mark.slow
def test_gyro_gaps_and_stuck_output_from_a_log_file(tmp_path):
    log = make_log(seed=2, laps=1, beams=121, fov_deg=70.0, max_range=4.5, odom_scale=SCALE)
    gs, gw = gyro_stream(log, gap=(20.0, 23.0), stuck=(34.5, 37.5))  # stuck through the turn at 35–37.6 s
    path = tmp_path / "ring_imu.mcap"
    recs = records(log) + [Imu(int(s), np.array([0.0, 0.0, w]), np.array([0.0, 0.0, 9.81]), frame_id="base_link", topic="/imu")
                           for s, w in zip(gs, gw)]
    recs.sort(key=lambda r: r.stamp_ns)
    with McapWriter(path) as w:
        for rec in recs:
            w.write(rec)
    cfg = Config()
    for k, v in {**HONEST, "loop_closure": False}.items():
        setattr(cfg.graph, k, v)
    for k, v in KOS_FRONTEND.items():  # a narrow scan (laser path, so no depth frames are needed)
        setattr(cfg.odometry, k, v)
    r = run_slam(path, cfg)
    m = evaluate(r)
    s = summary(r)
    assert s["imu"]["samples"] == len(gs)
    assert s["imu"]["gap"] >= 1 and s["imu"]["stuck"] >= 1 and s["imu"]["factors"] > 0.8 * (len(r.keyframes) - 1)
    assert any("stuck" in w for w in r.warnings) and any("gyro gaps" in w for w in r.warnings)
    assert sum("stuck" in w for w in r.warnings) == 1  # one warning, not one per interval
    assert m["ate"]["rmse"] <= 0.20, m["ate"]  # measured 0.124 m (one lap, no loops: the 3 % scale dominates)
    cfg.topics.imu = "none"  # the same log with its IMU ignored: runs as without one
    r2 = run_slam(path, cfg)
    assert summary(r2)["imu"]["samples"] == 0 and summary(r2)["gyro_bias_deg_s"] is None
    assert not any("gyro" in w for w in r2.warnings)
