"""KOS on the simulator's room world: real FSPF+ on noisy Kinect v2 frames, scored
against ray-cast ground truth and the simulated Hokuyo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.frontend.depthstream import DepthItem
from kosmap.frontend.kos import OBSTACLE, KosConfig, bearings_for, in_view
from kosmap.frontend.kosframe import kos_frame, merge_cameras
from kosmap.frontend.camera import DepthConfig
from kosmap.frontend.fspf import FspfConfig
from kosmap.tools.simulate.api import render_depth, render_laser
from kosmap.tools.simulate.render import LaserModel, camera_mount, cast_rays, kinect_v2_model, laser_mount
from kosmap.tools.simulate.world import World

ROOM = World.load("room")
CAM = kinect_v2_model()
# The thesis's offline setting (99 % of eligible pixels analysed): at the real-time 90 % the unexamined tenth
# of the image leaves holes in the scans (measured: a pitched and a level camera share 86 % of their bins at
# 90 %, 98 % at 99 %).
OFFLINE = FspfConfig(analysed_fraction=0.99)


def kos_at(pose, levels, mounts=None, seed=0, source="planes", fspf=None, nearest="surface"):
    """KOS scans (dict by level name) of the cameras at `mounts` on a robot at `pose` (noisy frames, seeded)."""
    mounts = mounts or [camera_mount()]
    fspf = fspf or OFFLINE
    cfg = KosConfig(levels=levels, source=source, nearest=nearest)
    cams = [(CAM, m) for m in mounts]
    b = bearings_for(cams)
    frames = []
    for i, m in enumerate(mounts):
        depth, _ = render_depth(ROOM, pose, m, CAM, rng=np.random.default_rng(seed + i))
        item = DepthItem(i, 0, depth, CAM, m, f"/cam{i}", m.child)
        frames.append(kos_frame(item, fspf, DepthConfig(), cfg, b))
    ranges = merge_cameras(frames)
    seen = in_view(b, cams)
    names = [n for n, _, _ in cfg.bands()]
    out = {}
    for k, n in enumerate(names):
        r = ranges[k].copy()
        r[~seen] = np.nan
        out[n] = r
    return out, b.centres()


def truth_at(pose, height, bearings):
    """Horizontal range from base_link to the first surface at `height`, per bearing (world ray cast), and
    that surface's class."""
    x, y, yaw = pose
    a = yaw + bearings
    dirs = np.column_stack((np.cos(a), np.sin(a), np.zeros_like(a)))
    origins = np.tile([x, y, height], (len(a), 1))
    t, sid, _ = cast_rays(ROOM, origins, dirs, 10.0)
    cls = np.array([ROOM.surface(s).cls if s > 0 else "" for s in sid])
    return np.where(sid > 0, t, np.inf), cls


def visible(truth, bearings, mount, half_fov=math.radians(35.0)):
    """Bins whose true surface point lies inside the camera's horizontal view, seen from the camera itself
    (the camera sits ahead of base_link, so the outermost bearings from base_link are out of its sight)."""
    cx, cy = mount.translation[:2]
    px, py = truth * np.cos(bearings) - cx, truth * np.sin(bearings) - cy
    return np.abs(np.arctan2(py, px)) < half_fov


POSES = [(1.2, 1.4, 0.0), (3.8, 1.4, math.pi / 2), (1.2, 3.6, -math.pi / 2), (2.5, 3.6, math.pi)]


@pytest.mark.slow
def test_level_ranges_match_truth_and_fill_the_bins():
    """Median |KOS − truth| ≤ 2 cm per frame; ≥ 95 % of the bins whose planar surface is in range and in view are
    filled (pooled over four views, FSPF+ at the thesis's offline 99 %). Curved surfaces (the simulated person)
    are not planes, so plane-based KOS leaves them out by design; the `depth` source catches them."""
    filled_all = surface_all = 0
    for pose in POSES:
        scans, a = kos_at(pose, [1.2])
        r = scans["h1_20"]
        truth, cls = truth_at(pose, 1.2, a)
        in_range = (truth >= 0.6) & (truth <= 4.4) & visible(truth, a, camera_mount())
        planar = in_range & (cls != "cylinder")
        filled = np.isfinite(r) & planar
        filled_all += filled.sum()
        surface_all += planar.sum()
        err = np.abs(r[filled] - truth[filled])
        assert np.median(err) <= 0.02, (pose, np.median(err))
        if (in_range & (cls == "cylinder")).any():
            d, _ = kos_at(pose, [1.2], source="depth")
            curved = in_range & (cls == "cylinder")
            assert np.isfinite(d["h1_20"][curved]).mean() > 0.9
    assert filled_all >= 0.95 * surface_all, filled_all / surface_all


