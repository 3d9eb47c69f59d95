"""FSPF and FSPF+ on an analytic box room (exact truth), the plane operations, and determinism."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.camera import depth_constraints
from kosmap.frontend.fspf import FspfConfig, filter_planes, fspf_plus
from kosmap.frontend.planes import (CEILING, FRONT, GROUND, LEFT, PLANE_CLASSES, RAISED, RIGHT, SLANTED, FrameStats,
                             Planes, classify, fit_plane, merge_planes, ransac_plane)
from kosmap.frontend.records import CameraModel
from tests.frontend.plane_truth import recovered, score
from kosmap.tools.boxroom import frame, noise_sigma
from kosmap.tools.fspf_numpy import filter_planes_numpy

POSE = (0.6, 0.3, 0.0)
WALLS = (3, 4, 5, 6)


def _filter(backend: str):
    """The compiled filter ("numba"), or the benchmark's numpy reference of the same algorithm ("numpy")."""
    return filter_planes if backend == "numba" else filter_planes_numpy


def _world_from_cam(mount):
    wb = np.eye(4)
    wb[:2, 3] = POSE[:2]
    return wb @ mount.matrix()


@pytest.fixture(scope="module", params=[0.0, 15.0], ids=["level", "pitched15"])
def room_frame(request):
    return frame(pose=POSE, pitch_deg=request.param, seed=3)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_fspf_plus_accuracy_on_box_room(room_frame, backend):
    depth, sid, room, cam, mount = room_frame
    truth = {r.id: (r.cls, r.plane) for r in room.surfaces}
    cfg = FspfConfig(drop_classes=[], analysed_fraction=0.99)
    p = _filter(backend)(depth, cam, cfg, mount=mount, seed=1)
    s = score(p, sid, truth, _world_from_cam(mount), cam, noise_sigma)
    assert s["on_surface"] >= 0.98
    assert s["median_normal_err_deg"] <= 2.0
    assert s["class_ok"] >= 0.95
    # the big surfaces are found with the right class
    names = {truth[m][0] for m, c in zip(s["majority"], p.counts) if c > 2000}
    eligible = depth_constraints(depth, 0.5, 4.5)
    visible = {truth[k][0] for k in truth if (eligible & (sid == k)).sum() > 5000}
    assert {"ground", "wall", "slanted"} <= visible <= names
    # walls recovered at the offline configuration, with ground and ceiling dropped
    p2 = _filter(backend)(depth, cam, FspfConfig(analysed_fraction=0.99), mount=mount, seed=1)
    assert recovered(p2, sid, depth_constraints(depth, 0.5, 4.5), WALLS) >= 0.90
    assert not np.isin(p2.classes, [GROUND, CEILING]).any()


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_fspf_baseline_on_box_room(room_frame, backend):
    depth, sid, room, cam, mount = room_frame
    truth = {r.id: (r.cls, r.plane) for r in room.surfaces}
    cfg = FspfConfig(method="fspf", drop_classes=[])
    p = _filter(backend)(depth, cam, cfg, mount=mount, seed=2)
    assert p.method == "fspf"
    assert 2000 <= len(p.points) + p.stats.dropped <= 2000 + cfg.fspf_local_samples  # stops at n_max
    s = score(p, sid, truth, _world_from_cam(mount), cam, noise_sigma)
    assert s["on_surface"] >= 0.98
    assert s["median_normal_err_deg"] <= 2.0
    assert s["class_ok"] >= 0.95


