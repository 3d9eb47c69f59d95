"""Keyframe and node spacing derived from the scan's field of view, its beam step, the fine field's cell and the
odometry's measured noise (backend/keyframes.py derived_spacing): the 180° lasers of the benchmark logs get the
spacing they were tuned with, a wider scan no coarser turn, a narrow depth scan a turn spacing in proportion to its
field of view, and noisy odometry denser keyframes."""

import math

import numpy as np
import pytest

from kosmap.backend.keyframes import (FOV_SHARE, KEY_CELLS, NODE_CELLS, NODE_FOV_SHARE, derived_spacing,
                                      scan_fov)
from kosmap.backend.odomnoise import OdomNoise

RES = 0.05  # [odometry] resolution


def _scan(fov_deg, step_deg, mount_x=0.1, seed=0):
    """End points in base_link of a scan of a room 3–8 m away, the sensor `mount_x` ahead of base_link."""
    rng = np.random.default_rng(seed)
    a = np.radians(np.arange(-fov_deg / 2, fov_deg / 2 + 1e-9, step_deg))
    r = rng.uniform(3.0, 8.0, len(a))
    return np.c_[r * np.cos(a) + mount_x, r * np.sin(a)]


def _spacings(points, noise=None):
    fov, step = scan_fov(points)
    return (derived_spacing(fov, step, RES, KEY_CELLS, FOV_SHARE, noise),
            derived_spacing(fov, step, RES, NODE_CELLS, NODE_FOV_SHARE, noise), fov, step)


def test_sick_180_gives_the_tuned_spacing():
    key, node, fov, step = _spacings(_scan(180.0, 1.0))
    assert math.degrees(fov) == pytest.approx(180.0, abs=2.5)  # the mount 0.1 m forward narrows it a little
    assert math.degrees(step) == pytest.approx(1.0, rel=0.05)
    assert key.distance == pytest.approx(0.15) and node.distance == pytest.approx(0.2)
    assert math.degrees(key.angle) == pytest.approx(7.5, rel=0.02)
    assert math.degrees(node.angle) == pytest.approx(10.0, rel=0.02)


def test_wide_urg_240_turns_no_coarser_than_180():
    key, node, fov, step = _spacings(_scan(240.0, 0.35))
    assert math.degrees(fov) == pytest.approx(240.0, abs=4.0)  # the mount narrows the span behind base_link more
    assert math.degrees(step) == pytest.approx(0.35, rel=0.1)
    assert math.degrees(key.angle) == pytest.approx(7.5) and math.degrees(node.angle) == pytest.approx(10.0)
    assert key.distance == pytest.approx(0.15)


def test_narrow_kos_scan_turn_scales_with_its_fov():
    key, node, fov, _ = _spacings(_scan(70.0, 0.5, mount_x=0.0))
    assert math.degrees(fov) == pytest.approx(70.5, abs=1.0)  # 140 beams of 0.5°
    assert math.degrees(key.angle) == pytest.approx(70.0 / 24, rel=0.03)  # 2.9°, against 7.5° for a 180° laser
    assert math.degrees(node.angle) == pytest.approx(70.0 / 18, rel=0.03)
    assert key.distance == pytest.approx(0.15)  # travel follows the field's cells, not the field of view
    # a coarse beam step bounds the turn from below: three beams
    coarse = derived_spacing(math.radians(70.0), math.radians(2.0), RES, KEY_CELLS, FOV_SHARE)
    assert math.degrees(coarse.angle) == pytest.approx(6.0)


