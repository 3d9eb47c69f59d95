"""KOS (thesis Alg. 7) on exact synthetic geometry: levels, bands, bearings, several cameras, laser fusion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.frontend.kos import OBSTACLE, Bearings, KosAccumulator, KosConfig, bearings_for, camera_view, fuse_with_laser, in_view
from kosmap.frontend.records import CameraModel, Scan, Transform

CAM = CameraModel.from_fov(512, 424, math.radians(70.6), math.radians(60.0))


def optical_mount(xyz=(0.0, 0.0, 1.0), pitch=0.0, yaw=0.0) -> Transform:
    """base_link ← optical frame of a camera at xyz, pitched down by `pitch`, turned by `yaw` (REP 103)."""
    link = Transform.from_xyz_rpy("base_link", "camera_link", xyz, [0.0, pitch, yaw])
    optical = Transform.from_xyz_rpy("camera_link", "optical", [0, 0, 0], [-math.pi / 2, 0, -math.pi / 2])
    return link.compose(optical)


def render(mount: Transform, box_fn, rng=None) -> np.ndarray:
    """Points seen by the camera: cast the ray of every column on every 2nd row in base_link and intersect with `box_fn`."""
    v, u = np.mgrid[0:CAM.height:2, 0:CAM.width]
    rays = np.stack(((u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u, float)), -1).reshape(-1, 3)
    m = mount.matrix()
    dirs = rays @ m[:3, :3].T
    t = box_fn(m[:3, 3], dirs)
    pts_base = m[:3, 3] + dirs * t[:, None]
    ok = np.isfinite(t) & (t * np.linalg.norm(rays, axis=1) > 0)
    local = (pts_base[ok] - m[:3, 3]) @ m[:3, :3]  # back into the optical frame
    if rng is not None:
        local += rng.normal(0, 0.002, local.shape)
    return local


def corridor(origin, dirs):
    """Walls at x = ±3 (front, back), y = ±1.5, floor z = 0, a table top z = 0.75 for 1.8 < x < 2.4, |y| < 0.4,
    a low box 0.2 m high at 1.0 < x < 1.2, -0.6 < y < -0.3 (its front face x = 1.0)."""
    best = np.full(len(dirs), np.inf)

    def plane(axis, value, lo, hi):
        d = dirs[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - origin[axis]) / d
            p = origin + dirs * t[:, None]
        ok = (t > 1e-6) & np.all((p >= lo) & (p <= hi), axis=1)
        np.minimum(best, np.where(ok, t, np.inf), out=best)

    plane(0, 3.0, [-9, -1.5, 0], [9, 1.5, 2.7])
    plane(0, -3.0, [-9, -1.5, 0], [9, 1.5, 2.7])
    plane(1, 1.5, [-9, -9, 0], [3, 9, 2.7])
    plane(1, -1.5, [-9, -9, 0], [3, 9, 2.7])
    plane(2, 0.0, [-9, -1.5, -1], [3, 1.5, 1])
    plane(2, 0.75, [1.8, -0.4, -1], [2.4, 0.4, 9])  # table top (no legs: level 0.3 sees under it)
    plane(0, 1.0, [-9, -0.6, 0], [9, -0.3, 0.2])  # low box front face
    return best


def true_range(bearing: np.ndarray, height: float) -> np.ndarray:
    """Horizontal range from base_link to the first surface of `corridor` at `height`, per bearing."""
    d = np.stack((np.cos(bearing), np.sin(bearing), np.zeros_like(bearing)), -1)
    return corridor(np.array([0.0, 0.0, height]), d)


def scans_of(points_and_mounts, cfg=None, increment_deg=0.0):
    cfg = cfg or KosConfig()
    b = bearings_for([(CAM, m) for _, m in points_and_mounts], increment_deg)
    acc = KosAccumulator(cfg, b, 0.5, 4.5)
    for pts, m in points_and_mounts:
        lo, hi = camera_view(CAM, m)
        acc.add(pts, m, (hi - lo) / 2)
    return acc.scans(123, in_view(b, [(CAM, m) for _, m in points_and_mounts]))


def test_level_ranges_match_the_geometry_and_fill_the_view():
    m = optical_mount()
    s = scans_of([(render(m, corridor, np.random.default_rng(0)), m)], KosConfig(levels=[1.2]))["h1_20"]
    truth = true_range(s.angles, 1.2)
    has_surface = (truth >= 0.5) & (truth <= 4.5)
    filled = np.isfinite(s.ranges) & has_surface
    assert filled.sum() / has_surface.sum() >= 0.95
    err = np.abs(s.ranges[filled] - truth[filled])
    assert np.median(err) <= 0.02
    assert s.frame_id == "base_link" and s.topic == "/kinect_scan/h1_20"
    assert len(s.ranges) == CAM.width  # one bin per image column by default


def test_table_top_appears_at_its_level_and_not_below():
    m = optical_mount(pitch=math.radians(20))  # look down enough to see the table top and the low box
    pts = render(m, corridor)
    scans = scans_of([(pts, m)], KosConfig(levels=[0.3, 0.75]))
    ahead = np.abs(scans["h0_75"].angles) < math.radians(5)
    assert np.nanmedian(scans["h0_75"].ranges[ahead]) == pytest.approx(1.8, abs=0.1)  # the table's front edge
    assert np.nanmin(scans["h0_30"].ranges[ahead]) > 2.5  # under the table: the wall at 3 m
    box = (scans["h0_30"].angles < math.atan2(-0.32, 1.0)) & (scans["h0_30"].angles > math.atan2(-0.58, 1.0))
    assert np.nanmedian(scans[OBSTACLE].ranges[box]) < 1.3  # the low box, in the obstacle scan
    assert np.nanmin(scans["h0_75"].ranges[box]) > 1.3  # not at table height
    assert np.nanmedian(scans["h0_30"].ranges[box]) > 1.3  # 0.3 ± 0.1 is above the 0.2 m box


def test_pitched_camera_gives_the_same_scan_as_a_level_one():
    level, pitched = optical_mount(), optical_mount(pitch=math.radians(15))
    a = scans_of([(render(level, corridor), level)], KosConfig(levels=[0.9]))["h0_90"]
    b = scans_of([(render(pitched, corridor), pitched)], KosConfig(levels=[0.9]))["h0_90"]
    both = np.isfinite(a.ranges) & np.isfinite(b.ranges)
    assert both.sum() > 0.9 * len(a.ranges)
    assert np.median(np.abs(a.ranges[both] - b.ranges[both])) < 0.01


def test_two_cameras_cover_both_fields_of_view():
    front, rear = optical_mount((0.2, 0, 1.0)), optical_mount((-0.2, 0, 1.0), yaw=math.pi)
    s = scans_of([(render(front, corridor), front), (render(rear, corridor), rear)], KosConfig(levels=[1.0]))["h1_00"]
    a = np.degrees(s.angles)
    seen = np.isfinite(s.ranges)
    assert seen[np.abs(a) < 30].mean() > 0.95
    assert seen[np.abs(a) > 150].mean() > 0.95
    assert np.isnan(s.ranges[np.abs(np.abs(a) - 90) < 30]).all()  # nobody looks sideways: NaN, not "no return"


def test_fusion_takes_the_nearer_of_laser_and_kos_inside_the_view():
    m = optical_mount(pitch=math.radians(20))
    obstacle = scans_of([(render(m, corridor), m)])[OBSTACLE]
    n = 1081
    ang = -math.radians(135) + np.arange(n) * math.radians(270) / (n - 1)
    laser_mount = Transform.from_xyz_rpy("base_link", "laser", [0.1, 0, 0.3], [0, 0, 0])
    # the laser at 0.3 m sees under the table: the wall at x = 3 (relative to the laser at x = 0.1)
    r = np.full(n, np.inf, np.float32)
    ahead = np.abs(ang) < math.radians(20)
    r[ahead] = (2.9 / np.cos(ang[ahead])).astype(np.float32)
    laser = Scan(7, r, float(ang[0]), math.radians(270) / (n - 1), 0.1, 30.0, "laser", "/scan")
    fused = fuse_with_laser(laser, laser_mount, obstacle)
    centre = np.abs(ang) < math.radians(3)
    assert np.median(fused.ranges[centre]) == pytest.approx(1.7, abs=0.1)  # the table edge, 1.8 − 0.1
    behind = np.abs(ang) > math.radians(60)
    np.testing.assert_array_equal(fused.ranges[behind], laser.ranges[behind])  # outside the view: the laser


def test_bearings_with_configured_increment():
    m = optical_mount()
    b = bearings_for([(CAM, m)], increment_deg=1.0)
    lo, hi = camera_view(CAM, m)
    assert isinstance(b, Bearings) and b.angle_increment == pytest.approx(math.radians(1.0))
    assert b.n == int(round((hi - lo) / math.radians(1.0))) + 1