def test_surface_rule_measures_walls_without_the_nearest_points_short_bias():
    """Signed KOS − truth on the walls in range, relative to the range, pooled over four views and two seeds: the
    nearest point of a bin's ~20–70 noisy wall points lies 2–3 σ short (the Kinect v2's σ grows with range, so the
    scans shrink: −0.3 % and worse, measured −0.5 % on the office); the mean of the nearest surface's points is
    within 0.05 % of the truth, at every range band."""
    rel = {"surface": [], "point": []}
    far = {"surface": [], "point": []}
    for pose in POSES:
        for seed in (0, 1):
            truth = None
            for nearest in rel:
                scans, a = kos_at(pose, [0.75, 1.5], seed=seed, nearest=nearest)
                for name, h in (("h0_75", 0.75), ("h1_50", 1.5)):
                    if truth is None or truth[0] != h:
                        truth = (h, *truth_at(pose, h, a))
                    t, cls = truth[1], truth[2]
                    r = scans[name]
                    ok = (np.isfinite(r) & (t >= 0.6) & (t <= 4.4) & (cls == "wall") & visible(t, a, camera_mount())
                          & (np.abs(r - t) < 0.1))
                    rel[nearest].append((r[ok] - t[ok]) / t[ok])
                    far[nearest].append((r[ok & (t > 3.0)] - t[ok & (t > 3.0)]) / t[ok & (t > 3.0)])
    med = {k: float(np.median(np.concatenate(v))) for k, v in rel.items()}
    med_far = {k: float(np.median(np.concatenate(v))) for k, v in far.items()}
    assert sum(len(v) for v in rel["surface"]) > 2000
    assert med["point"] < -0.003, med
    assert abs(med["surface"]) <= 0.0005, med
    assert abs(med_far["surface"]) <= 0.0005, med_far


def test_obstacle_scan_agrees_with_the_hokuyo_at_its_height():
    pose = (1.2, 1.4, 0.0)
    lm, model = laser_mount(), LaserModel()
    ranges = render_laser(ROOM, pose, lm, model, rng=np.random.default_rng(5))
    h = float(lm.translation[2])
    scans, a = kos_at(pose, [h])
    kos = scans[f"h{h:.2f}".replace(".", "_")]
    # laser end points into base_link, binned on the KOS bearings
    ang = model.angle_min + np.arange(len(ranges)) * model.angle_increment
    ok = np.isfinite(ranges)
    p = lm.apply(np.column_stack((ranges[ok] * np.cos(ang[ok]), ranges[ok] * np.sin(ang[ok]), np.zeros(ok.sum()))))
    bearing, rng_ = np.arctan2(p[:, 1], p[:, 0]), np.hypot(p[:, 0], p[:, 1])
    inc = a[1] - a[0]
    k = np.floor((bearing - a[0]) / inc + 0.5).astype(int)
    inside = (k >= 0) & (k < len(a))
    laser_on_bins = np.full(len(a), np.inf)
    np.minimum.at(laser_on_bins, k[inside], rng_[inside])
    shared = np.isfinite(kos) & np.isfinite(laser_on_bins)
    assert shared.sum() > 150  # (the door at x = 5 opens onto the far side room, beyond 4.5 m)
    assert np.median(np.abs(kos[shared] - laser_on_bins[shared])) <= 0.03


def test_table_top_at_its_level_only_and_low_box_only_low():
    levels = [0.15, 0.5, 0.75]
    # facing the table (x 1.9–3.1, top 0.75 m) from 0.7 m
    scans, a = kos_at((1.2, 2.5, 0.0), levels)
    ahead = np.abs(a) < math.radians(8)
    assert np.nanmedian(scans["h0_75"][ahead]) == pytest.approx(0.7, abs=0.08)
    # under the top the legs stand at the corners only: a stray flying pixel at most
    assert np.mean(scans["h0_50"][ahead] < 1.0) < 0.1
    # facing the 0.2 m box (x 4.0–4.4, y 0.4–0.8) from 2 m
    scans, a = kos_at((2.0, 0.6, 0.0), levels)
    box = np.abs(a) < math.radians(3)
    assert np.nanmedian(scans["h0_15"][box]) == pytest.approx(2.0, abs=0.08)
    assert np.nanmedian(scans[OBSTACLE][box]) == pytest.approx(2.0, abs=0.08)
    assert np.mean(scans["h0_50"][box] < 2.5) < 0.1
    assert np.mean(scans["h0_75"][box] < 2.5) < 0.1


def test_pitched_camera_gives_the_same_scan_as_a_level_one():
    pose = (1.2, 1.4, 0.3)
    level, _ = kos_at(pose, [0.9], [camera_mount()])
    pitched, _ = kos_at(pose, [0.9], [camera_mount(rpy=(0.0, math.radians(15), 0.0))])
    a, b = level["h0_90"], pitched["h0_90"]
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() >= 0.9 * np.isfinite(a).sum()
    assert np.median(np.abs(a[both] - b[both])) <= 0.01


def test_front_and_rear_cameras_cover_both_views():
    mounts = [camera_mount(), camera_mount(xyz=(-0.1, 0.0, 1.0), rpy=(0.0, 0.0, math.pi), frame_id="rear_optical")]
    scans, a = kos_at((3.8, 2.5, 0.0), [1.2], mounts)
    r = scans["h1_20"]
    deg = np.degrees(a)
    assert np.isfinite(r[np.abs(deg) < 30]).mean() > 0.9
    assert np.isfinite(r[np.abs(deg) > 150]).mean() > 0.9
    assert np.isnan(r[np.abs(np.abs(deg) - 90) < 40]).all()
