"""Gyro integration (backend/imu.py) and the gyro / odometry-scale factors of the pose graph (backend/graph.py)."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from kosmap.backend.graph import BIAS_KEY, SCALE_KEY, GraphConfig, PoseGraph, _gyro_error, _scale_error
from kosmap.backend.imu import GyroBuffer, yaw_sigma
from kosmap.frontend import se2

T0 = 1_700_000_000_000_000_000


def _buffer(rate_fn, t_end=5.0, hz=200.0, **kw) -> GyroBuffer:
    g = GyroBuffer(**kw)
    for t in np.arange(0.0, t_end, 1.0 / hz):
        g.add(T0 + int(round(t * 1e9)), rate_fn(t))
    return g


def test_constant_and_linear_rate_integrate_exactly():
    g = _buffer(lambda t: 0.3, stuck_s=1e6)  # a noiseless constant rate would otherwise look stuck
    a, b = T0 + 123_456_789, T0 + 3_210_987_654  # between samples at both ends
    inc = g.integrate(a, b)
    assert inc.ok and inc.dyaw == pytest.approx(0.3 * (b - a) * 1e-9, abs=1e-12)
    g = _buffer(lambda t: 0.1 + 0.2 * t)  # the trapezoid rule is exact for a rate linear in time
    ta, tb = 0.123456789, 3.210987654
    exact = 0.1 * (tb - ta) + 0.1 * (tb ** 2 - ta ** 2)
    assert g.integrate(T0 + 123_456_789, T0 + 3_210_987_654).dyaw == pytest.approx(exact, abs=1e-9)
    assert g.integrate(T0 + 10**9, T0 + 10**9).dyaw == 0.0


def test_uncovered_gap_and_stuck_intervals_give_no_increment():
    rng = np.random.default_rng(0)
    g = GyroBuffer(max_gap_s=0.1, stuck_s=1.0)
    for t in np.arange(0.0, 10.0, 0.005):
        if 3.0 <= t < 3.5:
            continue  # a 0.5 s gap
        w = 0.25 if 6.0 <= t < 7.5 else 0.2 + 0.001 * rng.standard_normal()  # stuck for 1.5 s
        g.add(T0 + int(round(t * 1e9)), w)
    s = lambda t: T0 + int(t * 1e9)  # noqa: E731
    assert g.integrate(s(1.0), s(2.0)).ok
    assert g.integrate(s(2.9), s(3.6)).reason == "gap"
    assert g.integrate(s(6.5), s(6.8)).reason == "stuck"
    assert g.integrate(s(5.0), s(6.2)).reason == "stuck"  # overlaps the stuck run
    assert g.integrate(s(8.0), s(9.0)).ok
    assert g.integrate(s(9.0), s(11.0)).reason == "uncovered"
    assert len(g.stuck) == 1 and g.stuck[0][1] - g.stuck[0][0] >= 1.4e9
    g.add(s(1.0), 0.0)  # out of order: dropped, counted
    assert g.dropped == 1


def test_yaw_sigma():
    # white noise 0.01 °/s/√Hz over 4 s: 0.02°; the bias term 0.05 °/s × 4 s = 0.2°
    assert math.degrees(yaw_sigma(4.0, math.radians(0.01), 0.0, 0.0)) == pytest.approx(0.02)
    assert math.degrees(yaw_sigma(4.0, 0.0, math.radians(0.05), 0.0)) == pytest.approx(0.2)


@pytest.mark.parametrize("which", ["scale", "gyro"])
def test_custom_factor_jacobians_match_numeric(which):
    v = gtsam.Values()
    v.insert(0, gtsam.Pose2(1.0, 2.0, 0.5))
    v.insert(1, gtsam.Pose2(1.2, 2.3, 0.9))
    key = SCALE_KEY if which == "scale" else BIAS_KEY
    v.insert(key, np.array([1.02 if which == "scale" else 0.001]))
    f = (gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [0, 1, key], _scale_error(np.array([0.3, 0.05, 0.2])))
         if which == "scale" else gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [0, 1, key], _gyro_error(0.35, 2.0)))
    A, _ = f.linearize(v).jacobian()
    e0 = f.unwhitenedError(v)
    J = np.zeros_like(A)
    eps = 1e-6
    for k, kk in enumerate((0, 1)):
        for j in range(3):
            d = np.zeros(3)
            d[j] = eps
            v2 = gtsam.Values(v)
            v2.update(kk, v.atPose2(kk).retract(d))
            J[:, 3 * k + j] = (f.unwhitenedError(v2) - e0) / eps
    v2 = gtsam.Values(v)
    v2.update(key, v.atVector(key) + eps)
    J[:, 6] = (f.unwhitenedError(v2) - e0) / eps
    assert np.abs(A - J).max() < 1e-5


def corridor_loop(seed: int = 0, laps: int = 2, scale: float = 1.03, bias_deg_s: float = 0.02):
    """A 30 × 10 m corridor loop driven `laps` times at 0.5 m/s, one node per 0.2 s: truth; wheel odometry
    (translation × `scale`, yaw 1 °/√m noise + 0.1 °/m bias); a narrow-scan front end (across-track and yaw
    good, along-track blind except near the corridor ends); a gyro (0.005 °/s/√Hz, constant bias); loops
    between laps at the corners. Returns the truth and a function building and solving the graph."""
    rng = np.random.default_rng(seed)
    corners = [(0, 0), (30, 0), (30, 10), (0, 10)]
    poses = []
    for _ in range(laps):
        for k in range(4):
            (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
            th = math.atan2(y1 - y0, x1 - x0)
            n = int(round(math.hypot(x1 - x0, y1 - y0) / 0.1))
            poses += [(x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n, th) for i in range(n)]
            poses += [(x1, y1, th + (math.pi / 2) * i / 9) for i in range(1, 9)]  # turn in place, 10° steps
    truth = np.array(poses)
    truth[:, 2] = se2.wrap(truth[:, 2])
    dt = 0.2
    rel = [se2.between(a, b) for a, b in zip(truth[:-1], truth[1:])]
    odo, match, gyro = [], [], []
    bias = math.radians(bias_deg_s)
    for i, d in enumerate(rel):
        dist = math.hypot(d[0], d[1])
        odo.append(np.array([d[0] * scale + rng.normal(0, 0.005 * math.sqrt(dist)), d[1] * scale,
                             d[2] + math.radians(0.1) * dist + rng.normal(0, math.radians(1.0) * math.sqrt(dist + 1e-4))]))
        p = truth[i + 1]
        near_end = min(abs(p[0] - c[0]) + abs(p[1] - c[1]) for c in corners) < 4.5  # a wall ahead within reach
        s_along = 0.002 if near_end else 1.0
        sig = np.array([s_along, 0.005, math.radians(0.3)])
        match.append((d + rng.normal(0, np.minimum(sig, 0.05)), np.diag(sig ** 2)))
        gyro.append(d[2] + bias * dt + rng.normal(0, math.radians(0.005) * math.sqrt(dt)))
    per_lap = len(truth) // laps
    loops = [(i, i + per_lap) for i in range(0, per_lap, 25) if i + per_lap < len(truth)]

    def solve(use_gyro: bool, **cfg) -> tuple[np.ndarray, PoseGraph]:
        g = PoseGraph(GraphConfig(**{"odom_sigma_xy": 0.002, "odom_sigma_xy_per_m": 0.01, **cfg}))  # honest wheels
        g.add_node(truth[0])
        for i, d in enumerate(rel):
            g.add_node(se2.compose(g.est[i], odo[i]))
            g.add_match(i, i + 1, match[i][0], cov=match[i][1])
            g.add_odometry(i, i + 1, odo[i])
            if use_gyro:
                g.add_gyro(i, i + 1, gyro[i], dt, odo[i][:2])
        for a, b in loops:
            g.add_loop(a, b, se2.between(truth[a], truth[b]) + rng.normal(0, [0.02, 0.02, 0.003]))
        g.optimize()
        return g.est.copy(), g

    return truth, solve


def _ate(est, truth):
    return float(np.sqrt(np.mean(np.sum((est[:, :2] - truth[:, :2]) ** 2, axis=1))))


def test_corridor_loop_gyro_beats_without_and_scale_is_recovered():
    truth, solve = corridor_loop(seed=0)
    est_no, g_no = solve(False)
    est_gy, g_gy = solve(True)
    est_fixed, _ = solve(True, odom_scale="fixed", gyro_bias="fixed")
    a_no, a_gy, a_fixed = _ate(est_no, truth), _ate(est_gy, truth), _ate(est_fixed, truth)
    assert a_gy < 0.5 * a_no, (a_gy, a_no)
    assert a_gy < a_fixed, (a_gy, a_fixed)  # estimating the scale and the bias pays
    assert a_gy <= 0.10, a_gy
    assert abs(g_gy.odom_scale - 1.03) <= 0.002, g_gy.odom_scale  # the injected 3 % within 0.2 %
    assert math.degrees(g_gy.gyro_bias) == pytest.approx(0.02, abs=0.01)
    assert math.degrees(g_no.gyro_bias) == 0.0  # no gyro factors: no bias variable


def _running_vs_batch(rebase: bool, seed: int = 0) -> tuple[float, float]:
    """A 20 × 10 m rectangle driven twice at 0.5 m/s (a node per 0.4 s), built incrementally as Slam does (ISAM2 every
    25 nodes, a calibration every 100) with an uncalibrated gyro bias of 0.1 °/s: the largest yaw difference between
    the running estimate after the last calibration and the batch solution of the same graph, and the bias found."""
    rng = np.random.default_rng(seed)
    corners = [(0, 0), (20, 0), (20, 10), (0, 10)]
    poses = []
    for _ in range(2):
        for k in range(4):
            (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
            th = math.atan2(y1 - y0, x1 - x0)
            n = int(round(math.hypot(x1 - x0, y1 - y0) / 0.2))
            poses += [(x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n, th) for i in range(n)]
            poses += [(x1, y1, th + (math.pi / 2) * i / 9) for i in range(1, 9)]
    truth = np.array(poses)
    dt, bias = 0.4, math.radians(0.1)
    g = PoseGraph(GraphConfig(calibrate_rebase=rebase, gyro_bias_walk_deg_s=0.0))  # one constant bias
    g.add_node(truth[0])
    n_cal = 100 * ((len(truth) - 1) // 100)
    for i in range(n_cal):
        d = se2.between(truth[i], truth[i + 1])
        m = d + rng.normal(0, [0.005, 0.005, math.radians(0.1)])
        g.add_node(se2.compose(g.est[i], m))
        g.add_match(i, i + 1, m, sigmas=np.array([0.01, 0.01, math.radians(0.1)]))
        g.add_odometry(i, i + 1, d + rng.normal(0, [0.01, 0.01, math.radians(0.5)]))
        g.add_gyro(i, i + 1, d[2] + bias * dt + rng.normal(0, math.radians(0.005) * math.sqrt(dt)), dt, d[:2])
        if (i + 1) % 25 == 0:
            g.update()
        if (i + 1) % 100 == 0:
            g.calibrate(rebase=rebase)
    running = g.est.copy()
    g.optimize()
    return float(np.abs(np.degrees(se2.wrap(running[:, 2] - g.est[:, 2]))).max()), math.degrees(g.gyro_bias)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calibrating_while_running_rebases_the_running_estimate(seed):
    """Without the rebase the yaw the uncalibrated gyro factors put in stays in the running estimate, which the loop
    search starts from; with it the running estimate is the batch solution after each calibration."""
    kept, b = _running_vs_batch(False, seed)
    rebased, _ = _running_vs_batch(True, seed)
    assert b == pytest.approx(0.1, abs=0.02)
    assert kept > 2.0 and rebased < 0.3, (rebased, kept)


def test_add_many_is_add_of_each():
    """GyroBuffer.add_many gives the buffer, stuck runs and drop count that `add` of each sample gives: a clean stream
    (appended at once), and streams with a repeated value, a stuck stretch, NaN and out-of-order stamps (one by one)."""
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.integers(4_000_000, 6_000_000, 600)).astype(np.int64)
    w = rng.normal(0, 0.2, 600)
    streams = [w.copy()]
    s = w.copy()
    s[100:400] = 0.125  # stuck for 1.5 s
    streams.append(s)
    s = w.copy()
    s[50] = np.nan
    s[51] = s[52]
    streams.append(s)
    found = []
    for k, rates in enumerate(streams):
        stamps = t.copy()
        if k == 2:
            stamps[300] = stamps[299]  # a duplicate stamp
        one, many = GyroBuffer(), GyroBuffer()
        for a, b in zip(stamps.tolist(), rates.tolist()):
            one.add(a, b)
        for lo, hi in ((0, 7), (7, 250), (250, 251), (251, 600)):  # pieces, as a log's stretches come
            many.add_many(stamps[lo:hi], rates[lo:hi])
        assert (many.t, many.w, many.stuck, many.dropped, many._run_start) == (one.t, one.w, one.stuck, one.dropped,
                                                                              one._run_start), k
        found.append((len(one.stuck), one.dropped))
    assert found == [(0, 0), (1, 0), (0, 2)]  # the stuck stretch found, the NaN and the duplicate dropped
