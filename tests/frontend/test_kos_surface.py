"""The KOS surface rule's one-pass image kernel (frontend/kos_image.py: the blocks of the nearest-range pass kept and
summed per column) gives, bit for bit, the two-pass rule it stands for: per bin and band the nearest squared range over
the image, then the mean of the ranges within (nearest + window)² of it, summed point by point. The reference below
is that rule in numpy over the same points (each pixel's bin, squared range and height from the kernel's row pass),
on simulated frames of two worlds: level, pitched and rolled cameras (columns over one, two and many bins), bins of
one column, of a fraction of one and of several, two cameras on a full circle, and an image whose rows are not a
whole number of the kernel's blocks. The point kernel (`add`) is held
to the same rule."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.camera import DepthConfig, backproject, depth_constraints
from kosmap.frontend.fspf import FspfConfig, filter_planes
from kosmap.frontend.kos import KosAccumulator, KosConfig, bearings_for, camera_view
from kosmap.frontend.kos_image import image_buffers
from kosmap.frontend.kos_points import point_bins
from kosmap.tools.simulate import load_world, render_depth
from kosmap.tools.simulate.render import camera_mount, kinect_v2_model

CAM = kinect_v2_model()
DEPTH = DepthConfig()
WINDOW = np.float32(0.08)
LEVELS = [0.3, 0.45, 0.75, 1.5]  # 0.3 and 0.45 overlap: a point in two level bands


def rule_in_numpy(bins, r2, z, lo, hi, n_bins):
    """Bins × bands float32 squared range of the surface rule, two passes point by point (+inf: empty)."""
    near2 = np.full((n_bins, len(lo)), np.inf, np.float32)
    total = np.zeros((n_bins, len(lo)))
    count = np.zeros((n_bins, len(lo)), np.int64)
    for j in range(len(lo)):
        sel = (bins >= 0) & (z >= lo[j]) & (z <= hi[j])
        np.minimum.at(near2[:, j], bins[sel], r2[sel])
    lim2 = np.square(np.sqrt(near2) + WINDOW)
    for j in range(len(lo)):
        sel = (bins >= 0) & (z >= lo[j]) & (z <= hi[j])
        sel[sel] = r2[sel] <= lim2[bins[sel], j]
        np.add.at(total[:, j], bins[sel], np.sqrt(r2[sel]).astype(np.float64))
        np.add.at(count[:, j], bins[sel], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.square(np.where(count > 0, total / count, np.inf).astype(np.float32))


def kept_points(cfg, b, cam, depth, mount, pixels):
    """A fresh accumulator given this one image, and each pixel's global bin (−1: dropped), squared range and height
    as the image kernel's row pass gave them (the blocks it keeps)."""
    one = KosAccumulator(cfg, b, DEPTH.min_depth, DEPTH.max_depth, float(WINDOW))
    one.add_depth(depth, cam, mount, pixels)
    ks, r2s, zs = (a.reshape(-1, a.shape[-1])[:depth.shape[0]] for a in image_buffers(depth.shape, 5, True)[:3])
    tb = one._pixel_table(cam, mount)
    bins = np.where(ks >= 0, (ks + tb.bin0) % b.n if b.full_circle else ks + tb.bin0, -1)
    return one, bins.ravel(), r2s.ravel(), zs.ravel()