def test_noisy_odometry_gives_denser_keyframes():
    good = OdomNoise(0.01, 0.03, 0.0, 0.0, 0.01, 0.05, 100, True)  # 1 % scale, 3 cm/√m: the laser logs' kind
    bad = OdomNoise(0.10, 0.50, 0.0, 0.0, 0.01, 0.05, 100, True)  # 10 % scale, 50 cm/√m: slipping wheels
    key_good, node_good, _, _ = _spacings(_scan(180.0, 1.0), good)
    key_bad, node_bad, _, _ = _spacings(_scan(180.0, 1.0), bad)
    assert key_good.distance == pytest.approx(0.15) and node_good.distance == pytest.approx(0.2)
    assert key_bad.distance < 0.05 and node_bad.distance == pytest.approx(key_bad.distance)
    # the step is where the odometry's own σ reaches one cell of the coarse field (2 × RES)
    assert bad.translation_sigma(key_bad.distance) == pytest.approx(2 * RES, rel=1e-6)
    # Intel's worst measured stretch (16 cm/√m, −13 %) keeps the tuned spacing
    intel = OdomNoise(-0.13, 0.16, 0.0, 0.0, 0.01, 0.05, 100, True)
    assert _spacings(_scan(180.0, 1.0), intel)[1].distance == pytest.approx(0.2)
    assert key_bad.angle == key_good.angle  # the turn bound is the sensor's


def test_scan_fov_full_turn_and_backward_scan():
    fov, _ = scan_fov(_scan(359.0, 1.0, mount_x=0.0))
    assert math.degrees(fov) == pytest.approx(359.0, abs=1.5)
    back = _scan(90.0, 1.0, mount_x=0.0) * np.array([-1.0, 1.0])  # a scan looking backwards, across ±180°
    fov, step = scan_fov(back)
    assert math.degrees(fov) == pytest.approx(91.0, abs=1.0)  # the span and one beam's step
    assert scan_fov(np.zeros((5, 2))) == (0.0, 0.0)


def test_slam_core_applies_the_derived_spacing_unless_fixed():
    from kosmap.backend.graph import GraphConfig
    from kosmap.backend.slam import Slam
    from kosmap.frontend.odometry import OdometryConfig

    narrow = _scan(70.0, 0.5, mount_x=0.0)
    slam = Slam()
    slam.add_scan(0, narrow, np.zeros(3))
    assert math.degrees(slam.frontend.key_angle) == pytest.approx(70.0 / 24, rel=0.03)
    assert math.degrees(slam.select.angle) == pytest.approx(10.0)  # a node's turn is a 180° scan's
    fixed = Slam(OdometryConfig(keyframe_spacing="fixed"), GraphConfig(node_spacing="fixed"))
    fixed.add_scan(0, narrow, np.zeros(3))
    assert math.degrees(fixed.frontend.key_angle) == pytest.approx(7.5)
    assert math.degrees(fixed.select.angle) == pytest.approx(10.0)
    said = slam.spacing()  # what metrics.json reports: the spacing in force, not the configured keys
    assert said["keyframe"] == said["node"] == "derived" and said["fov_deg"] == pytest.approx(70.0, rel=0.03)
    assert said["keyframe_angle_deg"] == pytest.approx(70.0 / 24, rel=0.03) and said["node_angle_deg"] == pytest.approx(10.0)
    assert said["keyframe_distance_m"] == pytest.approx(0.15) and said["node_distance_m"] == pytest.approx(0.2)
    assert fixed.spacing()["keyframe"] == "fixed" and fixed.spacing()["keyframe_angle_deg"] == pytest.approx(7.5)


def test_a_declared_sensor_sets_the_spacing_over_the_scans_bearings():
    """A laser's own description (the feed passes n beams × angle_increment): a SICK 180° mounted 0.3 m ahead of
    base_link in a 2 m corridor shows a much narrower span of bearings from base_link, yet gets 7.5° / 10°."""
    from kosmap.backend.slam import Slam

    a = np.radians(np.arange(-90.0, 90.01, 1.0))
    r = np.minimum(1.0 / np.maximum(np.abs(np.sin(a)), 1e-6), 20.0)  # side walls 1 m away
    pts = np.c_[r * np.cos(a) + 0.3, r * np.sin(a)]
    assert math.degrees(scan_fov(pts)[0]) < 170.0
    slam = Slam()
    slam.set_sensor(math.radians(180.0), math.radians(1.0))
    slam.add_scan(0, pts, np.zeros(3))
    assert math.degrees(slam.frontend.key_angle) == pytest.approx(7.5)
    assert math.degrees(slam.select.angle) == pytest.approx(10.0)
