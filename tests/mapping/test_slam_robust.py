"""SLAM that finishes whatever the log lacks: a 10 s laser blackout, 10 s without wheel odometry, 200+ scans in a
featureless corridor, and a pose graph that gtsam's ISAM2 finds indeterminate. Each run completes, says in one
warning line which stretch of the log (in seconds from the first scan) it had little to go by, and keeps the
trajectory elsewhere as accurate as on a clean log (synthetic worlds with exact ground truth,
tests/mapping/synthetic_laser.py)."""

from __future__ import annotations

import math
import re

import gtsam
import numpy as np
import pytest

from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.metrics import ate
from kosmap.frontend import se2
from kosmap.frontend.records import Odometry, Scan
from kosmap.mapping.config import Config
from kosmap.mapping.slam import run_slam
from tests.frontend.synthetic_log import write_mcap
from tests.mapping.synthetic_laser import T0, cast, make_log, records


@pytest.fixture(scope="module")
def ring():
    return make_log(seed=1)


def _stretch(warnings: list[str], words: str) -> tuple[float, float]:
    """The one warning line holding `words`, and the first stretch it names (t = a–b s)."""
    lines = [w for w in warnings if words in w]
    assert len(lines) == 1, warnings
    m = re.search(r"t = ([\d.]+)–([\d.]+) s", lines[0])
    assert m, lines[0]
    return float(m.group(1)), float(m.group(2))


def _run(tmp_path, recs):
    r = run_slam(write_mcap(recs, tmp_path / "log.mcap"), Config(), "laser")
    return r, r.ground_truth


@pytest.mark.slow
def test_ten_seconds_without_odometry_is_named(ring, tmp_path):
    t_rel = lambda ns: (ns - ring.stamps_ns[0]) * 1e-9  # noqa: E731
    recs = [x for x in records(ring)
            if not (isinstance(x, Odometry) and x.topic == "/odom" and 90.0 < t_rel(x.stamp_ns) < 100.0)]
    r, (tg, pg) = _run(tmp_path, recs)
    a, b = _stretch(r.warnings, "no wheel odometry")
    assert abs(a - 90.0) <= 0.6 and abs(b - 100.0) <= 0.6, (a, b)
    assert not any("scan(s) had no wheel odometry" in w for w in r.warnings)  # the count line is not repeated
    odom = np.isfinite(r.odom_poses[:, 0])
    t = r.stamps - r.stamps[0]
    assert not odom[(t > 90.6) & (t < 99.4)].any()  # never interpolated across the gap
    assert ate(r.stamps, r.poses, tg, pg)["rmse"] <= 0.06


def corridor_log(seed: int = 0, length: float = 60.0, rate: float = 5.0, speed: float = 1.0, max_range: float = 30.0):
    """A 2.5 m corridor with pillars in its first and last 6 m and bare walls between; the robot drives its length
    once. Scans: 181 beams forward over 180° (Intel-like), 1 cm noise, range `max_range`: from x ≈ 5 m the pillars
    behind are out of view and those ahead out of range until x ≈ 26 m from the end. Odometry: 1 % scale error,
    heading noise. Returns (records, stamps ns, truth)."""
    rng = np.random.default_rng(seed)
    segs = [(-8.0, 0.0, length + 8.0, 0.0), (-8.0, 2.5, length + 8.0, 2.5), (-8.0, 0.0, -8.0, 2.5),
            (length + 8.0, 0.0, length + 8.0, 2.5)]
    for x in (-6.0, -3.0, 1.0, 4.0, length - 4.0, length - 1.0, length + 3.0, length + 6.0):
        for y0, y1 in ((0.0, 0.4), (2.1, 2.5)):
            segs += [(x, y0, x + 0.4, y0), (x + 0.4, y0, x + 0.4, y1), (x + 0.4, y1, x, y1), (x, y1, x, y0)]
    segs = np.array(segs)
    n = int(length / speed * rate)
    t = np.arange(n) / rate
    truth = np.column_stack((t * speed, np.full(n, 1.25), np.zeros(n)))
    angles = -math.pi / 2 + np.arange(181) * (math.pi / 180)
    stamps = (T0 + np.round(t * 1e9)).astype(np.int64)
    recs, odom = [], truth[0].copy()
    for k, (ts, pose) in enumerate(zip(stamps, truth)):
        if k:
            d = se2.between(truth[k - 1], pose)
            d[:2] *= 1.01
            d[2] += rng.normal(0, math.radians(0.3) * math.sqrt(abs(d[0]) + 1e-3))
            odom = se2.compose(odom, d)
        r = cast(segs, pose[:2], pose[2] + angles, max_range)
        r = np.where(np.isfinite(r), r + rng.normal(0, 0.01, len(r)), r).astype(np.float32)
        recs.append(Scan(int(ts), r, float(angles[0]), math.pi / 180, 0.1, max_range, "base_link", "/scan"))
        recs.append(Odometry(int(ts) + 1000, *map(float, odom), "odom", "base_link", "/odom"))
        recs.append(Odometry(int(ts) + 2000, *map(float, pose), "map", "base_link", "/ground_truth/odom"))
    return recs, stamps, truth


