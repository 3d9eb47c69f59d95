"""The map metric validated independently of the simulator (test_sim_office.py runs it on the simulator's log): on
a synthetic 30 × 14 m office with exact ray casting, a laser grid from exact poses scores F1 ≥ 0.95 at 0.10 m
against the blueprint, and the same scans with one corridor sheared sideways by 0.5 m score clearly lower."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.mapping.compare import compare
from kosmap.mapping.grid import GridConfig, build_grid
from tests.mapping.worlds import office, path_poses, scan_at, thick_blueprint, thick_walls

CENTRES = office() + np.array([0.012, 0.017, 0.012, 0.017])  # 30 × 14 m, walls off the cell boundaries
WAYPOINTS = [(1, 1), (5.5, 1), (5.5, 7), (5.5, 1), (11.5, 1), (11.5, 7), (11.5, 1), (17.5, 1), (17.5, 7), (17.5, 1),
             (23.5, 1), (23.5, 8), (23.5, 1), (29, 1), (29, 13), (1, 13), (1, 1)]  # the corridor loop, into each room


@pytest.fixture(scope="module")
def office_run():
    walls = thick_walls(CENTRES, 0.15)  # 15 cm walls: the laser sees their faces
    blueprint = thick_blueprint(CENTRES, 0.15, 0.05)
    poses = path_poses(WAYPOINTS, 0.25)
    rng = np.random.default_rng(7)
    scans = [scan_at(p, walls, n=541, fov=np.radians(270), max_range=30.0, noise=0.01, rng=rng) for p in poses]
    return blueprint, poses, scans


@pytest.mark.slow
def test_laser_grid_from_true_poses_matches_blueprint(office_run):
    blueprint, poses, scans = office_run
    grid = build_grid(poses, scans, config=GridConfig(resolution=0.05))
    m = compare(grid, blueprint).metrics
    t = m["tolerances"]["0.10"]
    assert t["f1"] >= 0.95, t
    assert t["precision"] >= 0.97 and t["recall"] >= 0.95
    al = m["alignment"]
    assert abs(al["yaw_deg"]) < 0.2 and np.hypot(al["x"], al["y"]) < 0.05  # the frames already agreed
    assert m["distance_a_to_b"]["median"] <= 0.05


@pytest.mark.slow
def test_sheared_corridor_scores_clearly_lower(office_run):
    blueprint, poses, scans = office_run
    good = compare(build_grid(poses, scans), blueprint).metrics["tolerances"]["0.10"]["f1"]
    sheared = poses.copy()
    upper = sheared[:, 1] > 11  # the upper corridor, displaced 0.5 m sideways (a broken loop, say)
    sheared[upper, 1] += 0.5
    bad = compare(build_grid(sheared, scans), blueprint).metrics["tolerances"]
    assert bad["0.10"]["f1"] < good - 0.1, (good, bad["0.10"])
    assert bad["0.10"]["f1"] < 0.9
    assert bad["0.20"]["f1"] < 0.9  # not a tolerance effect: 0.5 m is beyond every tolerance
