"""Camera geometry: FOV fallback, depthConstraints, pixels ↔ 3D, the mount and its lookup in /tf_static."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.camera import (DepthConfig, backproject, camera_axes, camera_for, camera_mount, depth_constraints,
                             gravity_up, lookup_static, mount_transform, project)
from kosmap.frontend.records import CameraModel, Transform, Transforms


def test_fov_fallback_is_geometric():
    cam = camera_for((424, 512), None, DepthConfig())
    assert cam.fx == pytest.approx(256 / np.tan(np.radians(70.6) / 2))
    assert cam.fy == pytest.approx(212 / np.tan(np.radians(60.0) / 2))
    # the model spans the configured field of view (not half of it, as the thesis's eq. 2.1–2.2)
    assert np.degrees(cam.fov_h) == pytest.approx(70.6, abs=0.2)


def test_camera_info_used_and_scaled():
    K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    info = CameraModel(640, 480, K)
    assert camera_for((480, 640), info) is info
    half = camera_for((240, 320), info)
    assert half.fx == pytest.approx(262.5) and half.cx == pytest.approx(159.5) and half.cy == pytest.approx(119.5)
    other = camera_for((424, 512), info)  # another aspect: the FOV model
    assert other.fx == pytest.approx(256 / np.tan(np.radians(70.6) / 2))


def test_depth_constraints_thesis_alg4():
    d = np.array([[0.0, np.nan, 0.5, 0.50001], [4.5, 4.50001, 2.0, np.inf]], np.float32)
    ok = depth_constraints(d, 0.5, 4.5)
    assert ok.tolist() == [[False, False, False, True], [True, False, True, False]]


def test_backproject_project_roundtrip():
    cam = CameraModel.from_fov(64, 48, np.radians(70.0), np.radians(55.0))
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.6, 4.0, (48, 64)).astype(np.float32)
    rows, cols = rng.integers(0, 48, 100), rng.integers(0, 64, 100)
    p = backproject(depth, cam, rows, cols)
    assert np.allclose(p[:, 2], depth[rows, cols])
    r, c = project(p, cam)
    assert np.allclose(r, rows, atol=1e-3) and np.allclose(c, cols, atol=1e-3)
    assert backproject(depth, cam).shape == (48 * 64, 3)


def test_mount_pitch_down_and_optical_axes():
    m = mount_transform([0.1, 0.0, 1.0], [0.0, np.radians(15), 0.0])
    R = m.matrix()[:3, :3]
    assert np.allclose(R @ [0, 0, 1], [np.cos(np.radians(15)), 0, -np.sin(np.radians(15))])  # looks forward, down
    assert np.allclose(R @ [1, 0, 0], [0, -1, 0])  # optical x = right = −y
    assert np.allclose(m.apply(np.zeros((1, 3)))[0], [0.1, 0.0, 1.0])
    up, fwd, left = camera_axes(m)
    assert np.allclose(R @ up, [0, 0, 1]) and np.allclose(R @ left, [0, 1, 0])
    assert np.allclose(R @ fwd, [1, 0, 0])
    assert np.allclose(gravity_up(None), [0, -1, 0])


def test_mount_from_tf_static_chain_and_fallback():
    link = Transform.from_xyz_rpy("base_link", "kinect2_link", [0.2, 0.0, 0.9], [0.0, np.radians(10), 0.0])
    opt = Transform.from_xyz_rpy("kinect2_link", "kinect2_ir_optical_frame", [0, 0, 0], [-np.pi / 2, 0, -np.pi / 2])
    laser = Transform.from_xyz_rpy("base_link", "laser", [0.1, 0, 0.3], [0, 0, 0])
    tfs = [Transforms(0, (link, laser), True), Transforms(0, (opt,), True)]
    tf, src = camera_mount(tfs, "/kinect2_ir_optical_frame")
    assert src == "tf_static"
    assert np.allclose(tf.matrix(), mount_transform([0.2, 0.0, 0.9], [0.0, np.radians(10), 0.0]).matrix())
    # the reverse direction through the same tree
    back = lookup_static(tfs, "kinect2_ir_optical_frame", "laser")
    assert np.allclose(back.matrix(), np.linalg.inv(tf.matrix()) @ laser.matrix())
    cfg = DepthConfig(mount_xyz=[0.0, 0.0, 1.2], mount_rpy_deg=[0.0, 15.0, 0.0])
    tf2, src2 = camera_mount(tfs, "some_other_camera", cfg)
    assert src2 == "config"
    assert np.allclose(tf2.matrix(), mount_transform([0, 0, 1.2], [0, np.radians(15), 0]).matrix())