CASES = [  # world, pose, camera rpy, bin width (deg; 0: one per column), two cameras, image size
    ("office", (5.0, 3.0, 0.0), (0.0, 0.0, 0.0), 0.0, False, (512, 424)),
    ("office", (6.0, 4.0, 2.0), (0.3, 0.35, 0.0), 0.07, False, (512, 424)),
    ("room", (2.0, 2.0, 1.0), (-0.5, 0.2, 0.4), 1.0, True, (512, 424)),
    ("room", (1.5, 1.5, 0.2), (0.0, 0.6, 0.0), 0.0, True, (512, 424)),
    ("office", (3.0, 2.0, 1.5), (0.2, 0.3, 0.0), 0.0, True, (161, 99)),  # rows not a whole number of blocks
]


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_image_kernel_surface_rule_bit_identical_to_two_passes(case):
    world_name, pose, rpy, inc, two, (w, h) = case
    cam = kinect_v2_model(width=w, height=h)
    world = load_world(world_name)
    mounts = [camera_mount(rpy=rpy)] + ([camera_mount(xyz=(-0.1, 0.05, 0.8), rpy=(rpy[0], rpy[1], rpy[2] + 2.5),
                                                       frame_id="rear_optical")] if two else [])
    cfg = KosConfig(levels=LEVELS)
    b = bearings_for([(cam, m) for m in mounts], inc)
    acc = KosAccumulator(cfg, b, DEPTH.min_depth, DEPTH.max_depth, float(WINDOW))
    want = np.full((b.n, len(LEVELS) + 1), np.inf, np.float32)
    spread = 0
    for k, mount in enumerate(mounts):
        depth, _ = render_depth(world, pose, mount, cam, rng=np.random.default_rng(k))
        pixels = filter_planes(depth, cam, FspfConfig(analysed_fraction=0.99), DEPTH, mount, seed=k).pixels
        for pix in (pixels, None):  # FSPF+'s plane pixels, then every valid pixel into the same bins
            one, bins, r2, z = kept_points(cfg, b, cam, depth, mount, pix)
            ref = rule_in_numpy(bins, r2, z, one.lo.astype(np.float32), one.hi.astype(np.float32), b.n)
            np.testing.assert_array_equal(np.sqrt(ref.T), one.ranges)  # this camera alone, bit for bit
            np.minimum(want, ref, out=want)
            acc.add_depth(depth, cam, mount, pix)
            cols = bins.reshape(depth.shape)
            spread = max(spread, int(np.max(np.where(cols >= 0, cols, -1).max(0) -
                                            np.where(cols >= 0, cols, 1 << 30).min(0))))
    got = acc.ranges
    np.testing.assert_array_equal(np.sqrt(want.T), got)  # cameras and sources in turn: the nearest mean per bin
    assert np.isfinite(got).mean() > 0.2  # the frames do fill the scans
    if rpy != (0.0, 0.0, 0.0):
        assert spread >= 2  # some column's pixels lie in three bins or more (the point-by-point path)


def test_point_kernel_surface_rule_bit_identical_to_two_passes():
    """`add` (N×3 points): the surface rule's means bit for bit as two passes over the points in numpy."""
    mount = camera_mount(rpy=(0.2, 0.3, 0.0))
    depth, _ = render_depth(load_world("office"), (6.0, 4.0, 2.0), mount, CAM, rng=np.random.default_rng(5))
    rows, cols = np.nonzero(depth_constraints(depth, DEPTH.min_depth, DEPTH.max_depth))
    pts = backproject(depth, CAM, rows, cols).astype(np.float32)
    cfg = KosConfig(levels=LEVELS)
    b = bearings_for([(CAM, mount)])
    lo, hi = camera_view(CAM, mount)
    acc = KosAccumulator(cfg, b, DEPTH.min_depth, DEPTH.max_depth, float(WINDOW))
    acc.add(pts, mount, (hi - lo) / 2)
    m = mount.matrix()
    g = _point_grid(acc, m, (hi - lo) / 2)
    bins, r, z = point_bins(pts, m[:3, :3].copy(), m[:3, 3].copy(), acc.lo, acc.hi, g)
    near = np.full((len(acc.lo), b.n), np.inf, np.float32)
    for j in range(len(acc.lo)):
        sel = (bins >= 0) & (z >= acc.lo[j]) & (z <= acc.hi[j])
        np.minimum.at(near[j], bins[sel], r[sel].astype(np.float32))
    total, count = np.zeros(near.shape), np.zeros(near.shape, np.int64)
    for j in range(len(acc.lo)):
        sel = (bins >= 0) & (z >= acc.lo[j]) & (z <= acc.hi[j])
        sel[sel] = r[sel] <= near[j, bins[sel]].astype(np.float64) + float(WINDOW)
        for i in np.flatnonzero(sel):  # in point order, as the kernel adds them (float64 sums depend on order)
            total[j, bins[i]] += r[i]
            count[j, bins[i]] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        want = np.where(count > 0, total / count, np.inf).astype(np.float32)
    assert np.isfinite(want).mean() > 0.2
    np.testing.assert_array_equal(want, acc.ranges)


def _point_grid(acc, m, view_half):
    from kosmap.frontend.kos_points import PointGrid

    tb = acc._table(m, view_half)
    b = acc.bearings
    return PointGrid(tb.cos_c, tb.sin_c, tb.t_min, tb.scale, tb.first, tb.tan_edges, tb.bin0, b.n, b.full_circle,
                     acc.min_range ** 2, acc.max_range ** 2)
