"""The likelihood field kernel `kosmap localize` scores particles (backend/mcl.py) and stitched submaps
(backend/globalsearch.py) with: one kernel, whose rays start at the pose or, for a submap, where each point was
seen from. On a small map with one wall: a reading past the wall is charged as through it when seen from this side,
and scored by the field when seen from the far side."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.backend import globalsearch as gs
from kosmap.backend import mcl
from kosmap.backend.likelihood_field import map_field

RES = 0.05
WALL_X = 2.0  # a wall 0.15 m thick from x = 2.0 to 2.15, across the whole 5 × 5 m map


@pytest.fixture(scope="module")
def field():
    data = np.zeros((100, 100), np.int8)
    data[:, int(WALL_X / RES):int(WALL_X / RES) + 3] = 100
    return map_field(data, RES, (0.0, 0.0), 0.2, 0.7, 0.3, 4.5, 0.05)


THROUGH = math.log(0.001 / 4.5)


def test_views_at_the_pose_score_as_the_particle_filter_does(field):
    rng = np.random.default_rng(3)
    parts = np.column_stack((rng.uniform(0.2, 4.8, 400), rng.uniform(0.2, 4.8, 400), rng.uniform(-math.pi, math.pi, 400)))
    pts = np.column_stack((rng.uniform(0.3, 3.5, 60), rng.uniform(-1.5, 1.5, 60)))
    for tol in (0.0, 0.2, 0.5):
        a = mcl.log_likelihoods(field, parts, pts, THROUGH, tol)
        b = gs.window_loglik(field, parts, pts, np.zeros_like(pts), THROUGH, tol)
        assert np.array_equal(a, b)
    in_wall = np.isin(np.floor(parts[:, 0] / RES), (40, 41, 42))
    assert np.array_equal(np.isneginf(a), in_wall) and in_wall.any()  # poses in the wall: -inf


def test_a_reading_past_a_wall_is_charged_from_this_side_only(field):
    pose = np.array([[1.0, 2.5, 0.0]])
    far = np.array([[2.6, 0.0]])  # 0.45 m past the wall's far face, in the pose's frame
    ll_here = mcl.log_likelihoods(field, pose, far, THROUGH, 0.2)[0]
    assert ll_here == pytest.approx(THROUGH)
    # the same point seen from x = 3.0, past the wall (a scan of a submap taken in the next room)
    ll_there = gs.window_loglik(field, pose, far, np.array([[2.0, 0.0]]), THROUGH, 0.2)[0]
    assert ll_there > ll_here + 3.0
    assert ll_there == pytest.approx(mcl.log_likelihoods(field, pose, far)[0])  # the field's value, not charged
    # every-th point traced: with every=2 the second reading is not traced, so it is scored by the field
    two = np.array([[2.6, 0.0], [2.6, 0.01]])
    ll2 = mcl.log_likelihoods(field, pose, two, THROUGH, 0.2, every=2)[0]
    assert ll2 == pytest.approx(THROUGH + mcl.log_likelihoods(field, pose, two[1:])[0])


def test_views_must_match_the_points(field):
    with pytest.raises(ValueError, match="views"):
        mcl.log_likelihoods(field, np.array([[1.0, 2.5, 0.0]]), np.ones((3, 2)), THROUGH, 0.2, views=np.ones((2, 2)))
