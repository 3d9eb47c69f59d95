"""The KOS's image kernel (frontend/kos.py `KosAccumulator.add_depth`, what the pipeline runs): a depth image (and
FSPF+'s plane pixels) → per bin and band the nearest squared range (thesis Alg. 7) and, for the surface rule, the sums
of the ranges within the surface window of it.

From the per-pixel tables of kos_bins.pixel_table, base_link = d·(column term + row term) + mount offset: a
branch-free float32 pass over each image row that numba vectorises, then, per block of rows, the nearest range of each
column per bin and band, so one bin update stands for a whole column of the block (docs/bench/kos.md has the numbers).
The surface rule keeps every block's points of that pass and sums them per column in a second pass against the
nearest ranges the first found. Written by hand and compiled with numba: no library bins a depth image into several
height bands in one pass.
"""

from __future__ import annotations

import math
import threading
from collections import namedtuple

import numpy as np
from numba import njit

# The kernel's per-pixel tables (kos_bins.PixelTable), bearing grid and depth and range limits
ImageGrid = namedtuple("ImageGrid", "ax ay az bx by bz tx ty tz a0 inv_inc n_local bin0 n full_circle dmin dmax rmin2 "
                                    "rmax2")


# ---- the image kernel: per-pixel tables, vectorised rows, per-column reduction ------------------------------------

_ROWS = 8  # rows per block: one bin update per column and band stands for up to this many pixels
_NO_BIN = np.int32(1 << 30)
_F = np.float32
# Cephes atanf (S. Moshier): range reduction at tan(3π/8) and tan(π/8), then a degree-9 odd polynomial; ≤ 1.4e-7 rad
_T3P8, _TP8 = _F(2.414213562373095), _F(0.41421356237309503)
_PIO2, _PIO4 = _F(math.pi / 2), _F(math.pi / 4)
_A0, _A1, _A2, _A3 = _F(8.05374449538e-2), _F(-1.38776856032e-1), _F(1.99777106478e-1), _F(-3.33329491539e-1)


@njit(cache=True, error_model="numpy", inline="always")
def _atan2_front(y, x):  # pragma: no cover - compiled
    """atan2(y, x) for x > 0 in float32, branch-free so that a loop around it vectorises (no SVML here)."""
    ay = abs(y)
    big = ay > _T3P8 * x
    mid = ay > _TP8 * x
    num = -x if big else (ay - x if mid else ay)
    den = ay if big else (ay + x if mid else x)
    t = num / den
    base = _PIO2 if big else (_PIO4 if mid else _F(0.0))
    z = t * t
    a = base + ((((_A0 * z + _A1) * z + _A2) * z + _A3) * z * t + t)
    return -a if y < 0 else a


@njit(cache=True, error_model="numpy")
def _row_bins(drow, mrow, ax, ay, az, bx, by, bz, tx, ty, tz, a0, inv_inc, n_local, zmin, zmax, dmin, dmax, rmin2,
              rmax2, ks, r2s, zs):  # pragma: no cover - compiled
    """One image row, branch-free (numba vectorises it): local bin (−1: dropped), squared range and height per pixel.

    The point of pixel (u, v) at depth d in base_link, turned to the view centre, is t + d·(a[u] + b[v]): the
    column and row terms of the pinhole ray times the mount rotation (thesis eq. 2.1–2.2, then the mount).
    """
    for u in range(drow.shape[0]):
        d = drow[u] if mrow[u] else _F(0.0)
        z = tz + d * (az[u] + bz)
        x = tx + d * (ax[u] + bx)
        y = ty + d * (ay[u] + by)
        r2 = x * x + y * y
        fk = (np.float64(_atan2_front(y, x)) - a0) * inv_inc + 0.5
        ok = ((d > dmin) & (d <= dmax) & (z >= zmin) & (z <= zmax) & (r2 >= rmin2) & (r2 <= rmax2) & (x > 0)
              & (fk >= 0) & (fk < n_local))
        ks[u] = np.int32(fk) if ok else np.int32(-1)
        r2s[u] = r2
        zs[u] = z


