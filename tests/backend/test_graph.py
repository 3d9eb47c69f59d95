"""The pose graph: a square trajectory with drifting odometry, true loops and injected false loops."""

from __future__ import annotations

import math

import numpy as np

from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.metrics import ate
from kosmap.frontend import se2


def _square(n_side: int = 40, step: float = 0.25) -> np.ndarray:
    poses = []
    x = y = th = 0.0
    for _lap in range(2):
        for _side in range(4):
            for _ in range(n_side):
                poses.append((x, y, th))
                x += step * math.cos(th)
                y += step * math.sin(th)
            th += math.pi / 2
    return np.array(poses)


def _build(kernel: str, n_false: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    truth = _square()
    n = len(truth)
    g = PoseGraph(GraphConfig(robust_kernel=kernel))
    est = truth[0].copy()
    g.add_node(est)
    for i in range(1, n):
        d = se2.between(truth[i - 1], truth[i])
        noisy = d + np.array([rng.normal(0, 0.01), rng.normal(0, 0.01), rng.normal(0, math.radians(1.0))])
        est = se2.compose(est, noisy)
        g.add_node(est)
        g.add_match(i - 1, i, noisy, np.array([0.01, 0.01, math.radians(1.0)]))
    # true loops: the second lap sees the first
    half = n // 2
    for i in range(0, half, 5):
        g.add_loop(i, i + half, se2.between(truth[i], truth[i + half]))
    # false loops: random pairs far apart, with plausible-looking (small) measurements
    for _ in range(n_false):
        a, b = rng.integers(0, n, 2)
        g.add_loop(int(a), int(b), np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3)]))
    g.optimize()
    return truth, g.est.copy()


def test_false_loops_do_not_break_the_graph_with_cauchy():
    truth, clean = _build("cauchy", n_false=0)
    t = np.arange(len(truth), dtype=float)
    base = ate(t, clean, t, truth)["rmse"]  # the odometry noise is what remains
    for kernel in ("cauchy", "gnc"):
        _, est = _build(kernel, n_false=20)
        err = ate(t, est, t, truth)["rmse"]
        assert err < base + 0.01, (kernel, err, base)
    _, plain = _build("none", n_false=20)
    assert ate(t, plain, t, truth)["rmse"] > 1.0  # without a kernel the false loops pull the square apart


def test_incremental_updates_match_the_batch_solution():
    rng = np.random.default_rng(3)
    truth = _square(n_side=20)
    g = PoseGraph(GraphConfig(optimize_every=5))
    est = truth[0].copy()
    g.add_node(est)
    for i in range(1, len(truth)):
        d = se2.between(truth[i - 1], truth[i]) + rng.normal(0, 0.005, 3)
        est = se2.compose(g.est[i - 1], d)
        g.add_node(est)
        g.add_match(i - 1, i, d)
        if i % 5 == 0:
            g.update(full=i >= len(truth) // 2)
        if i >= len(truth) // 2 and i % 4 == 0:
            j = i - len(truth) // 2
            g.add_loop(j, i, se2.between(truth[j], truth[i]))
    g.update(full=True)
    inc = g.est.copy()
    g.optimize()
    assert np.abs(se2.between(inc, g.est)[:, :2]).max() < 0.02