@pytest.mark.slow
def test_featureless_corridor_is_named_and_held_by_odometry(tmp_path):
    recs, stamps, truth = corridor_log()
    r, (tg, pg) = _run(tmp_path, recs)
    a, b = _stretch(r.warnings, "fixed no position along the way")
    n_blind = int(np.sum((r.stamps - r.stamps[0] >= a) & (r.stamps - r.stamps[0] <= b)))
    assert n_blind >= 200, (a, b, n_blind)  # measured t = 4.4–49.0 s, 223 scans, 45 m
    assert a <= 6.0 and b >= 45.0, (a, b)
    before = (r.stamps - r.stamps[0]) < a - 1.0
    assert ate(r.stamps[before], r.poses[before], tg, pg)["rmse"] <= 0.03
    err = ate(r.stamps, r.poses, tg, pg)
    odom = ate(r.stamps, r.odom_poses, tg, pg)
    assert err["max"] <= 0.5 and err["rmse"] <= 1.5 * odom["rmse"], (err, odom)  # measured 0.21 m (odometry 0.19 m)


def _raw_isam_fails_on(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> bool:
    try:
        gtsam.ISAM2().update(graph, values)
    except RuntimeError as e:
        return "Indeterminate" in str(e)
    return False


def test_graph_chained_by_a_gyro_factor_alone_gets_a_weak_motion_prior():
    """Node 3 is tied to node 2 by the gyro's yaw-only factor alone (x, y σ of a kilometre): ISAM2 as such throws
    gtsam's IndeterminateSystemException; the pose graph chains node 3 with a weak motion prior and solves."""
    g = PoseGraph(GraphConfig())
    truth = np.array([[i * 1.0, 0.1 * i, 0.05 * i] for i in range(6)])
    for p in truth:
        g.add_node(p)
    for i in range(1, 6):
        if i != 3:
            g.add_match(i - 1, i, se2.between(truth[i - 1], truth[i]))
    g.add_gyro(2, 3, 0.05, 0.1)
    raw = gtsam.NonlinearFactorGraph()
    for f in g.factors:
        raw.add(f)
    assert _raw_isam_fails_on(raw, g.initial)  # the failure the 80-minute log met, reproduced
    g.update()
    g.optimize()
    assert g.weak_nodes == [3]
    assert np.abs(g.est - truth).max() < 1e-6


def test_indeterminate_isam_is_re_solved_and_reported():
    """A factor the chain check cannot see makes ISAM2's Cholesky factorisation fail: the graph restarts with QR
    and names the node; the solution equals the truth."""
    g = PoseGraph(GraphConfig())
    truth = np.array([[i * 1.0, 0.0, 0.0] for i in range(4)])
    for p in truth:
        g.add_node(p)
    g.add_match(0, 1, truth[1])
    bad = gtsam.BetweenFactorPose2(1, 2, gtsam.Pose2(1, 0, 0), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e3, 1e3, 1e-3])))
    g.pending.add(bad)
    g.all_factors.add(bad)
    g._chain[2] = np.eye(3)  # (as if it chained node 2: only ISAM2 finds out)
    g.add_match(2, 3, truth[1])
    g.update()
    assert g.factorization == "QR"
    assert g.solver_notes[0][0] == 2 and "Indeterminate" in g.solver_notes[0][1]
    g.optimize()
    assert np.abs(g.est - truth).max() < 1e-6


