"""The KOS's point kernel (frontend/kos.py `KosAccumulator.add`, the reference): N×3 points of a camera's frame →
per point its bearing bin, horizontal range and height in base_link, then per level and bin the nearest range (thesis
Alg. 7) or the sums of the surface rule. Written by hand and compiled with numba: no library bins a cloud into
several height bands in one pass."""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

# The kernel's bearing grid (kos_bins.BearingTable) and range limits
PointGrid = namedtuple("PointGrid", "cos_c sin_c t_min scale first tan_edges bin0 n full_circle rmin2 rmax2")


@njit(cache=True, error_model="numpy", inline="always")
def _to_base(R, t, px, py, pz):  # pragma: no cover - compiled
    """A point of the camera's frame in base_link (the mount R, t)."""
    x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
    y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
    z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
    return x, y, z


@njit(cache=True, error_model="numpy")
def _bearing_bin(x, y, g):  # pragma: no cover - compiled
    """The global bearing bin of (x, y) from the tangent table of kos_bins.BearingTable; −1 outside the grid or behind."""
    xc = x * g.cos_c + y * g.sin_c
    if xc <= 0.0:
        return -1
    tt = (y * g.cos_c - x * g.sin_c) / xc
    fj = (tt - g.t_min) * g.scale
    if not (fj >= 0.0 and fj < g.first.shape[0]):  # (int() truncates towards 0: test before, or bin 0 takes 1/8 bin too much)
        return -1
    k = g.first[int(fj)]
    while k + 1 < g.tan_edges.shape[0] - 1 and tt >= g.tan_edges[k + 1]:
        k += 1
    b = g.bin0 + k
    if g.full_circle:
        return b % g.n
    return b if 0 <= b < g.n else -1


@njit(cache=True)
def _point_bins(pts, R, t, zmin, zmax, g, bins, rs, zs):  # pragma: no cover - compiled
    """Each point into base_link, its height tested against the bands' span, its horizontal range against the limits
    and its bearing binned: per point the global bin (−1: dropped), range and height. g: PointGrid."""
    for i in range(pts.shape[0]):
        bins[i] = -1
        x, y, z = _to_base(R, t, pts[i, 0], pts[i, 1], pts[i, 2])
        if not (z >= zmin and z <= zmax):  # in some level's band (also drops NaN points)
            continue
        r2 = x * x + y * y
        if r2 < g.rmin2 or r2 > g.rmax2:
            continue
        bins[i] = _bearing_bin(x, y, g)
        rs[i] = math.sqrt(r2)
        zs[i] = z


@njit(cache=True)
def _nearest_points(bins, rs, zs, lo, hi, out):  # pragma: no cover - compiled
    """Thesis Alg. 7 for all levels at once: out[level, bin] ← the nearest range of the points in the level's band."""
    for i in range(bins.shape[0]):
        b = bins[i]
        if b < 0:
            continue
        for lev in range(lo.shape[0]):
            if zs[i] >= lo[lev] and zs[i] <= hi[lev] and rs[i] < out[lev, b]:
                out[lev, b] = rs[i]


@njit(cache=True)
def _surface_points(bins, rs, zs, lo, hi, lim, s, c):  # pragma: no cover - compiled
    """The surface rule's sums (KosAccumulator): per level and bin the sum `s` and count `c` of the ranges no farther
    than `lim` (levels × bins; the nearest range plus the surface window)."""
    for i in range(bins.shape[0]):
        b = bins[i]
        if b < 0:
            continue
        for lev in range(lo.shape[0]):
            if zs[i] >= lo[lev] and zs[i] <= hi[lev] and rs[i] <= lim[lev, b]:
                s[lev, b] += rs[i]
                c[lev, b] += 1


def point_bins(pts: np.ndarray, R: np.ndarray, t: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               g: PointGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bin, range, height) of each of the N×3 float32 points `pts` (frame of the mount R, t); bin −1: dropped."""
    n = pts.shape[0]
    bins, rs, zs = np.empty(n, np.int64), np.empty(n), np.empty(n)
    _point_bins(pts, R, t, lo.min(), hi.max(), g, bins, rs, zs)
    return bins, rs, zs
