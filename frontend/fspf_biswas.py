"""The FSPF kernel (Biswas & Veloso 2012; thesis Algorithm 1), the baseline FSPF+ is measured against: its main
loop `fspf_kernel` reads as the algorithm, each step a compiled helper, its parameters in one record (Params)."""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from kosmap.frontend.fspf_kernels import _classify_nb, _randint, _refit_nb, _uniform, plane_through


# ---- FSPF (Biswas & Veloso; thesis Alg. 1) -----------------------------------------------------------------------------

# n_max: plane points wanted; k_max: neighbourhoods tried; l: local samples; eta: η, the pixel neighbourhood of d1, d2;
# size: S, the window's world size; eps: ε; alpha: α_in, the inlier fraction that accepts a plane
Params = namedtuple("Params", "fx fy cx cy min_d max_d n_max k_max l eta size eps alpha sl_min sl_max cam_h "
                              "ground_max_h")
S_PIXELS, S_INELIGIBLE, S_INLIERS, S_DROPPED, S_OUTLIERS, S_REMAINING = range(6)
# st, per pixel: 0 ineligible, 1 eligible, 2 examined (an outlier, in O), 3 plane point (in P), 4 dropped (its class)


@njit(cache=True, error_model="numpy")
def _depth_constraints_nb(flat, min_d, max_d, st):
    """st = 1 for the eligible pixels (NaN compares false), 0 else; branch-free. Returns their count."""
    n = 0
    for i in range(len(flat)):
        z = flat[i]
        ok = (z > min_d) & (z <= max_d)
        st[i] = ok
        n += ok
    return n


@njit(cache=True, error_model="numpy", inline="always")
def _point_nb(flat, j, W, prm):
    """The 3D point of pixel j (thesis eq. 2.1–2.2)."""
    r = j // W
    c = j - r * W
    z = np.float64(flat[j])
    return (c - prm.cx) * z / prm.fx, (r - prm.cy) * z / prm.fy, z


@njit(cache=True, error_model="numpy")
def _draw_d0_d1_d2_nb(state, st, H, W, eta):
    """d0 anywhere in the image, d1 and d2 within η of it; all three eligible. Returns their pixels, or −1s."""
    half = eta // 2
    r0 = _randint(state, H)
    c0 = _randint(state, W)
    i0 = r0 * W + c0
    if st[i0] == 0:
        return -1, -1, -1
    r1 = r0 + _randint(state, eta + 1) - half
    c1 = c0 + _randint(state, eta + 1) - half
    r2 = r0 + _randint(state, eta + 1) - half
    c2 = c0 + _randint(state, eta + 1) - half
    if r1 < 0 or r1 >= H or c1 < 0 or c1 >= W or r2 < 0 or r2 >= H or c2 < 0 or c2 >= W:
        return -1, -1, -1
    i1 = r1 * W + c1
    i2 = r2 * W + c2
    if st[i1] == 0 or st[i2] == 0:
        return -1, -1, -1
    return i0, i1, i2


@njit(cache=True, error_model="numpy")
def _local_samples_nb(flat, st, W, H, i0, zbar, nx, ny, nz, d, prm, state, loc, stats):
    """RANSAC's test of the plane (n, d) on l local samples in the w'×h' window of world size S around d0
    (w' = fx·S/z̄, h' = fy·S/z̄): the inliers (within ε) go to `loc` (pixel, x, y, z); the eligible outliers are
    examined (O). Stops as soon as α_in·l can no longer be reached. Returns (inliers, whether α_in was reached)."""
    li, lx, ly, lz = loc[0], loc[1], loc[2], loc[3]
    max_bad = prm.l - int(np.ceil(prm.alpha * prm.l - 1e-9))
    r0 = i0 // W
    c0 = i0 - r0 * W
    ww = prm.fx * prm.size / zbar
    wh = prm.fy * prm.size / zbar
    n_in = 0
    n_bad = 0
    for _s in range(prm.l):
        r = r0 + int(np.floor((_uniform(state) - 0.5) * wh + 0.5))
        c = c0 + int(np.floor((_uniform(state) - 0.5) * ww + 0.5))
        if r >= 0 and r < H and c >= 0 and c < W:
            j = r * W + c
            if st[j] != 0:
                z = np.float64(flat[j])
                x, y = (c - prm.cx) * z / prm.fx, (r - prm.cy) * z / prm.fy
                if abs(nx * x + ny * y + nz * z + d) < prm.eps:
                    li[n_in] = j
                    lx[n_in] = x
                    ly[n_in] = y
                    lz[n_in] = z
                    n_in += 1
                    continue
                if st[j] == 1:
                    st[j] = 2
                    stats[S_OUTLIERS] += 1
        n_bad += 1
        if n_bad > max_bad:  # α_in can no longer be reached
            return n_in, False
    return n_in, True


@njit(cache=True, error_model="numpy")
def _to_outliers_nb(loc, n_in, st, stats):
    """A rejected neighbourhood's inliers are examined: they join the outliers O."""
    li = loc[0]
    for a in range(n_in):
        if st[li[a]] == 1:
            st[li[a]] = 2
            stats[S_OUTLIERS] += 1