def test_slam_run_with_an_indeterminate_graph_finishes_with_one_warning(ring):
    """The same through a whole run: ISAM2 fails once mid-run (as on the 80-minute hospital log); the run
    finishes, one warning line names the time, and the trajectory is as good as a clean run's."""
    from kosmap.frontend.odometry import OdometryConfig, scan_points_base
    from kosmap.backend.slam import Slam

    class Flaky:  # ISAM2, failing on its fifth update
        def __init__(self, isam):
            self.isam, self.calls = isam, 0

        def update(self, *args):
            self.calls += 1
            if self.calls == 5:
                raise RuntimeError("\nIndeterminate linear system detected while working near variable\n130 (Symbol: 130).\n")
            return self.isam.update(*args)

        def __getattr__(self, name):
            return getattr(self.isam, name)

    slam = Slam(OdometryConfig(), GraphConfig())
    slam.graph.isam = Flaky(slam.graph.isam)
    n = 600
    for scan, o in zip(ring.scans[:n], ring.odom[:n]):
        slam.add_scan(scan.stamp_ns, scan_points_base(scan.ranges, scan.angles, scan.valid(), ring.mount, 0.1, 30.0), o)
    r = slam.finish()
    lines = [w for w in r.warnings if "pose graph could not be solved" in w]
    assert len(lines) == 1, r.warnings
    t130 = (r.keyframes[130].stamp_ns - r.stamps_ns[0]) * 1e-9
    assert f"near t = {t130:.1f} s" in lines[0]
    assert ate(r.stamps, r.poses, r.stamps, ring.truth[:n])["rmse"] <= 0.05


def _ring_run(ring, gcfg: GraphConfig, wrong_loop: bool = False):
    from kosmap.frontend.odometry import OdometryConfig, scan_points_base
    from kosmap.backend.slam import Slam

    slam = Slam(OdometryConfig(), gcfg)
    n = len(ring.scans)
    for i, (scan, o) in enumerate(zip(ring.scans, ring.odom)):
        slam.add_scan(scan.stamp_ns, scan_points_base(scan.ranges, scan.angles, scan.valid(), ring.mount, 0.1, 30.0), o)
        if wrong_loop and i == 3 * n // 4:  # node 5 claimed 0.9 m and 11° from where the robot is
            slam.graph.add_loop(5, len(slam.keyframes) - 1, np.array([0.8, 0.5, 0.2]))
    r = slam.finish()
    return r, ate(r.stamps, r.poses, r.stamps, ring.truth)["rmse"], slam


@pytest.mark.slow
def test_self_consistency_tells_a_bent_map_from_a_good_one():
    """Without ground truth: the good run's revisits fit the earlier scans within mm and it is not called bent; the
    same keyframes with the second lap turned 2° about the middle (a heading error the loops did not fix) are, and so
    is a run bent by a wrong loop under a plain Gaussian kernel, each with one warning line. The ground truth
    agrees (ATE). The Cauchy kernel keeps the same wrong loop out: not bent."""
    from kosmap.frontend import se2 as S
    from kosmap.backend.consistency import consistency, warning

    ring = make_log(seed=0)
    good, e_good, slam = _ring_run(ring, GraphConfig())
    c = good.consistency
    assert not c["bent"] and c["median_m"] <= 0.01 and c["loops_disagreeing"] == 0, c  # measured 0.003 m
    assert not any("likely bent" in w for w in good.warnings)
    kt = np.array([(k.stamp_ns - good.stamps_ns[0]) * 1e-9 for k in good.keyframes])
    poses = good.graph.est.copy()
    mid = len(poses) // 2
    turn = np.array([0.0, 0.0, math.radians(2.0)])
    pivot = np.array([*poses[mid, :2], 0.0])
    poses[mid:] = S.compose(np.repeat(S.compose(pivot, turn)[None], len(poses) - mid, 0),
                            S.compose(np.repeat(S.inverse(pivot)[None], len(poses) - mid, 0), poses[mid:]))
    bent = consistency(kt, poses, slam.key_points)
    assert bent.bent and bent.median_m > 5 * c["median_m"] and bent.worst_t_s > kt[mid], bent
    assert warning(bent) is not None and f"t = {bent.worst_t_s:.0f} s" in warning(bent)
    wrong, e_wrong, _ = _ring_run(ring, GraphConfig(robust_kernel="none"), True)
    assert wrong.consistency["bent"], wrong.consistency  # measured: 8 of 102 loops missed beyond their covariance
    assert len([w for w in wrong.warnings if "likely bent" in w]) == 1
    assert e_wrong > 10 * e_good, (e_wrong, e_good)  # 4.6 m against 0.031 m
    robust, e_robust, _ = _ring_run(ring, GraphConfig(), True)  # the Cauchy kernel leaves the wrong loop out
    assert not robust.consistency["bent"] and e_robust <= 0.05  # measured 0.031 m