@njit(cache=True, error_model="numpy")
def _column_bins(ks, kmin, kmax):  # pragma: no cover - compiled
    """Per column of a block: its lowest and highest local bin (kmax −1: nothing in the column)."""
    for u in range(ks.shape[1]):
        a = _NO_BIN
        b = np.int32(-1)
        for r in range(_ROWS):
            k = ks[r, u]
            a = min(a, k if k >= 0 else _NO_BIN)
            b = max(b, k)
        kmin[u] = a
        kmax[u] = b


@njit(cache=True, error_model="numpy")
def _column_band_min(ks, r2s, zs, lo, hi, kmin, kmax, m_lo, m_hi):  # pragma: no cover - compiled
    """Per column of a block, for one band: the nearest squared range among its points in the column's lowest
    and in its highest bin (vectorised over columns)."""
    inf = _F(np.inf)
    for u in range(ks.shape[1]):
        a = inf
        b = inf
        k0 = kmin[u]
        k1 = kmax[u]
        for r in range(_ROWS):
            k = ks[r, u]
            z = zs[r, u]
            v = r2s[r, u] if (z >= lo) & (z <= hi) else inf  # (k = −1, dropped, matches only a column without points)
            a = min(a, v if k == k0 else inf)
            b = min(b, v if k == k1 else inf)
        m_lo[u] = a
        m_hi[u] = b


@njit(cache=True, error_model="numpy")
def _global_bin(k, bin0, n, full_circle):  # pragma: no cover - compiled
    b = bin0 + k
    if full_circle:
        if b >= n:
            b -= n
        elif b < 0:
            b += n
    return b


@njit(cache=True, error_model="numpy")
def _column_scatter(ks, r2s, zs, lo, hi, kmin, kmax, m_lo, m_hi, bin0, n, full_circle, out2):  # pragma: no cover
    """Nearest range per bin and band: one update per column and bin; columns spread over > 2 bins point by point."""
    n_band = lo.shape[0]
    for u in range(ks.shape[1]):
        k1 = kmax[u]
        if k1 < 0:
            continue
        k0 = kmin[u]
        if k1 - k0 <= 1:
            b = _global_bin(k0, bin0, n, full_circle)
            for j in range(n_band):
                if m_lo[j, u] < out2[b, j]:
                    out2[b, j] = m_lo[j, u]
            if k1 != k0:
                b = _global_bin(k1, bin0, n, full_circle)
                for j in range(n_band):
                    if m_hi[j, u] < out2[b, j]:
                        out2[b, j] = m_hi[j, u]
            continue
        for r in range(_ROWS):
            k = ks[r, u]
            if k < 0:
                continue
            b = _global_bin(k, bin0, n, full_circle)
            z = zs[r, u]
            r2 = r2s[r, u]
            for j in range(n_band):
                if z >= lo[j] and z <= hi[j] and r2 < out2[b, j]:
                    out2[b, j] = r2

@njit(cache=True, error_model="numpy", inline="always")
def _block_points(depth, mask, v0, g, zmin, zmax, ks, r2s, zs):  # pragma: no cover - compiled
    """The points of a block of rows from v0 into ks, r2s, zs (_ROWS × w): each pixel's point in base_link, its height
    and range tested and its bearing binned (_row_bins); rows past the image's last are empty."""
    rows = min(_ROWS, depth.shape[0] - v0)
    for r in range(rows):
        v = v0 + r
        _row_bins(depth[v], mask[v], g.ax, g.ay, g.az, g.bx[v], g.by[v], g.bz[v], g.tx, g.ty, g.tz, g.a0, g.inv_inc,
                  g.n_local, zmin, zmax, g.dmin, g.dmax, g.rmin2, g.rmax2, ks[r], r2s[r], zs[r])
    for r in range(rows, _ROWS):
        ks[r, :] = -1


