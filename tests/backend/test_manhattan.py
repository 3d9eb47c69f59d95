"""Manhattan-world heading priors (backend/manhattan.py): wall directions from a scan, the axes, the gate, and what
the priors do to a drifting graph (backend/graph.py add_heading)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.manhattan import ManhattanHeading, wall_direction, wrap_quarter
from kosmap.frontend import se2


def room_scan(pose, rng, half=(3.0, 2.0), rotation=0.0, fov_deg=70.0, beams=320, noise=0.005) -> np.ndarray:
    """A forward scan (bearing order, robot frame) from `pose` inside a rectangular room of half sizes `half`,
    rotated by `rotation` about the origin, with range noise."""
    c, s = math.cos(rotation), math.sin(rotation)
    x0, y0 = c * pose[0] + s * pose[1], -s * pose[0] + c * pose[1]  # the pose in the room's own frame
    out = []
    for b in np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, beams)):
        a = pose[2] + b - rotation
        dx, dy = math.cos(a), math.sin(a)
        ts = [t for t in ((half[0] - x0) / dx if dx > 1e-9 else math.inf, (-half[0] - x0) / dx if dx < -1e-9 else math.inf,
                          (half[1] - y0) / dy if dy > 1e-9 else math.inf, (-half[1] - y0) / dy if dy < -1e-9 else math.inf)]
        r = min(ts) + rng.normal(0, noise)
        out.append((r * math.cos(b), r * math.sin(b)))
    return np.array(out)


@pytest.mark.parametrize("yaw_deg", [0.0, 7.3, 33.0, -20.0, 95.5])
def test_wall_direction_is_the_walls_heading_modulo_90(yaw_deg):
    rng = np.random.default_rng(1)
    pts = room_scan((0.5, -0.3, math.radians(yaw_deg)), rng)
    d = wall_direction(pts)
    assert d is not None and d[1] >= 5
    # walls along the room's axes (0° and 90°) appear at −yaw in the robot frame
    assert abs(math.degrees(wrap_quarter(d[0] + math.radians(yaw_deg)))) < 0.3, math.degrees(d[0])


def test_no_straight_walls_no_direction():
    rng = np.random.default_rng(2)
    a = np.linspace(-0.6, 0.6, 300)
    circle = np.c_[2.0 * np.cos(a), 2.0 * np.sin(a)] + rng.normal(0, 0.003, (300, 2))  # a round pillar's face
    assert wall_direction(circle) is None
    assert wall_direction(rng.uniform(-3, 3, (300, 2))) is None  # clutter
    assert wall_direction(np.zeros((5, 2))) is None


def test_axes_are_fixed_then_headings_follow_and_the_gate_holds():
    rng = np.random.default_rng(3)
    rot = math.radians(12.0)  # the building is turned 12° in the map frame
    h = ManhattanHeading()
    for k in range(h.init_keyframes):
        y = rng.uniform(-math.pi, math.pi)
        assert h.observe(y, room_scan((0.2, 0.1, y), rng, rotation=rot)) is None  # fixing the axes
    assert h.stats.axis_deg == pytest.approx(12.0, abs=0.3)
    y_true = math.radians(40.0)
    pts = room_scan((0.2, 0.1, y_true), rng, rotation=rot)
    got = h.observe(y_true + math.radians(3.0), pts)  # the running estimate 3° off: the walls say where it is
    assert got is not None and abs(math.degrees(se2.wrap(got - y_true))) < 0.3
    assert h.observe(y_true + math.radians(9.0), pts) is None and h.stats.off_axis == 1  # beyond the 5° gate
    assert h.stats.priors == 1 and not h.stats.disabled


def test_a_building_that_is_not_manhattan_gets_no_priors():
    rng = np.random.default_rng(4)
    h = ManhattanHeading()
    for k in range(h.init_max_keyframes):  # every room turned its own way
        assert h.observe(0.0, room_scan((0.0, 0.0, 0.3), rng, rotation=rng.uniform(0, math.pi / 2))) is None
    assert h.stats.axis_deg is None and "not a Manhattan building" in h.stats.disabled
    assert h.observe(0.0, room_scan((0.0, 0.0, 0.3), rng)) is None and h.stats.priors == 0


def test_heading_priors_hold_a_drifting_chain_and_keep_its_start():
    """A 300-node chain whose yaw steps carry a 0.05°/step bias (an unmodelled gyro bias): without priors the yaw at
    the end is off by the bias times the steps; with heading priors (σ 1°, the true yaw modulo 90° plus 0.3° noise)
    it is held, and the solution still starts at the first node's pose."""
    rng = np.random.default_rng(5)
    n = 300
    truth = np.zeros((n, 3))
    for i in range(1, n):
        turn = math.radians(90.0) if i % 75 == 0 else 0.0
        truth[i] = se2.compose(truth[i - 1], np.array([0.2, 0.0, turn]))
    truth = se2.compose(np.repeat(np.array([[1.0, 2.0, math.radians(3.0)]]), n, 0), truth)  # starts turned 3° to the axes

    def solve(manhattan: bool) -> np.ndarray:
        g = PoseGraph(GraphConfig(manhattan=manhattan))
        g.add_node(truth[0])
        for i in range(1, n):
            d = se2.between(truth[i - 1], truth[i]) + np.array([0.0, 0.0, math.radians(0.05)])
            g.add_node(se2.compose(g.est[i - 1], d))
            g.add_match(i - 1, i, d)
            if manhattan and i >= 10:
                y = truth[i, 2] - math.radians(3.0) + math.radians(rng.normal(0, 0.3))  # walls along 0°/90°
                off = wrap_quarter(g.est[i, 2] - y)
                g.add_heading(i, g.est[i, 2] - off)
        g.optimize()
        return g.est.copy()

    free, held = solve(False), solve(True)
    err = lambda e: float(np.abs(np.degrees(se2.wrap(e[:, 2] - truth[:, 2]))).max())  # noqa: E731
    assert err(free) > 10.0
    # the priors fix the heading up to the axes' 3° offset from the start, which the re-gauge puts back
    rel = se2.between(np.repeat(held[:1], n, 0), held)
    rel_true = se2.between(np.repeat(truth[:1], n, 0), truth)
    assert float(np.abs(np.degrees(se2.wrap(rel[:, 2] - rel_true[:, 2]))).max()) < 1.0
    assert np.allclose(held[0], truth[0], atol=1e-6)
