"""The self-consistency check (backend/consistency.py) on a narrow-scan KOS run: the simulated office (361 s, the
corridor ring with two loops; one Kinect, 70.6° and ≤ 4.5 m, at 5 Hz and half resolution to keep CI short) mapped by
KOS SLAM is a good map and is not called bent; the same recorded scans mapped on odometry and scan matching alone
(loop closure, the gyro and the wall headings off, the front end held to the wheels) are bent, and are called so.
The ground truth (ATE) agrees. Also
the rule's parts on their own: the scan's measured noise and the loop's own covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.backend.consistency import LoopCheck, consistency, scan_noise
from kosmap.frontend import se2


def _replay(doc: dict, odometry: dict | None = None, **graph):
    """KOS SLAM on the recorded SlamFeed calls of a run with [graph] overrides: the benchmark's own replay
    (tools/bench_kos_slam.replay_slam, at the rate the run was recorded), and its ATE against the recorded truth."""
    from kosmap.mapping.slam import evaluate
    from kosmap.tools.bench_kos_slam import replay_slam

    r, _ = replay_slam(doc, RATE, odometry, **graph)
    return r, evaluate(r)["ate"]["rmse"]


RATE = 5.0  # Hz: the depth rate the office is simulated and recorded at (half resolution, to keep CI short)


@pytest.mark.slow
def test_a_good_narrow_scan_map_is_not_called_bent_and_a_drifted_one_is(tmp_path):
    from kosmap.tools.bench_kos_slam import record
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "office.mcap"
    simulate(load_world("office"), SimConfig(seed=0, depth_rate=RATE, depth_width=256, depth_height=212, laser=False,
                                             compression="lz4"), log)
    doc = record(log, RATE, tmp_path / "cache")
    good, e_good = _replay(doc)
    c = good.consistency
    assert e_good <= 0.08, e_good
    assert c["loops"] >= 2 and c["revisit_keyframes"] >= 20, c
    assert not c["bent"] and c["median_m"] < c["tolerance_m"], c
    assert not any("likely bent" in w for w in good.warnings), good.warnings
    # odometry and matching alone, the front end held to the wheels along-track: ATE 0.24 m, 18 revisits, bent. With
    # the default front end (free along-track where the scan fixes it) the same run is 0.20 m off with 3 revisits:
    # too few for the check to decide, and called ok (docs/consistency.md)
    drift, e_drift = _replay(doc, {"prior_weight_along": 1000.0, "degenerate_ratio": 0.0},
                             loop_closure=False, imu=False, manhattan=False)
    d = drift.consistency
    assert e_drift >= 2 * e_good and e_drift >= 0.08, (e_drift, e_good)
    assert d["bent"] and d["median_m"] > 2 * c["median_m"], d
    assert len([w for w in drift.warnings if "likely bent" in w]) == 1


def test_scan_noise_is_measured_on_the_scan():
    """A wall sampled along its length with σ of normal noise: the measured scatter is σ (±20 %; its spread over
    seeds is 9–19 % on 60–200 points), whatever the point spacing; a corner does not count; a clean wall scatters
    nothing."""
    rng = np.random.default_rng(0)
    for sigma, step in ((0.002, 0.03), (0.01, 0.1), (0.03, 0.05)):
        x = np.arange(0.0, 20.0, step)
        wall = np.column_stack((x, 2.0 + rng.normal(0.0, sigma, len(x))))
        corner = np.column_stack((np.full(20, 20.0), 2.0 - np.arange(1, 21) * step))  # a second wall, at right angles
        s = scan_noise(np.vstack((wall, corner)))
        assert abs(s - sigma) <= 0.2 * sigma, (s, sigma)
    assert scan_noise(np.column_stack((np.arange(0, 3, 0.05), np.full(60, 1.0)))) < 1e-9


def test_a_loop_is_missed_against_its_own_covariance():
    """A loop 0.2 m off across: missed under a 0.05 m σ (4σ); not missed when the loop closer gave it a loose σ (1 m)
    along that direction (a corridor's axis), which the fixed-σ rule counted as missed."""
    tight = np.diag([0.05 ** 2, 0.05 ** 2, math.radians(1.0) ** 2])
    loose = tight.copy()
    loose[0, 0] = 1.0
    err = np.array([0.2, 0.0, 0.0])
    assert LoopCheck(err, tight).missed() and not LoopCheck(err, loose).missed()
    assert not LoopCheck(np.array([0.0, 0.12, 0.0]), tight).missed()  # 2.4σ on one axis: within 99 % (χ²₂)
    # three of twenty loops missed: bent; the same under their loose covariance: not
    t = np.arange(10.0)
    poses = np.column_stack((t, np.zeros(10), np.zeros(10)))
    pts = [np.zeros((0, 2))] * 10
    checks = [LoopCheck(err if k < 3 else np.zeros(3), tight) for k in range(20)]
    assert consistency(t, poses, pts, checks).bent
    assert not consistency(t, poses, pts, [LoopCheck(c.error, loose) for c in checks]).bent


def test_the_tolerance_is_the_runs_grid_cell():
    """A room seen again 35 s later with every revisit placed 7 cm off each wall (noise-free walls): bent on a 5 cm grid
    (the walls doubled by more than a cell), not on a 10 cm grid (one wall in the map); the tolerance is the cell given."""
    side = np.arange(0.0, 6.0, 0.05)
    walls = np.vstack([np.column_stack((side, np.zeros_like(side))), np.column_stack((side, np.full_like(side, 6.0))),
                       np.column_stack((np.zeros_like(side), side)), np.column_stack((np.full_like(side, 6.0), side))])
    true = np.array([[1.5 + 0.3 * k, 2.0 + 0.2 * (k % 3), 0.1 * k] for k in range(10)] * 2)
    t = np.concatenate([np.arange(10.0), 45.0 + np.arange(10.0)])
    solved = true.copy()
    solved[10:, :2] += [0.07, 0.07]  # 7 cm across each wall
    pts = [se2.transform_points(se2.inverse(p), walls)[::3] for p in true]
    for cell, bent in ((0.05, True), (0.10, False)):
        c = consistency(t, solved, pts, cell=cell)
        assert c.revisit_keyframes == 10 and c.bent is bent, (cell, c)
        assert abs(c.tolerance_m - cell) < 0.01, (cell, c.tolerance_m)
        assert 0.06 < c.median_m < 0.08, c.median_m