@pytest.mark.slow
def test_laser_blackout_is_named_by_slam_and_build_and_bridged(ring, tmp_path, capsys):
    """10 s without a laser message: the run completes, the stretch's one warning line is on the console, in
    metrics.json and (build) in the report, from both commands, beside the self-consistency figure; the trajectory
    outside the stretch stays as accurate as on the clean log."""
    import json

    from kosmap.backend.trajio import read_tum

    from kosmap.tools.cli import main

    t_rel = (ring.stamps_ns - ring.stamps_ns[0]) * 1e-9
    gone = set(ring.stamps_ns[(t_rel > 60.0) & (t_rel < 70.0)].tolist())
    path = write_mcap([x for x in records(ring) if not (isinstance(x, Scan) and x.stamp_ns in gone)], tmp_path / "log.mcap")
    assert main(["slam", str(path), "--out", str(tmp_path / "s"), "--no-map"]) == 0
    out, err = capsys.readouterr()
    lines = [w for w in err.splitlines() if "no usable scan" in w]
    assert len(lines) == 1 and re.search(r"t = 59\.\d–70\.\d s", lines[0]), err
    t, p = read_tum(tmp_path / "s" / "trajectory.tum")
    rel = t - t[0]
    outside = (rel < 59.0) | (rel > 71.0)
    tg = ring.stamps_ns * 1e-9
    assert ate(t[outside], p[outside], tg, ring.truth)["rmse"] <= 0.05  # measured 0.03 m (the clean log's run alike)
    assert ate(t, p, tg, ring.truth)["rmse"] <= 0.06
    assert "self-consistency: revisits" in out
    run = json.loads((tmp_path / "s" / "metrics.json").read_text())["run"]
    assert sum("no usable scan" in w for w in run["warnings"]) == 1 and len(run["stretches"]["no_scans_s"]) == 1
    assert run["consistency"]["median_m"] < 0.03 and not run["consistency"]["bent"]
    assert main(["build", str(path), "--out", str(tmp_path / "b"), "--workers", "0"]) == 0
    out, err = capsys.readouterr()
    assert sum("laser SLAM: no usable scan" in w for w in err.splitlines()) == 1, err
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert sum("no usable scan" in w for w in m["warnings"]) == 1
    assert m["slam"]["laser"]["stretches"]["no_scans_s"] == run["stretches"]["no_scans_s"]  # the same run
    assert "no usable scan" in (tmp_path / "b" / "report.md").read_text()
    assert "consistency   laser SLAM" in out


def test_a_pause_in_the_scans_while_the_robot_stands_is_no_blackout():
    """A logger that pauses while the robot stands or creeps (the Intel log: 2–3 s, dozens of times, the wheels
    moving up to 12 cm) leaves no stretch to report; the same gap while the wheels moved 1 m is one."""
    from kosmap.backend.slamhealth import HealthTracker

    h = HealthTracker(expect_odom=True)
    for t, x in ((0.0, 0.0), (0.1, 0.01), (3.1, 0.13), (3.2, 0.14), (6.2, 1.14)):
        h.scan(int(T0 + t * 1e9), True, np.array([x, 0.0, 0.0]))
    st = h.finish(np.array([T0]), [], [])
    assert st.no_scans == [(int(T0 + 3.2e9), int(T0 + 6.2e9))]
