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


def _small_block(walls, reach, drift: float = 0.5, seed: int = 0, back_at: float = 4.0):
    """A first pass along the corridor (x 2–10 m: one submap of 40 nodes), 14 m round a block elsewhere (a corridor far
    away: the next submap and most of the open one), then one node back at the corridor's start heading on as before,
    its estimate `drift` m off along +x: the place is two submaps back, which `loop_min_separation` skips."""
    cfg = GraphConfig()
    rng = np.random.default_rng(seed)
    g = PoseGraph(cfg)
    lc = LoopCloser(cfg)
    lc.frontend_reach = reach
    lc.sensor_fov = WIDE["fov"]

    def node(est, true, w):
        i = g.add_node(est)
        lc.add_node(Keyframe(i, i, i, est, _scan(w, true, rng, **WIDE)), g)
        return i

    for x in np.arange(2.0, 9.9, 0.2):
        node(np.array([x, 0.1, 0.0]), np.array([x, 0.1, 0.0]), walls)
    far = walls + np.array([0.0, 100.0, 0.0, 100.0])
    for x in np.arange(10.0, 24.0, 0.2):
        node(np.array([x, 100.1, 0.0]), np.array([x, 100.1, 0.0]), far)
    true = np.array([back_at, -0.1, 0.0])
    i = node(true + np.array([drift, 0.0, 0.0]), true, walls)
    assert len(lc.submaps) - cfg.loop_min_separation <= 0  # the count rule alone leaves no submap to search
    return lc, lc.search(i, g), true


def test_a_place_few_submaps_back_but_beyond_the_front_ends_reach_is_searched_and_closed():
    """Round a small block back to the start: within the submaps `loop_min_separation` skips, but every node of the
    first submap lies further back along the path than the front end's local map reaches (4.2 m: 2 × 14 keyframes of
    0.15 m), so it is searched, and the loop lies at the true place; without the reach (count rule only) nothing is."""
    walls = _walls(doors_top=[3.5, 7.0, 15.0], doors_bottom=[5.5, 12.0], length=30.0)
    lc, found, true = _small_block(walls, reach=4.2)
    assert found, lc.stats
    for f in found:
        p = se2.compose(np.array([2.0 + 0.2 * f.a, 0.1, 0.0]), f.rel)
        assert abs(p[0] - true[0]) < 0.2 and abs(p[1] - true[1]) < 0.05, (p, true)
    lc0, found0, _ = _small_block(walls, reach=None)
    assert not found0 and lc0.stats.searches == 0, lc0.stats


def test_a_place_driven_on_from_is_not_a_revisit_and_a_place_come_back_to_is():
    """Straight on along a corridor, the submaps just left lie within the radius but the path from them is the straight
    way (no revisit: never a candidate); after turning back, the path to the same places exceeds the straight way by
    more than the front end's reach, and they are."""
    cfg = GraphConfig()
    rng = np.random.default_rng(1)
    walls = _walls(doors_top=[3.5, 7.0, 15.0], doors_bottom=[5.5, 12.0], length=40.0)
    g = PoseGraph(cfg)
    lc = LoopCloser(cfg)
    lc.frontend_reach, lc.sensor_fov = 4.2, WIDE["fov"]

    def node(pose):
        i = g.add_node(np.asarray(pose, dtype=float))
        lc.add_node(Keyframe(i, i, i, g.est[i], _scan(walls, g.est[i], rng, **WIDE)), g)
        return i

    for k in range(85):  # submaps 0 (x 2–9.8 m) and 1 (10–17.8 m) finished, 5 nodes into the open one
        i = node([2.0 + 0.2 * k, 0.1, 0.0])
    near = lc._recent_revisits(i, g.est[i], g, len(lc.submaps) - cfg.loop_min_separation)
    assert [s for s, _ in near] == [0, 1] and all(math.isinf(d) for _, d in near), near
    for k in range(30):  # turned back: 6 m towards the start
        i = node([18.8 - 0.2 * k, -0.1, math.pi])
    near = dict(lc._recent_revisits(i, g.est[i], g, len(lc.submaps) - cfg.loop_min_separation))
    # the nearest nodes: submap 1's at the same x (0.2 m across), submap 0's last (x 9.8 m)
    assert abs(near[1] - 0.2) < 1e-6 and abs(near[0] - math.hypot(g.est[i, 0] - 9.8, 0.2)) < 1e-6, (near, g.est[i])