@pytest.mark.parametrize("method", ["fspf+", "fspf"])
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_same_seed_same_result(method, backend):
    depth, _, _, cam, mount = frame(seed=5)
    cfg = FspfConfig(method=method)
    a = _filter(backend)(depth, cam, cfg, mount=mount, seed=7)
    b = _filter(backend)(depth, cam, cfg, mount=mount, seed=7)
    c = _filter(backend)(depth, cam, cfg, mount=mount, seed=8)
    for f in ("points", "plane", "pixels", "normals", "offsets", "classes", "counts"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert not np.array_equal(a.pixels, c.pixels)


def test_uncopied_planes_equal_the_copied_until_the_next_call():
    """copy=False (the frame stage, which uses the planes at once) gives the same planes as views of scratch
    buffers that the next call on this thread overwrites."""
    depth, _, _, cam, mount = frame(seed=5)
    cfg = FspfConfig()
    a = fspf_plus(depth, cam, cfg, mount=mount, seed=7)
    b = fspf_plus(depth, cam, cfg, mount=mount, seed=7, copy=False)
    for f in ("points", "plane", "pixels", "normals", "offsets", "classes", "counts"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert a.points.base is None and b.points.base is not None  # a view, not an array of its own
    kept = b.pixels.copy()
    fspf_plus(depth, cam, cfg, mount=mount, seed=8, copy=False)
    assert not np.array_equal(b.pixels, kept)  # overwritten: a caller must use them before the next call
    assert np.array_equal(a.pixels, kept)


@pytest.mark.parametrize("method", ["fspf+", "fspf"])
def test_stats_add_up_and_output_is_consistent(method):
    depth, _, _, cam, mount = frame(seed=6)
    p = filter_planes(depth, cam, FspfConfig(method=method), mount=mount, seed=0)
    st = p.stats
    assert st.pixels == depth.size
    assert st.ineligible == int((~depth_constraints(depth, 0.5, 4.5)).sum())
    assert st.ineligible + st.inliers + st.dropped + st.outliers + st.remaining == st.pixels
    assert st.inliers == len(p.points) == p.counts.sum()
    assert st.planes == len(p) and st.elapsed_ms > 0
    assert np.array_equal(np.bincount(p.plane, minlength=len(p)), p.counts)
    assert len(np.unique(p.pixels[:, 0] * depth.shape[1] + p.pixels[:, 1])) == len(p.pixels)  # each pixel once
    assert np.allclose(p.points[:, 2], depth[p.pixels[:, 0], p.pixels[:, 1]])
    assert (p.offsets > 0).all()  # rectified: normals face the camera
    assert (np.einsum("ij,ij->i", p.points, p.normals[p.plane]) < 0).mean() > 0.99
    if method == "fspf+":
        assert st.remaining <= 0.1 * st.eligible + 1
    img = p.depth_image()
    assert (img > 0).sum() == len(p.points)


def test_fspf_plus_planes_have_more_than_n_min_and_thesis_mode():
    depth, _, _, cam, mount = frame(seed=4)
    cfg = FspfConfig(n_min=200, merge=False, planes_per_window=1, drop_classes=[])
    p = fspf_plus(depth, cam, cfg, mount=mount, seed=0)
    assert (p.counts > 200).all()


def test_degenerate_images_do_not_break():
    cam = CameraModel.from_fov(40, 30, np.radians(70.0), np.radians(60.0))
    for depth in (np.zeros((30, 40), np.float32), np.full((30, 40), np.nan, np.float32),
                  np.full((30, 40), 9.0, np.float32)):
        for method in ("fspf+", "fspf"):
            for backend in ("numba", "numpy"):
                p = _filter(backend)(depth, cam, FspfConfig(method=method), seed=0)
                assert len(p) == 0 and p.stats.ineligible == depth.size
    # one fronto-parallel plane filling the image; the window is clipped at the border
    flat = np.full((30, 40), 1.0, np.float32)
    for backend in ("numba", "numpy"):
        p = _filter(backend)(flat, cam, FspfConfig(n_min=10), seed=0)
        assert len(p) == 1 and PLANE_CLASSES[p.classes[0]] == "front"
        assert np.allclose(p.normals[0], [0, 0, -1], atol=1e-6) and p.offsets[0] == pytest.approx(1.0)
    with pytest.raises(ValueError):
        fspf_plus(flat, CameraModel.from_fov(41, 30, 1.0, 1.0))


def test_classify_by_angle_to_gravity():
    up, fwd, left = np.array([0, -1.0, 0]), np.array([0, 0, 1.0]), np.array([-1.0, 0, 0])
    def n_at(tilt_deg, toward):  # a camera-facing normal tilted from up toward a horizontal direction
        t = np.radians(tilt_deg)
        return np.cos(t) * up + np.sin(t) * np.asarray(toward, float)
    normals = [up, -up, [1.0, 0, 0], [-1.0, 0, 0], [0, 0, -1.0], n_at(12, [0, 0, -1]), n_at(2, [0, 0, -1]),
               n_at(87, [0, 0, -1]), n_at(4.76, [1, 0, 0])]
    got = classify(np.array(normals), up, fwd, left)
    # the floor faces up; a wall on the left faces right (−left); the wall ahead faces back; a 1:12 ramp slants
    assert got.tolist() == [GROUND, CEILING, LEFT, RIGHT, FRONT, SLANTED, GROUND, FRONT, SLANTED]
    got = classify(np.array([n_at(12, [0, 0, -1])]), up, fwd, left, slanted_min_deg=15)
    assert got.tolist() == [GROUND]
    # with the camera 1 m above the floor: the floor (1 m below) is ground, a table top 0.25 m below is raised
    got = classify(np.array([up, up, -up]), up, fwd, left, offsets=np.array([1.0, 0.25, 1.6]), camera_height=1.0)
    assert got.tolist() == [GROUND, RAISED, CEILING]


def test_box_top_is_raised_not_ground():
    depth, sid, room, cam, mount = frame(pose=POSE, seed=3, pitch_deg=10.0, height=1.6)
    p = fspf_plus(depth, cam, FspfConfig(drop_classes=[]), mount=mount, seed=1)
    lab = p.label_image()
    top = lab[(sid == 9) & (lab > 0)] - 1  # the box top, 0.8 m above the floor
    assert len(top) > 500 and (p.classes[top] == RAISED).mean() > 0.85  # the rest: edge pixels of the sides
    floor = lab[(sid == 1) & (lab > 0)] - 1
    assert (p.classes[floor] == GROUND).mean() > 0.95
    # by default ground and ceiling are dropped, the box top is kept
    q = fspf_plus(depth, cam, FspfConfig(), mount=mount, seed=1)
    assert RAISED in q.classes and GROUND not in q.classes


def test_fits_and_ransac():
    rng = np.random.default_rng(0)
    n_true = np.array([0.2, -0.9, 0.3])
    n_true /= np.linalg.norm(n_true)
    uv = rng.uniform(-1, 1, (700, 2))
    a = np.cross(n_true, [1, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n_true, a)
    pts = 2.0 * n_true * -1 + uv[:, :1] * a + uv[:, 1:] * b  # plane n·p + 2 = 0
    pts += rng.normal(0, 0.003, (700, 1)) * n_true
    n, d = fit_plane(pts)
    assert abs(abs(n @ n_true) - 1) < 1e-4 and abs(abs(d) - 2.0) < 0.01
    noisy = np.vstack([pts, rng.uniform(-2, 2, (300, 3))])
    n, d, inl = ransac_plane(noisy, 0.01, 3.0, np.random.default_rng(1))
    assert np.degrees(np.arccos(min(1, abs(n @ n_true)))) < 0.5 and d > 0
    assert inl[:700].mean() > 0.98 and inl[700:].mean() < 0.05


def test_merge_two_patches_of_one_wall():
    rng = np.random.default_rng(0)
    up, fwd, left = np.array([0, -1.0, 0]), np.array([0, 0, 1.0]), np.array([-1.0, 0, 0])
    p1 = np.column_stack((rng.uniform(-1.0, -0.2, 500), rng.uniform(-0.5, 0.5, 500), 3.0 + rng.normal(0, 0.004, 500)))
    p2 = np.column_stack((rng.uniform(0.2, 1.0, 300), rng.uniform(-0.5, 0.5, 300), 3.0 + rng.normal(0, 0.004, 300)))
    p3 = np.column_stack((rng.uniform(-1.0, 1.0, 200), rng.uniform(-0.5, 0.5, 200), 3.3 + rng.normal(0, 0.004, 200)))
    tilt = np.radians(2.0)  # the patches' own fits disagree by a little
    normals = np.array([[0, 0, -1.0], [np.sin(tilt), 0, -np.cos(tilt)], [0, 0, -1.0]])
    pts = np.vstack([p1, p2, p3]).astype(np.float32)
    planes = Planes(pts, np.repeat([0, 1, 2], [500, 300, 200]).astype(np.int32), np.zeros((1000, 2), np.int32),
                    normals, np.array([3.0, 3.0, 3.3]), np.array([FRONT] * 3, np.int8), np.array([500, 300, 200]),
                    FrameStats(pixels=1000, inliers=1000), (10, 100))
    m = merge_planes(planes, 5.0, 0.05, lambda n, d: classify(n, up, fwd, left))
    assert len(m) == 2 and m.counts.tolist() == [800, 200] and m.classes.tolist() == [FRONT, FRONT]
    assert np.allclose(m.normals[0], [0, 0, -1], atol=2e-3) and m.offsets[0] == pytest.approx(3.0, abs=2e-3)
    assert m.stats.planes == 2 and planes.stats.planes == 0  # the input is not changed
    assert len(merge_planes(planes, 1.0, 0.05)) == 3  # 2° apart: not within 1°
    dropped = merge_planes(planes, 5.0, 0.05, drop_classes=(FRONT,))
    assert len(dropped) == 0 and dropped.stats.dropped == 1000 and dropped.stats.inliers == 0


def test_compiled_classification_matches_numpy():
    from kosmap.frontend.fspf import _Classes
    from kosmap.tools.boxroom import default_mount

    rng = np.random.default_rng(0)
    n = rng.normal(size=(2000, 3))
    n[:400] = [0, -1, 0]  # near level planes, up and down, in both camera poses
    n[400:800] = [0, 1, 0]
    n[:800] += rng.normal(0, 0.2, (800, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = rng.uniform(0.05, 3.0, 2000)
    for mount in (None, default_mount(15.0, 1.2)):
        c = _Classes(FspfConfig(), mount)
        ref = classify(n, c.up, c.fwd, c.left, 3.0, 80.0, d, c.cam_h, 0.15)
        assert np.array_equal(c(n, d), ref)
        assert set(ref.tolist()) >= {0, 1, 2, 3, 4, 5}
