"""The front end along a bare corridor: the scan fixes the lateral position and the heading only, and the walls'
returns end where the sensor's range does, a place that moves with the robot; matched against the map alone every
scan is dragged back onto what the map already holds. The scan's own surfaces say so (frontend/odometry.py
scan_geometry) and the odometry holds the corridor's direction (degeneracy_prior)."""

from __future__ import annotations

import math

import numpy as np

from kosmap.frontend.odometry import OdometryConfig, SubmapOdometry, scan_geometry
from tests.backend.test_loops import _scan, _walls

WIDE = dict(beams=721, rmax=12.0, fov=math.radians(180.0))


def _drive(cfg: OdometryConfig, walls: np.ndarray, length: float, scale: float = 1.01, seed: int = 0) -> float:
    """Drive `length` metres along +x at 4.5 cm a scan with wheel odometry reading `scale` × the truth; returns the
    front end's final along-track error (m)."""
    rng = np.random.default_rng(seed)
    fe = SubmapOdometry(cfg)
    pose = None
    for k, x in enumerate(np.arange(2.0, 2.0 + length, 0.045)):
        true = np.array([x, 0.0, 0.0])
        odo = np.array([2.0 + scale * (x - 2.0), 0.0, 0.0])
        pose = fe.update(k, _scan(walls, true, rng, **WIDE), odo).pose
    return float(pose[0] - (x - 2.0))


def test_scan_geometry_tells_a_bare_corridor_from_a_room():
    rng = np.random.default_rng(0)
    corridor = _scan(_walls(doors_top=[], length=100.0), np.array([30.0, 0.0, 0.0]), rng, **WIDE)
    g, v = scan_geometry(corridor)
    assert g < 0.02 and abs(v[0]) > 0.99  # measured: 0.006, along x
    room = np.array([[0, 0, 4, 0], [4, 0, 4, 3], [4, 3, 0, 3], [0, 3, 0, 0]], dtype=float)
    g, _ = scan_geometry(_scan(room, np.array([1.5, 1.2, 0.3]), rng, **WIDE))
    assert g > 0.3  # measured: 0.61


def test_the_corridor_keeps_its_length():
    walls = _walls(doors_top=[], length=200.0)
    off = _drive(OdometryConfig(degenerate_ratio=0.0), walls, 30.0)
    assert off < -5.0  # measured: −29.95 m, the front end never leaves its start
    held = _drive(OdometryConfig(), walls, 30.0)
    assert abs(held) < 0.5  # the odometry's 1 % over 30 m, and no more (measured 0.31 m)
