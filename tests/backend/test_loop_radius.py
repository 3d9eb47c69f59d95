"""The loop candidates' radius grows with the pose uncertainty the graph's own factors accumulated since the last
accepted loop (backend/loops.py DriftModel.radius, propagate): a robot that comes back to a mapped corridor from
elsewhere with its estimate 1.5 m off is searched against it, at the right place, and a corridor of repeated doors
does not give a loop at a look-alike door."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.keyframes import Keyframe
from kosmap.backend.loops import DriftModel, LoopCloser, propagate
from kosmap.frontend import se2
from tests.backend.test_loops import _scan, _walls

WIDE = dict(beams=361, rmax=30.0, fov=math.radians(180.0))


def test_the_radius_grows_with_the_chains_uncertainty_and_restarts_at_a_loop():
    cfg = GraphConfig()
    d = DriftModel(cfg)
    xs = np.arange(0.0, 45.01, 0.2)
    for x in xs:
        d.travel_to(np.array([x, 0.0, 0.0]))
    # straight ahead, the yaw σ of each step turns into a sideways σ growing with the distance still to go: the
    # closed form Σ σ_yaw² (L − x_i)², beside the loop σ the chain started from
    s_yaw = math.radians(cfg.match_sigma_yaw_deg)
    L = xs[-1]
    lateral = (cfg.loop_sigma_xy ** 2 + (math.radians(cfg.loop_sigma_yaw_deg) * L) ** 2
               + np.sum((s_yaw * (L - xs[1:])) ** 2) + len(xs[1:]) * (cfg.match_sigma_xy + cfg.match_sigma_xy_per_m * 0.2) ** 2)
    assert abs(d.position_sigma() - math.sqrt(lateral)) < 1e-3 * math.sqrt(lateral), (d.position_sigma(), math.sqrt(lateral))
    assert abs(d.radius() - (cfg.loop_search_radius + 3.0 * d.position_sigma())) < 1e-9
    assert d.radius() > 9.0  # 45 m from the last loop: 4 m + 3 × 1.88 m
    d.reset()  # a loop: the chain starts again from the loop's own σ
    assert d.radius() < cfg.loop_search_radius + 0.2
    # the adjoint: a yaw error at the old pose is a sideways error 1 m further on
    c = propagate(np.diag([0.0, 0.0, 0.01 ** 2]), np.array([1.0, 0.0, 0.0]), np.zeros(3))
    assert abs(c[1, 1] - 0.01 ** 2) < 1e-12 and abs(c[0, 0]) < 1e-12


def _come_back(walls, first_until: float, back_at: float, drift: float, cfg: GraphConfig, seed: int = 0):
    """A first pass along the corridor (x from 2 m, exact poses), 60 m of travel elsewhere (a corridor far away),
    then one node back in the corridor at `back_at` facing −x, its estimate `drift` metres off along +x."""
    rng = np.random.default_rng(seed)
    g = PoseGraph(cfg)
    lc = LoopCloser(cfg)
    k = 0

    def node(est, true, w):
        nonlocal k
        i = g.add_node(est)
        lc.add_node(Keyframe(i, i, k, est, _scan(w, true, rng, **WIDE)), g)
        k += 1
        return i

    for x in np.arange(2.0, first_until, 0.2):
        node(np.array([x, 0.1, 0.0]), np.array([x, 0.1, 0.0]), walls)
    far = walls + np.array([0.0, 100.0, 0.0, 100.0])
    for x in np.arange(first_until, first_until + 60.0, 0.2):
        node(np.array([x, 100.1, 0.0]), np.array([x, 100.1, 0.0]), far)
    true = np.array([back_at, -0.1, math.pi])
    i = node(true + np.array([drift, 0.0, 0.0]), true, walls)
    reach = (lc.drift.radius(), lc.drift.window())  # before the search (an accepted loop restarts them)
    return lc, lc.search(i, g), true, reach


def test_a_robot_coming_back_with_a_drifted_estimate_closes_the_loop_at_the_right_place():
    walls = _walls(doors_top=[6.0, 13.0, 19.5, 27.0, 36.0, 44.0, 51.0], doors_bottom=[9.0, 24.0, 40.0, 48.0], length=60.0)
    cfg = GraphConfig()
    lc, found, true, (radius, window) = _come_back(walls, 40.0, 46.0, 1.5, cfg)
    nearest = 47.5 - 39.8  # from the estimate to the first pass's last node
    centre_reach = cfg.loop_search_radius + window - cfg.loop_linear_window  # 4 m + the window's growth
    assert centre_reach < nearest < radius, (centre_reach, nearest, radius)
    assert found, lc.stats
    for f in found:
        p = se2.compose(np.array([2.0 + 0.2 * f.a, 0.1, 0.0]), f.rel)
        assert abs(p[0] - true[0]) < 0.2 and abs(p[1] - true[1]) < 0.05, (p, true)


def test_repeated_doors_give_no_loop_at_a_look_alike():
    """Doors every 3 m on both walls and an estimate 1.5 m off: the window holds the true place and look-alike door
    rows 3 m either side; whatever is accepted lies at the true place."""
    doors = list(np.arange(4.0, 58.0, 3.0))
    walls = _walls(doors_top=doors, doors_bottom=doors, length=60.0)
    lc, found, true, _ = _come_back(walls, 40.0, 46.0, 1.5, GraphConfig())
    assert lc.stats.searches > 0, lc.stats  # the submaps with the look-alikes were searched
    assert found or lc.stats.rejected_ambiguous + lc.stats.rejected_edge > 0, lc.stats  # ... and refused as such
    for f in found:
        p = se2.compose(np.array([2.0 + 0.2 * f.a, 0.1, 0.0]), f.rel)
        assert abs(p[0] - true[0]) < 0.2, (p, true, lc.stats)
