"""Map comparison: global alignment from any rotation, metrics on maps of different resolutions and sizes."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.mapping.compare import CompareConfig, align, apply, compare, occupied_points, overlay_picture, se2
from kosmap.mapping.grid import OccupancyGrid
from tests.mapping.worlds import room, wall_grid

# walls off the cell boundaries, so that rasterising the moved world is not ambiguous by a whole cell
WORLD = room() + np.array([0.012, 0.017, 0.012, 0.017])


def _errors(al, truth, a: OccupancyGrid) -> tuple[float, float, float]:
    """(yaw error deg, displacement of A's wall centroid m, largest displacement of any wall cell m)."""
    pa = occupied_points(a, CompareConfig())
    T, Tt = al.matrix, se2(*truth)
    d = np.hypot(*(apply(T, pa) - apply(Tt, pa)).T)
    c = pa.mean(axis=0, keepdims=True)
    yaw = (np.degrees(al.yaw - truth[2]) + 180) % 360 - 180
    return abs(yaw), float(np.hypot(*(apply(T, c) - apply(Tt, c))[0])), float(d.max())


@pytest.mark.parametrize("deg", [10, 90, 180])
@pytest.mark.parametrize("res", [0.05, 0.10])
def test_rotated_and_shifted_map_realigns_within_one_cell(deg, res):
    a = wall_grid(WORLD, res)
    truth = (1.0, 0.0, np.radians(deg))
    b = wall_grid(WORLD, res, transform=truth)  # the world rotated and shifted 1 m, rasterised anew
    al = align(a, b)
    yaw_err, centroid_err, max_err = _errors(al, truth, a)
    assert yaw_err < 0.5
    assert centroid_err <= res
    assert max_err <= res * 1.0 + 1e-9
    assert al.inliers > 0.98


@pytest.mark.parametrize("deg", [10, 90, 180, 271])
def test_origin_yaw_and_shift_realign_exactly(deg):
    """The same cells under a rotated, shifted origin (how other tools store rotated maps)."""
    a = wall_grid(WORLD, 0.05)
    th = np.radians(deg)
    T = se2(1.0, -0.4, th) @ se2(*a.origin)
    b = OccupancyGrid(a.data.copy(), a.resolution, (T[0, 2], T[1, 2], th))
    al = align(a, b)
    yaw_err, centroid_err, max_err = _errors(al, (1.0, -0.4, th), a)
    assert yaw_err < 1e-6 and max_err < 1e-6
    m = compare(a, b, alignment=al).metrics
    assert m["tolerances"]["0.05"]["f1"] == pytest.approx(1.0, abs=0.01)


def test_different_resolutions_compare_both_ways():
    fine, coarse = wall_grid(WORLD, 0.05), wall_grid(WORLD, 0.10, margin=1.3)  # also different sizes and origins
    for a, b in ((fine, coarse), (coarse, fine)):
        m = compare(a, b).metrics
        assert m["canvas"]["resolution"] == pytest.approx(0.05)
        t = m["tolerances"]
        assert t["0.10"]["f1"] >= 0.97, t
        assert t["0.20"]["f1"] >= 0.999, t
        assert m["distance_a_to_b"]["median"] <= 0.05 + 1e-6
        assert abs(m["alignment"]["yaw_deg"]) < 0.5 and np.hypot(m["alignment"]["x"], m["alignment"]["y"]) <= 0.1


def test_partial_map_scores_low_recall_full_precision():
    """A map covering only the left part of the room: its walls are all right, but it misses most of B's."""
    full = wall_grid(WORLD, 0.05)
    part = OccupancyGrid(full.data[:, : full.width * 2 // 5].copy(), full.resolution, full.origin)
    m = compare(part, full, CompareConfig(align=False)).metrics
    t = m["tolerances"]["0.10"]
    assert t["precision"] > 0.99
    frac = (part.data == 100).sum() / (full.data == 100).sum()
    assert t["recall"] == pytest.approx(frac, abs=0.02)
    assert t["coverage"] == pytest.approx(frac, abs=0.03)
    assert t["recall_observed"] > 0.97  # of the walls it saw, it got nearly all
    m2 = compare(full, part).metrics  # aligning the whole to a part works too
    assert m2["tolerances"]["0.10"]["recall"] > 0.99
    assert abs(m2["alignment"]["x"]) < 0.05 and abs(m2["alignment"]["yaw_deg"]) < 0.5


def test_no_align_measures_a_known_offset():
    a = wall_grid(WORLD, 0.05)
    b = OccupancyGrid(a.data.copy(), a.resolution, (a.origin[0] + 0.15, a.origin[1], 0.0))  # 3 cells east
    m = compare(a, b, CompareConfig(align=False)).metrics
    t = m["tolerances"]
    # walls running north-south are 0.15 m apart, east-west ones still overlap
    assert t["0.10"]["f1"] < 0.75
    assert t["0.20"]["f1"] > 0.99
    assert m["alignment"]["aligned"] is False
    m = compare(a, b).metrics  # aligning removes it
    assert m["alignment"]["x"] == pytest.approx(0.15, abs=1e-6) and m["tolerances"]["0.05"]["f1"] > 0.999


def test_free_space_agreement_and_overlay_colours():
    a = wall_grid(WORLD, 0.05)
    b = OccupancyGrid(a.data.copy(), a.resolution, a.origin)
    b.data[: b.height // 2, : b.width // 2] = -1  # B knows nothing in one quadrant
    extra = a.data.copy()
    extra[20, 150:170] = 100  # a wall that only A has, where B knows free space
    a = OccupancyGrid(extra, a.resolution, a.origin)
    c = compare(a, b, CompareConfig(align=False))
    fr = c.metrics["free"]
    assert fr["cells_compared"] == (b.data >= 0).sum()
    assert 0.99 < fr["agreement"] < 1.0
    img = overlay_picture(c)
    assert img.shape == (c.canvas.height, c.canvas.width, 3)
    red = np.all(img == (0, 0, 230), axis=2)[::-1]  # back to row 0 = bottom
    assert red[20, 150:170].all()  # A-only wall in red
    assert np.all(img == (0, 170, 0), axis=2).sum() == 0  # every wall B has, A has too
    assert (np.all(img == 0, axis=2)).sum() > 500  # agreement black


def test_empty_map_is_a_clear_error():
    a = wall_grid(WORLD, 0.05)
    empty = OccupancyGrid(np.zeros_like(a.data), a.resolution, a.origin)
    from kosmap.mapping.compare import CompareError

    with pytest.raises(CompareError, match="wall cells"):
        compare(empty, a)


def test_thick_blueprint_walls_count_by_their_faces():
    """A laser map sees only the inner faces of a plan's thick outer walls: scored by faces (the default) it
    matches the plan; scoring every occupied cell would punish it for what it can never see."""
    import cv2

    from kosmap.mapping.grid import build_grid
    from kosmap.mapping.mapio import outside_unknown
    from tests.mapping.worlds import scan_at

    poses = np.array([(x, y, 0.0) for x, y in [(1.5, 1.5), (1.5, 5.5), (5, 2), (8.5, 3), (5, 4.5), (6, 6.5), (2, 3.5)]])
    grid = build_grid(poses, [scan_at(p, WORLD) for p in poses])
    thin = wall_grid(WORLD, 0.05)
    wall = thin.data == 100
    outside = outside_unknown(thin.data) == -1
    thick = cv2.dilate(wall.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0  # outer walls 20 cm thick, outwards
    data = np.where(wall | (thick & outside), 100, np.where(outside, -1, 0)).astype(np.int8)
    plan = OccupancyGrid(data, thin.resolution, thin.origin)
    faces = compare(grid, plan, CompareConfig(align=False)).metrics["tolerances"]["0.05"]
    every = compare(grid, plan, CompareConfig(align=False, walls="all")).metrics["tolerances"]["0.05"]
    assert faces["f1"] >= 0.95 and faces["precision"] > 0.99
    assert every["recall"] < 0.6 and every["precision"] > 0.99
    aligned = compare(grid, plan).metrics  # and the alignment is not pulled into the thick walls
    assert np.hypot(aligned["alignment"]["x"], aligned["alignment"]["y"]) < 0.03
    assert abs(aligned["alignment"]["yaw_deg"]) < 0.3


def test_canvas_coarsens_when_too_large_and_still_scores():
    a = wall_grid(WORLD, 0.05)
    m = compare(a, a, CompareConfig(align=False, max_canvas_cells=10_000)).metrics
    assert m["canvas"]["width"] * m["canvas"]["height"] <= 10_000 and m["canvas"]["resolution"] > 0.1
    assert m["tolerances"]["0.20"]["f1"] > 0.99
