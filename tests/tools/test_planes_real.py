"""FSPF+ and FSPF on the real depth frames of ../shared/data/depth: every dataset decodes and runs; the
labelled mOSD table plane is found as one plane, whole, at any seed."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.camera import DepthConfig, backproject, depth_constraints
from kosmap.frontend.fspf import FspfConfig, filter_planes, fspf_plus
from kosmap.frontend.planes import fit_plane
from kosmap.tools.datasets import DATASETS, iter_dataset, iter_samples

pytestmark = pytest.mark.data

# decoded depth ranges from SOURCES.md (metres, of the valid pixels)
RANGES = {"tum_fr1_xyz": (0.3, 3.8), "slambook2_ch5_rgbd": (0.2, 9.9), "cape_tunnel_frame": (0.2, 7.0),
          "pcl_mosd_plane_gt": (0.3, 2.0)}


def test_every_dataset_decodes_and_runs(data_dir):
    seen = set()
    wide = DepthConfig(max_depth=10.0)
    for s in iter_samples(data_dir / "depth", limit=2, every=97):
        seen.add(s.dataset)
        d = s.depth
        assert d.shape == (480, 640) and d.dtype == np.float32
        v = d[d > 0]
        assert 0.4 < v.size / d.size <= 1.0
        lo, hi = RANGES.get(s.dataset, (0.2, 10.0))
        assert lo <= np.median(v) <= hi and v.max() <= 10.0, (s.dataset, s.name)
        for method in ("fspf+", "fspf"):
            p = filter_planes(d, s.camera, FspfConfig(method=method, drop_classes=[]), wide, seed=0)
            st = p.stats
            assert st.ineligible + st.inliers + st.dropped + st.outliers + st.remaining == d.size
            assert len(p) >= 1 and st.inliers > (500 if method == "fspf" else 0.3 * st.eligible), (s.dataset, s.name)
    assert seen == set(DATASETS)


def test_sun_and_nyu_decoding(data_dir):
    s = {x.name: x for x in iter_dataset(data_dir / "depth" / "open3d_rgbd_formats")}
    sun = s["SUN"].depth
    assert 2.4 < np.median(sun[sun > 0]) < 3.0 and sun.max() == pytest.approx(9.87, abs=0.01)
    nyu = s["NYU"].depth
    assert nyu[nyu > 0].min() == pytest.approx(1.39, abs=0.02) and nyu.max() == pytest.approx(6.69, abs=0.02)
    assert 0.05 < (nyu == 0).mean() < 0.1  # 2047 = invalid, about 7 %


def test_mosd_table_is_one_plane(data_dir):
    samples = list(iter_dataset(data_dir / "depth" / "pcl_mosd_plane_gt"))
    assert len(samples) >= 2
    for s in samples:
        assert s.camera.fx == pytest.approx(525.0, abs=0.5)  # fitted from the organised cloud
        table = (s.labels >= 1) & (s.labels <= 9)
        assert table.sum() > 100000
        assert depth_constraints(s.depth, 0.5, 4.5)[table].mean() > 0.99
        r, c = np.nonzero(table)
        n_true = fit_plane(backproject(s.depth, s.camera, r, c))[0]
        cfg = FspfConfig(drop_classes=[])  # the defaults: 90 % analysed, the rest grown onto the planes found
        recalls, kept = [], {}
        for seed in range(5):
            p = fspf_plus(s.depth, s.camera, cfg, seed=seed)
            lab = p.label_image()
            for obj in np.unique(s.labels[s.labels >= 20]):
                kept.setdefault(int(obj), []).append((lab[s.labels == obj] > 0).mean())
            overlap = np.bincount(lab[table], minlength=len(p) + 1)[1:]
            k = int(overlap.argmax())
            recall, precision = overlap[k] / table.sum(), overlap[k] / p.counts[k]
            recalls.append(recall)
            assert recall >= 0.90 and precision >= 0.98, (s.name, seed, recall, precision)
            assert np.degrees(np.arccos(min(1.0, abs(p.normals[k] @ n_true)))) <= 0.5, (s.name, seed)
        assert np.mean(recalls) >= 0.95 and max(recalls) - min(recalls) <= 0.05, (s.name, recalls)
        # the boxes standing on the table are kept too (their faces are planes: most of their pixels), at the median
        # seed (a box's share varies by seed: which windows land on it)
        for obj, share in kept.items():
            assert np.median(share) >= 0.6, (s.name, obj, share)
        again = fspf_plus(s.depth, s.camera, cfg, seed=4)  # the same seed, the same planes
        assert np.array_equal(again.pixels, p.pixels) and np.array_equal(again.normals, p.normals)


def test_gravity_from_the_frames_agrees_with_the_kinects_accelerometer(data_dir):
    """TUM fr1_xyz, handheld over a desk: up from the dominant level plane family (the desk, tracked) against the
    Kinect's accelerometer averaged over ±0.25 s (at rest it reads the optical frame's up with x and y negated:
    its axes are the optical ones turned half a turn about z). The hand's accelerations move the accelerometer
    by a few degrees; the two agree to 2–3° in the median."""
    from kosmap.frontend.gravity import GravityTracker

    folder = data_dir / "depth" / "tum_fr1_xyz"
    acc = np.loadtxt(folder / "accelerometer.txt")
    tracker, errs = GravityTracker(), []
    for s in iter_dataset(folder, 20, 20):
        up = tracker.update(fspf_plus(s.depth, s.camera, FspfConfig(drop_classes=[]), seed=0))
        a = acc[np.abs(acc[:, 0] - s.stamp) < 0.25, 1:].mean(axis=0) * np.array([-1.0, -1.0, 1.0])
        errs.append(np.degrees(np.arccos(min(1.0, float(up @ a) / np.linalg.norm(a)))))
    assert tracker.frames == 20
    assert np.median(errs) < 4.0 and np.percentile(errs, 90) < 9.0, np.round(errs, 1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tum_floor_is_ground_with_gravity_from_the_frames(data_dir, seed):
    """TUM fr1_xyz, a handheld camera tilted over a desk, no mount, no IMU used: gravity from the frames, the floor's
    height tracked through the frames that see only the desk (frontend/gravity.FloorTracker), a level plane at the
    floor's height ground even when its fit tilts past [fspf] slanted_min_deg (gravity.on_floor).
    The label, from the ground-truth poses: the Kinect's accelerometer turned into the mocap frame and averaged over
    the sequence (the hand's accelerations cancel) gives up within ~2° (its own bias: the floor planes' mean normal
    lies 1.8–2.3° from it at every seed); a floor plane is within 10° of that up and 1.3 m or more below the camera
    (the desk lies 0.5–1.2 m below it). "Horizontal" is then the floor planes' own mean normal in the mocap frame.
    Of the floor planes ≥ 2000 px ≥ 90 % come out ground and ≥ 98 % of the ground planes are horizontal within 5°.
    No plane is ground before the floor is confirmed (gravity.FloorTracker): the desk is raised, also in the frames
    before the floor is first seen: ≥ 97 % of the ground planes are floor (99.3–100 % at these; taking the farthest
    level plane for the floor until then, 97–99 %; without the tracking, half)."""
    from scipy.spatial.transform import Rotation

    from kosmap.frontend.gravity import GravityTracker, reclassify
    from kosmap.frontend.planes import PLANE_CLASSES

    folder = data_dir / "depth" / "tum_fr1_xyz"
    acc, gt = np.loadtxt(folder / "accelerometer.txt"), np.loadtxt(folder / "groundtruth.txt")

    def rot(t):
        return Rotation.from_quat(gt[np.argmin(np.abs(gt[:, 0] - t)), 4:8]).as_matrix()

    acc_up = np.mean([rot(a[0]) @ (a[1:] * np.array([-1.0, -1.0, 1.0])) for a in acc[::5]], axis=0)
    acc_up /= np.linalg.norm(acc_up)
    cfg, tracker, rows = FspfConfig(drop_classes=[]), GravityTracker(), []
    for s in iter_dataset(folder, 200, 2):
        p = fspf_plus(s.depth, s.camera, cfg, seed=seed)
        p = reclassify(p, tracker.update(p, s.stamp, s.depth, s.camera), tracker.height, cfg)
        big = p.counts >= 2000
        rows += [(*(rot(s.stamp) @ n), d, c == PLANE_CLASSES.index("ground"))
                 for n, d, c in zip(p.normals[big], p.offsets[big], p.classes[big])]
    world, below, ground = np.array(rows)[:, :3], np.array(rows)[:, 3], np.array(rows)[:, 4] > 0
    floor = (world @ acc_up > np.cos(np.radians(10.0))) & (below > 1.3)
    up = world[floor].sum(axis=0) / np.linalg.norm(world[floor].sum(axis=0))
    assert np.degrees(np.arccos(up @ acc_up)) < 3.0  # the accelerometer's bias, as measured
    level = world @ up > np.cos(np.radians(5.0))
    assert floor.sum() >= 100 and (floor & ground).sum() / floor.sum() >= 0.90, ((floor & ground).sum(), floor.sum())
    assert (ground & level).sum() / ground.sum() >= 0.98, ((ground & level).sum(), ground.sum())
    assert (ground & floor).sum() / ground.sum() >= 0.97, ((ground & floor).sum(), ground.sum())
