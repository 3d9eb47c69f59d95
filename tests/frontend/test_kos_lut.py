"""The image KOS kernel (per-pixel tables, `KosAccumulator.add_depth`) gives the reference kernel's bins
(`KosAccumulator.add` on the back-projected points), bin for bin, on seeded simulated frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.frontend.camera import DepthConfig, backproject, depth_constraints
from kosmap.frontend.fspf import FspfConfig, filter_planes
from kosmap.frontend.kos import KosAccumulator, KosConfig, bearings_for, camera_view
from kosmap.frontend.kos_bins import pixel_table
from kosmap.tools.simulate.api import render_depth
from kosmap.tools.simulate.render import camera_mount, kinect_v2_model
from kosmap.tools.simulate.world import World

ROOM = World.load("room")
CAM = kinect_v2_model()
DEPTH = DepthConfig()
LEVELS = [0.3, 0.75, 1.5]


def reference_and_image(frames, cfg, increment_deg=0.0, use_planes=True, window=0.0):
    """(reference ranges, image-kernel ranges) of the frames [(depth, mount, seed)] merged on one bin grid;
    `window` > 0: the surface rule (KosAccumulator)."""
    b = bearings_for([(CAM, m) for _, m, _ in frames], increment_deg)
    ref = KosAccumulator(cfg, b, DEPTH.min_depth, DEPTH.max_depth, window)
    img = KosAccumulator(cfg, b, DEPTH.min_depth, DEPTH.max_depth, window)
    for depth, mount, seed in frames:
        lo, hi = camera_view(CAM, mount)
        if use_planes:
            planes = filter_planes(depth, CAM, FspfConfig(analysed_fraction=0.99), DEPTH, mount, seed=seed)
            ref.add(planes.points, mount, (hi - lo) / 2)
            img.add_depth(depth, CAM, mount, planes.pixels)
        else:
            rows, cols = np.nonzero(depth_constraints(depth, DEPTH.min_depth, DEPTH.max_depth))
            ref.add(backproject(depth, CAM, rows, cols), mount, (hi - lo) / 2)
            img.add_depth(depth, CAM, mount)
    return ref.ranges, img.ranges


def assert_same_bins(ref, img):
    """Same filled bins, same nearest range (float32 rounding of the two computations: ≤ 10 µm)."""
    assert ref.shape == img.shape
    np.testing.assert_array_equal(np.isfinite(ref), np.isfinite(img))
    ok = np.isfinite(ref)
    assert ok.sum() > 0.3 * ok.size  # the frames do fill the scans
    assert np.abs(ref[ok] - img[ok]).max() <= 1e-5


def frame(pose, mount, seed):
    depth, _ = render_depth(ROOM, pose, mount, CAM, rng=np.random.default_rng(seed))
    return depth, mount, seed


@pytest.mark.parametrize("use_planes", [True, False], ids=["planes", "depth"])
def test_image_kernel_equals_reference_bin_for_bin(use_planes):
    ref, img = reference_and_image([frame((1.2, 1.4, 0.3), camera_mount(), 0)], KosConfig(levels=LEVELS),
                                   use_planes=use_planes)
    assert ref.shape[0] == len(LEVELS) + 1  # the levels and the obstacle scan
    assert_same_bins(ref, img)


@pytest.mark.parametrize("use_planes", [True, False], ids=["planes", "depth"])
def test_surface_rule_same_in_both_kernels_and_farther_than_the_nearest_point(use_planes):
    """The surface rule (mean of the points within the window of the nearest) bin for bin in both kernels, over a
    front and a rear camera; it lies beyond the nearest point (never nearer) and within the window of it."""
    pose = (3.8, 2.5, 0.0)
    rear = camera_mount(xyz=(-0.1, 0.0, 1.0), rpy=(0.0, 0.0, math.pi), frame_id="rear_optical")
    frames = [frame(pose, camera_mount(), 2), frame(pose, rear, 3)]
    cfg = KosConfig(levels=LEVELS)
    ref, img = reference_and_image(frames, cfg, use_planes=use_planes, window=0.08)
    near, _ = reference_and_image(frames, cfg, use_planes=use_planes)
    ok = np.isfinite(ref) & np.isfinite(img)
    np.testing.assert_array_equal(np.isfinite(ref), np.isfinite(near))
    # the image kernel's ranges are float32 (a mean of float32 ranges: ≤ 0.1 mm), the reference's float64
    assert np.abs(ref[ok] - img[ok]).max() <= 1e-4
    assert (ref[ok] >= near[ok] - 1e-6).all() and (ref[ok] <= near[ok] + 0.08 + 1e-6).all()
    assert np.median(ref[ok] - near[ok]) > 0.003  # a wall's nearest point lies 2–3 σ (mm to cm) short


def test_image_kernel_equals_reference_pitched_with_wide_bins():
    # pitched 15° down: a column's pixels spread over several bearings; 1° bins: several columns per bin
    mount = camera_mount(rpy=(0.0, math.radians(15), 0.0))
    ref, img = reference_and_image([frame((2.5, 3.6, math.pi), mount, 1)], KosConfig(levels=[0.5, 0.9]),
                                   increment_deg=1.0)
    assert_same_bins(ref, img)


def test_image_kernel_equals_reference_front_and_rear_cameras():
    pose = (3.8, 2.5, 0.0)
    rear = camera_mount(xyz=(-0.1, 0.0, 1.0), rpy=(0.0, 0.0, math.pi), frame_id="rear_optical")
    frames = [frame(pose, camera_mount(), 2), frame(pose, rear, 3)]
    ref, img = reference_and_image(frames, KosConfig(levels=[1.2]), increment_deg=math.degrees(
        (lambda v: (v[1] - v[0]) / (CAM.width - 1))(camera_view(CAM, camera_mount()))))
    assert_same_bins(ref, img)


def test_pixel_tables_are_memoised_and_checked():
    b = bearings_for([(CAM, camera_mount())])
    acc = KosAccumulator(KosConfig(), b, 0.5, 4.5)
    assert acc._pixel_table(CAM, camera_mount()) is acc._pixel_table(kinect_v2_model(), camera_mount())
    assert pixel_table.cache_info().currsize >= 1
    with pytest.raises(ValueError, match="424"):
        acc.add_depth(np.zeros((10, 10), np.float32), CAM, camera_mount())


def test_pixels_outside_the_image_are_ignored():
    depth, mount, _ = frame((1.2, 1.4, 0.3), camera_mount(), 4)
    b = bearings_for([(CAM, mount)])
    rows, cols = np.nonzero(depth_constraints(depth, DEPTH.min_depth, DEPTH.max_depth))
    pixels = np.column_stack((rows, cols)).astype(np.int32)
    bad = np.array([[CAM.height + 5, 10], [-1, 3], [-7, -7]], np.int32)
    a = KosAccumulator(KosConfig(), b, DEPTH.min_depth, DEPTH.max_depth)
    a.add_depth(depth, CAM, mount, pixels)
    c = KosAccumulator(KosConfig(), b, DEPTH.min_depth, DEPTH.max_depth)
    c.add_depth(depth, CAM, mount, np.concatenate((bad, pixels, bad)))
    np.testing.assert_array_equal(a.ranges, c.ranges)
    d = KosAccumulator(KosConfig(), b, DEPTH.min_depth, DEPTH.max_depth)
    d.add_depth(depth, CAM, mount)  # all valid pixels = the same as listing them
    np.testing.assert_array_equal(a.ranges, d.ranges)
