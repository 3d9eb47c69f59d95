"""Likelihood fields and the three scan matchers (correlative, Gauss–Newton, branch and bound)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from kosmap.frontend import se2
from kosmap.frontend.likelihood import LikelihoodField, densify
from kosmap.frontend.matcher import SearchGrids, correlative_search, gauss_newton, mean_score
from kosmap.frontend.odometry import WheelOdometry, prior_weight_matrix, voxel_filter


def _room_points(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """Points on the walls of an L-shaped room with a pillar (no symmetry)."""
    segs = [((0, 0), (6, 0)), ((6, 0), (6, 3)), ((6, 3), (3, 3)), ((3, 3), (3, 5)), ((3, 5), (0, 5)), ((0, 5), (0, 0)),
            ((1.5, 1.5), (2.0, 1.5)), ((2.0, 1.5), (2.0, 2.2)), ((2.0, 2.2), (1.5, 2.2)), ((1.5, 2.2), (1.5, 1.5))]
    pts = []
    for (x0, y0), (x1, y1) in segs:
        k = int(math.hypot(x1 - x0, y1 - y0) / 0.03)
        a = np.linspace(0, 1, k, endpoint=False)
        pts.append(np.column_stack((x0 + a * (x1 - x0), y0 + a * (y1 - y0))))
    p = np.vstack(pts)
    return p[rng.choice(len(p), min(n, len(p)), replace=False)]


def test_splatted_field_equals_the_distance_transform_model():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.3, 2.7, (25, 2))
    f = LikelihoodField((0.0, 0.0), 0.05, 60, 60, sigma=0.1)
    f.insert(pts)
    centres = (np.stack(np.meshgrid(np.arange(60), np.arange(60)), -1) + 0.5) * 0.05  # [row, col] → (x, y)
    d = np.sqrt(((centres[:, :, None, :] - pts[None, None]) ** 2).sum(-1)).min(-1)
    expected = np.where(d <= 0.3, np.exp(-d ** 2 / (2 * 0.1 ** 2)), 0.0)
    near = d <= 0.3 - 0.05 * math.sqrt(2)  # inside the splat radius for sure
    assert np.abs(f.values - expected)[near].max() < 1e-5
    # the grid version of the same model (distance transform of the occupied cells) agrees within a cell
    occ = np.ones((60, 60), bool)
    c = np.floor(pts / 0.05).astype(int)
    occ[c[:, 1], c[:, 0]] = False
    dt = distance_transform_edt(occ) * 0.05
    assert np.abs(np.exp(-dt ** 2 / 0.02) - f.values)[near].max() < 0.35


def test_gauss_newton_and_correlative_search_recover_an_offset():
    rng = np.random.default_rng(1)
    wall = _room_points(rng, 2000)
    field = LikelihoodField.covering(wall, 0.05, 0.05)
    truth = np.array([2.5, 1.0, 0.3])
    scan = se2.transform_points(se2.inverse(truth), _room_points(rng, 300)) + rng.normal(0, 0.005, (300, 2))
    start = se2.compose(truth, [0.07, -0.05, math.radians(2.5)])
    W = np.zeros((3, 3))
    o = field.origin
    p, H, score = gauss_newton(field.values, o[0], o[1], 0.05, scan, start, start, W, 30)
    assert np.hypot(*(p[:2] - truth[:2])) < 0.015 and abs(se2.wrap(p[2] - truth[2])) < math.radians(0.5)
    assert score > 0.8 and np.all(np.linalg.eigvalsh(H) > 0)
    c, raw = correlative_search(field.values, o[0], o[1], 0.05, scan, start, 0.1, 0.025, math.radians(3),
                                math.radians(0.5), 0.0, 0.0)
    assert np.hypot(*(c[:2] - truth[:2])) < 0.03 and abs(se2.wrap(c[2] - truth[2])) < math.radians(0.6)
    assert raw >= mean_score(field.values, o[0], o[1], 0.05, scan, start)


def test_prior_holds_the_unobservable_direction():
    # a single straight wall: along it the data says nothing, the prior decides
    rng = np.random.default_rng(2)
    wall = np.column_stack((np.linspace(-5, 5, 400), np.full(400, 1.0)))
    field = LikelihoodField.covering(wall, 0.05, 0.05)
    scan = np.column_stack((np.linspace(-2, 2, 100), np.full(100, 1.0))) + rng.normal(0, 0.003, (100, 2))
    start = np.array([0.3, 0.04, 0.0])  # 4 cm across the wall, 0.3 m along it
    W = prior_weight_matrix(0.0, w_across=1.0, w_along=1000.0, w_yaw=1.0)
    o = field.origin
    p, _, _ = gauss_newton(field.values, o[0], o[1], 0.05, scan, start, start, W, 30)
    assert abs(p[1]) < 0.01  # across: the wall wins
    assert abs(p[0] - 0.3) < 0.01  # along: the prior (heading x) keeps it


@pytest.mark.parametrize("offset", [(0.6, -0.4, 12.0), (-0.3, 0.7, -17.0)])
def test_branch_and_bound_finds_the_pose_from_a_poor_guess(offset):
    rng = np.random.default_rng(3)
    wall = _room_points(rng, 3000)
    field = LikelihoodField.covering(wall, 0.05, 0.1)
    truth = np.array([4.0, 1.5, 2.0])
    scan = se2.transform_points(se2.inverse(truth), _room_points(rng, 200)) + rng.normal(0, 0.01, (200, 2))
    guess = se2.compose(truth, [offset[0], offset[1], math.radians(offset[2])])
    grids = SearchGrids(field, depth=6)
    pose, score = grids.search(scan, guess, 1.0, math.radians(20), 0.3)
    assert pose is not None
    assert np.hypot(*(pose[:2] - truth[:2])) < 0.06 and abs(se2.wrap(pose[2] - truth[2])) < math.radians(1.0)
    # no pose near the answer scores clearly better (brute force on the quantised field the search uses)
    res = field.resolution
    best = 0.0
    for da in np.linspace(-0.02, 0.02, 9):
        for dx in np.arange(-3, 4) * res:
            for dy in np.arange(-3, 4) * res:
                q = pose + np.array([dx, dy, da])
                ij = np.floor((se2.transform_points(q, scan) - field.origin) / res).astype(int)
                ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < field.shape[1]) & (ij[:, 1] < field.shape[0])
                v = np.zeros(len(scan))
                v[ok] = np.round(field.values[ij[ok, 1], ij[ok, 0]] * 255) / 255
                best = max(best, v.mean())
    assert score >= best - 0.03


def test_branch_and_bound_rejects_a_scan_from_elsewhere():
    rng = np.random.default_rng(4)
    field = LikelihoodField.covering(_room_points(rng, 3000), 0.05, 0.1)
    noise = rng.uniform(-3, 3, (150, 2))  # a scan of nothing in this room
    pose, _ = SearchGrids(field).search(noise, np.array([3.0, 2.0, 0.0]), 1.0, math.radians(20), 0.6)
    assert pose is None


def test_densify_fills_walls_but_not_depth_jumps():
    a = np.deg2rad(np.arange(-10, 11, 1.0))
    wall = np.column_stack((np.full_like(a, 8.0), 8.0 * np.tan(a)))  # a wall 8 m ahead: returns 0.14 m apart
    jump = np.vstack((wall[:10], wall[10:] * [0.3, 0.3]))  # then a near object: a 5.6 m jump
    d = densify(wall, 0.05, 1.0)
    gaps = np.hypot(*np.diff(d, axis=0).T)
    assert gaps.max() <= 0.05 + 1e-9 and len(d) > 2 * len(wall)
    dj = densify(jump, 0.05, 1.0)
    assert np.hypot(*np.diff(dj, axis=0).T).max() > 5.0  # the jump stays open
    assert densify(wall, 0.05, 0.0) is wall


def test_wheel_odometry_interpolates_across_the_yaw_seam_and_voxel_filter_keeps_order():
    w = WheelOdometry()
    w.add(0, 0.0, 0.0, math.radians(179.0))
    w.add(1_000_000_000, 1.0, 0.0, math.radians(-179.0))
    p = w.pose_at(500_000_000)
    assert p[0] == pytest.approx(0.5) and abs(abs(p[2]) - math.pi) < 1e-9
    assert w.pose_at(-5)[0] == 0.0 and w.pose_at(5_000_000_000)[0] == 1.0
    assert w.covers(1_000_000_000) and not w.covers(1_000_000_001)
    pts = np.array([[0.0, 0.0], [0.01, 0.0], [1.0, 1.0], [0.02, 0.01], [2.0, 0.0]])
    assert np.array_equal(voxel_filter(pts, 0.05), pts[[0, 2, 4]])