@njit(cache=True, error_model="numpy")
def _any_finite(a, b):  # pragma: no cover - compiled
    """Whether a or b holds a finite value (an integer count: LLVM vectorises it, a float min it does not)."""
    n = 0
    for u in range(a.shape[0]):
        n += 1 if (a[u] < np.inf) | (b[u] < np.inf) else 0
    return n > 0


@njit(cache=True, error_model="numpy")
def _accumulate_image(depth, mask, g, lo, hi, out2, pts):  # pragma: no cover - compiled
    """Thesis Alg. 7 over the pixels of a depth image where `mask` is set (0 / NaN depths dropped), every band at
    once into out2 (bins × bands, squared ranges), in blocks of _ROWS rows: the block's points in base_link with
    their height and bearing bin, then per column its lowest and highest bin, the column's nearest in each per band,
    and one bin update per column and bin. g: ImageGrid. pts (image_buffers): the blocks' local bins, squared
    ranges and heights (blocks × _ROWS × w), columns' lowest and highest bins (blocks × w) and whether a band holds
    points (blocks × bands), for one block (reused) or for every block (kept for _surface_image)."""
    ks, r2s, zs, kmin, kmax, present = pts
    keep = ks.shape[0] > 1
    m_lo = np.empty((lo.shape[0], ks.shape[2]), np.float32)
    m_hi = np.empty((lo.shape[0], ks.shape[2]), np.float32)
    zmin = lo.min()
    zmax = hi.max()
    for i in range((depth.shape[0] + _ROWS - 1) // _ROWS):
        o = i if keep else 0
        _block_points(depth, mask, i * _ROWS, g, zmin, zmax, ks[o], r2s[o], zs[o])
        _column_bins(ks[o], kmin[o], kmax[o])
        for j in range(lo.shape[0]):
            _column_band_min(ks[o], r2s[o], zs[o], lo[j], hi[j], kmin[o], kmax[o], m_lo[j], m_hi[j])
            if keep:
                present[o, j] = _any_finite(m_lo[j], m_hi[j])
        _column_scatter(ks[o], r2s[o], zs[o], lo, hi, kmin[o], kmax[o], m_lo, m_hi, g.bin0, g.n, g.full_circle, out2)


# ---- the surface rule's pass over the kept blocks -----------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _image_columns(kmin, kmax, k_lo, k_hi):  # pragma: no cover - compiled
    """Per image column, its lowest and highest local bin over all blocks (k_hi −1: nothing in the column)."""
    k_lo[:] = _NO_BIN
    k_hi[:] = -1
    for o in range(kmin.shape[0]):
        for u in range(kmin.shape[1]):
            k_lo[u] = min(k_lo[u], kmin[o, u])
            k_hi[u] = max(k_hi[u], kmax[o, u])


@njit(cache=True, error_model="numpy")
def _column_band_sum(ks, r2s, rs, zs, lo, hi, k_lo, k_hi, lim_lo, lim_hi, s_lo, c_lo, s_hi, c_hi):  # pragma: no cover
    """One block's points added to its columns' sums for one band: per column, the sum and count of the ranges of
    its points in the column's lowest and in its highest bin (k_lo, k_hi over the whole image) whose squares are
    within that bin's limit (lim_lo, lim_hi), row by row and vectorised over columns (with the rows innermost LLVM
    vectorises nothing). Float32 ranges of at least min_range are multiples of its float32 spacing, so their float64
    sums are exact in any order (while a bin's sum stays below 2²⁹·min_range, 2.7·10⁸ m at 0.5 m): these partial
    sums give the bins the sums point by point would, bit for bit (tests/frontend/test_kos_surface.py)."""
    for r in range(_ROWS):
        for u in range(ks.shape[1]):
            k = ks[r, u]
            z = zs[r, u]
            r2 = r2s[r, u]
            v = np.float64(rs[r, u])
            inb = (z >= lo) & (z <= hi) & (k >= 0)
            a = inb & (k == k_lo[u]) & (r2 <= lim_lo[u])
            b = inb & (k == k_hi[u]) & (r2 <= lim_hi[u])
            s_lo[u] += v if a else 0.0
            c_lo[u] += 1.0 if a else 0.0
            s_hi[u] += v if b else 0.0
            c_hi[u] += 1.0 if b else 0.0


@njit(cache=True, error_model="numpy")
def _between_points(ks, r2s, zs, lo, hi, k_lo, k_hi, lim2, bin0, n, full_circle, s, c):  # pragma: no cover - compiled
    """The points of columns spread over more than two bins that lie in neither the column's lowest nor its highest
    bin, point by point into the bins (s, c: bins × bands)."""
    for u in range(k_lo.shape[0]):
        if k_hi[u] - k_lo[u] <= 1:
            continue
        for o in range(ks.shape[0]):
            for r in range(_ROWS):
                k = ks[o, r, u]
                if k <= k_lo[u] or k >= k_hi[u]:
                    continue
                b = _global_bin(k, bin0, n, full_circle)
                z = zs[o, r, u]
                r2 = r2s[o, r, u]
                for j in range(lo.shape[0]):
                    if z >= lo[j] and z <= hi[j] and r2 <= lim2[b, j]:
                        s[b, j] += math.sqrt(r2)
                        c[b, j] += 1


@njit(cache=True, error_model="numpy")
def _surface_image(pts, g, lo, hi, lim2, s, c):  # pragma: no cover - compiled
    """The surface rule (KosAccumulator) over the blocks `_accumulate_image` kept in pts: per bin and band, the sum
    `s` and count `c` of the ranges whose square is no more than `lim2` (bins × bands: the nearest range plus the
    window). Per image column, sums per band in its lowest and highest bin over all blocks (vectorised over columns),
    then one update per column, bin and band; points of a column's other bins one by one."""
    ks, r2s, zs, kmin, kmax, present = pts
    n_band, w = lo.shape[0], ks.shape[2]
    k_lo, k_hi = np.empty(w, np.int32), np.empty(w, np.int32)
    _image_columns(kmin, kmax, k_lo, k_hi)
    lim_lo, lim_hi = np.full((n_band, w), -1.0, np.float32), np.full((n_band, w), -1.0, np.float32)
    for u in range(w):
        if k_hi[u] >= 0:
            b0 = _global_bin(k_lo[u], g.bin0, g.n, g.full_circle)
            b1 = _global_bin(k_hi[u], g.bin0, g.n, g.full_circle)
            for j in range(n_band):
                lim_lo[j, u] = lim2[b0, j]
                lim_hi[j, u] = lim2[b1, j]
    s_lo, s_hi, c_lo, c_hi = np.zeros((n_band, w)), np.zeros((n_band, w)), np.zeros((n_band, w)), np.zeros((n_band, w))
    rs = np.empty((_ROWS, w), np.float32)
    for o in range(ks.shape[0]):
        r2b = r2s[o]
        for r in range(_ROWS):
            for u in range(w):
                rs[r, u] = math.sqrt(r2b[r, u])
        for j in range(n_band):
            if not present[o, j]:  # (no point of the block in the band)
                continue
            _column_band_sum(ks[o], r2b, rs, zs[o], lo[j], hi[j], k_lo, k_hi, lim_lo[j], lim_hi[j], s_lo[j], c_lo[j],
                             s_hi[j], c_hi[j])
    for u in range(w):
        if k_hi[u] < 0:
            continue
        b0 = _global_bin(k_lo[u], g.bin0, g.n, g.full_circle)
        b1 = _global_bin(k_hi[u], g.bin0, g.n, g.full_circle)
        for j in range(n_band):
            s[b0, j] += s_lo[j, u]
            c[b0, j] += np.int64(c_lo[j, u])
            if b1 != b0:
                s[b1, j] += s_hi[j, u]
                c[b1, j] += np.int64(c_hi[j, u])
    _between_points(ks, r2s, zs, lo, hi, k_lo, k_hi, lim2, g.bin0, g.n, g.full_circle, s, c)


@njit(cache=True, error_model="numpy")
def _surface_rule(depth, mask, g, lo, hi, window, pts, out2):  # pragma: no cover - compiled
    """The surface rule (KosAccumulator) for one image, in one call: the nearest squared range per bin and band
    (`_accumulate_image`, keeping the blocks in pts), the limit (nearest range + window)² per bin and band in float32,
    the ranges within it summed (`_surface_image`), and each bin's mean squared; out2 (bins × bands) keeps the nearer
    of it and what it holds (an earlier camera's)."""
    near2 = np.full(out2.shape, np.inf, np.float32)
    _accumulate_image(depth, mask, g, lo, hi, near2, pts)
    lim2 = np.empty_like(near2)
    for b in range(near2.shape[0]):
        for j in range(near2.shape[1]):
            q = np.float32(math.sqrt(near2[b, j])) + window
            lim2[b, j] = q * q
    s = np.zeros(near2.shape)
    c = np.zeros(near2.shape, np.int64)
    _surface_image(pts, g, lo, hi, lim2, s, c)
    for b in range(near2.shape[0]):
        for j in range(near2.shape[1]):
            if c[b, j] > 0:
                m = np.float32(s[b, j] / c[b, j])
                out2[b, j] = min(out2[b, j], m * m)


@njit(cache=True, error_model="numpy")
def _pixels_mask(pixels, mask):  # pragma: no cover - compiled
    """Set `mask` (H×W uint8) at the given pixels (N×2 row, col; e.g. FSPF+'s plane points); others stay as they
    are."""
    w = np.uint32(mask.shape[1])
    size = np.uint32(mask.size)
    dst = mask.ravel()
    for i in range(pixels.shape[0]):
        p = np.uint32(pixels[i, 0]) * w + np.uint32(pixels[i, 1])  # unsigned: no negative-index wrap test
        if p < size:  # (a pixel above or below the image is ignored)
            dst[p] = 1


_SCRATCH = threading.local()


def pixel_mask(shape: tuple[int, int], pixels: np.ndarray | None) -> np.ndarray:
    """The pixels to use as a uint8 H×W mask: all (a shared array of ones) or those given (a per-thread buffer,
    reused: a fresh one costs its page faults). One of each per image shape (cameras may differ)."""
    cache = getattr(_SCRATCH, "masks", None)
    if cache is None:
        cache = _SCRATCH.masks = {}
    key = (pixels is None, tuple(shape))
    buf = cache.get(key)
    if buf is None:
        buf = cache[key] = np.ones(shape, np.uint8) if pixels is None else np.zeros(shape, np.uint8)
    elif pixels is not None:
        buf.fill(0)
    if pixels is not None:
        _pixels_mask(np.ascontiguousarray(pixels), buf)
    return buf

def image_buffers(shape: tuple[int, int], n_band: int, keep: bool) -> tuple:
    """`_accumulate_image`'s block buffers for an H×W image: one block, reused, or (`keep`, the surface rule) every
    block, per thread and reused (a fresh 2.6 MB costs its page faults)."""
    cache = getattr(_SCRATCH, "blocks", None)
    if cache is None:
        cache = _SCRATCH.blocks = {}
    h, w = shape
    key = (keep, h, w, n_band)
    buf = cache.get(key)
    if buf is None:
        nb = (h + _ROWS - 1) // _ROWS if keep else 1
        buf = cache[key] = (np.empty((nb, _ROWS, w), np.int32), np.empty((nb, _ROWS, w), np.float32),
                            np.empty((nb, _ROWS, w), np.float32), np.empty((nb, w), np.int32),
                            np.empty((nb, w), np.int32), np.empty((nb, n_band), np.bool_))
    return buf