@njit(cache=True, error_model="numpy")
def _fit_nb(loc, n_in, prm, axes):
    """The plane refitted by least squares on the inliers, its normal facing the camera, and its class."""
    act = loc[4]
    for a in range(n_in):
        act[a] = a
    nx, ny, nz, d = _refit_nb(loc[1], loc[2], loc[3], act, n_in)
    if d < 0:
        nx, ny, nz, d = -nx, -ny, -nz, -d
    cls = _classify_nb(nx, ny, nz, d, axes[0], axes[1], axes[2], prm.sl_min, prm.sl_max, prm.cam_h, prm.ground_max_h)
    return nx, ny, nz, d, cls


@njit(cache=True, error_model="numpy")
def _drop_nb(loc, n_in, st, stats):
    """The inliers of a plane of a dropped class are set apart (not plane points, not outliers)."""
    li = loc[0]
    for a in range(n_in):
        j = li[a]
        if st[j] == 1 or st[j] == 2:
            stats[S_OUTLIERS] -= st[j] == 2
            st[j] = 4
            stats[S_DROPPED] += 1


@njit(cache=True, error_model="numpy")
def _add_plane_nb(loc, n_in, nx, ny, nz, d, cls, st, W, out, n_pl, stats):
    """Add P̂ to P and R̂ to R: the inliers not yet taken become the plane's points; the plane is recorded when it
    took any. Returns the planes' count."""
    li, lx, ly, lz = loc[0], loc[1], loc[2], loc[3]
    out_pix, out_pts, out_plane, pl_n, pl_d, pl_cls, pl_cnt = out
    n_out = stats[S_INLIERS]
    added = 0
    for a in range(n_in):
        j = li[a]
        if st[j] == 1 or st[j] == 2:
            stats[S_OUTLIERS] -= st[j] == 2
            st[j] = 3
            out_pix[n_out, 0] = j // W
            out_pix[n_out, 1] = j - (j // W) * W
            out_pts[n_out, 0] = lx[a]
            out_pts[n_out, 1] = ly[a]
            out_pts[n_out, 2] = lz[a]
            out_plane[n_out] = n_pl
            n_out += 1
            added += 1
    stats[S_INLIERS] = n_out
    if added == 0:
        return n_pl
    pl_n[n_pl, 0], pl_n[n_pl, 1], pl_n[n_pl, 2] = nx, ny, nz
    pl_d[n_pl] = d
    pl_cls[n_pl] = cls
    pl_cnt[n_pl] = added
    return n_pl + 1


@njit(cache=True, error_model="numpy")
def fspf_kernel(depth, prm, axes, drop, state, st, out, stats):
    """FSPF (thesis Alg. 1) on one depth image. prm: Params; axes: (up, forward, left); drop: bool per class; st:
    a reused buffer of ≥ H·W; out: (pixels, points, plane, normals, offsets, classes, counts); stats (S_*):
    Table 5.2's counts. Returns (points, planes) written to out."""
    H, W = depth.shape
    flat = depth.ravel()
    stats[:] = 0
    n_elig = _depth_constraints_nb(flat, prm.min_d, prm.max_d, st)
    loc = (np.empty(prm.l, np.int64), np.empty(prm.l), np.empty(prm.l), np.empty(prm.l), np.empty(prm.l, np.int32))
    n_pl = 0
    for _k in range(prm.k_max):  # while n < n_max and k < k_max
        if stats[S_INLIERS] + stats[S_DROPPED] >= prm.n_max:
            break
        i0, i1, i2 = _draw_d0_d1_d2_nb(state, st, H, W, prm.eta)
        if i0 < 0:
            continue
        x0, y0, z0 = _point_nb(flat, i0, W, prm)  # reconstruct p0, p1, p2
        x1, y1, z1 = _point_nb(flat, i1, W, prm)
        x2, y2, z2 = _point_nb(flat, i2, W, prm)
        ok, nx, ny, nz, d = plane_through(x0, y0, z0, x1, y1, z1, x2, y2, z2)  # r, the plane's normal
        if not ok:
            continue
        zbar = (z0 + z1 + z2) / 3.0
        n_in, accepted = _local_samples_nb(flat, st, W, H, i0, zbar, nx, ny, nz, d, prm, state, loc, stats)
        if not accepted:  # numInliers ≤ α_in·l: P̂ to O
            _to_outliers_nb(loc, n_in, st, stats)
            continue
        if n_in < 3:
            continue
        nx, ny, nz, d, cls = _fit_nb(loc, n_in, prm, axes)
        if drop[cls]:
            _drop_nb(loc, n_in, st, stats)
            continue
        n_pl = _add_plane_nb(loc, n_in, nx, ny, nz, d, cls, st, W, out, n_pl, stats)  # P̂ to P, R̂ to R
    stats[S_PIXELS] = H * W
    stats[S_INELIGIBLE] = H * W - n_elig
    stats[S_REMAINING] = n_elig - stats[S_INLIERS] - stats[S_DROPPED] - stats[S_OUTLIERS]
    return stats[S_INLIERS], n_pl
