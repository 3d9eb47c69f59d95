"""The FSPF+ kernel (thesis Algorithm 3, with Alg. 4–6): its main loop `fspf_plus_kernel` reads as the algorithm,
each step and each of kosmap's extensions a compiled helper (frontend/fspf.py describes them)."""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from kosmap.frontend.fspf_coherence import _split_bridge_nb
from kosmap.frontend.fspf_kernels import (_classify_nb, _curved_nb, _grow_nb, _inlier_fit_nb, _partition_nb, _randint,
                                          _ransac_need, _score_nb, _unmark_nb, _window_sample_nb, plane_through,
                                          window_point)


# ---- FSPF+ (thesis Alg. 3, 5, 6) -----------------------------------------------------------------------------------------

# The FSPF+ kernel: its parameters in one record (Params), its buffers in two tuples, its counters in `stats`
# (S_* indices), and its main loop as the thesis's Algorithm 3, each step and each of our extensions a helper.

Params = namedtuple("Params", "fx fy cx cy min_d max_d n_min omega delta eps beta frac subset max_iter per_window "
                              "extra_min bend_max min_width tail_eps coherence grow sl_min sl_max cam_h ground_max_h")
S_PIXELS, S_INELIGIBLE, S_INLIERS, S_DROPPED, S_OUTLIERS, S_REMAINING, S_WINDOWS, S_VISITED, S_BENT, S_THIN, \
    S_SPLIT, S_GROWN = range(12)


@njit(cache=True, error_model="numpy")
def _depth_constraints_nb(flat, min_d, max_d, st, cand):
    """depthConstraints (thesis Alg. 4): st = 1 for eligible pixels (NaN compares false), 0 else (a vectorised
    pass); their indices into cand, in image order, eight pixels at a time where st holds eight 1s or eight 0s
    (one 64-bit word), one at a time, branch-free, elsewhere. Returns their count."""
    n = len(flat)
    for i in range(n):
        z = flat[i]
        st[i] = (z > min_d) & (z <= max_d)
    nw = n // 8
    words = st[:nw * 8].view(np.uint64)
    ones = np.uint64(0x0101010101010101)
    m = 0
    for w in range(nw):
        v = words[w]
        i = w * 8
        if v == ones:
            for b in range(8):
                cand[m + b] = i + b
            m += 8
        elif v != 0:
            for b in range(i, i + 8):
                cand[m] = b
                m += st[b]
    for i in range(nw * 8, n):
        cand[m] = i
        m += st[i]
    return m


@njit(cache=True, error_model="numpy")
def _draw_p0_nb(state, cand, m, st):
    """p0: a random eligible, unconsumed pixel; consumed candidates are removed lazily. Returns (p0 or −1, m)."""
    i = _randint(state, m)
    i0 = cand[i]
    if st[i0] != 1:
        m -= 1
        cand[i] = cand[m]
        return -1, m
    return i0, m


@njit(cache=True, error_model="numpy")
def _draw_p1_p2_nb(state, flat, st, i0, W, H, omega):
    """p1, p2: eligible unconsumed pixels within Ω of p0 (40 tries). Returns the mean depth z̄ of p0, p1, p2, or
    −1 when p0 is isolated."""
    r0 = i0 // W
    c0 = i0 - r0 * W
    found = 0
    j1 = -1
    zs = np.float64(flat[i0])
    for _ in range(40):
        r = r0 + _randint(state, 2 * omega + 1) - omega
        c = c0 + _randint(state, 2 * omega + 1) - omega
        if r < 0 or r >= H or c < 0 or c >= W:
            continue
        j = r * W + c
        if j == i0 or j == j1 or st[j] != 1:
            continue
        zs += flat[j]
        j1 = j
        found += 1
        if found == 2:
            return zs / 3.0
    return -1.0


@njit(cache=True, error_model="numpy")
def _gather_window_nb(flat, st, i0, zbar, prm, W, H, wp, stats):
    """The search window: the world size Δ at the mean depth, W = fx·Δ/z̄, H = fy·Δ/z̄ around p0, clipped at the
    border; its eligible pixels are consumed and listed in image order as packed pixels (wp: row << 16 | column;
    fspf_kernels.window_point makes them 3D points where a step needs them). Returns their count."""
    r0 = i0 // W
    c0 = i0 - r0 * W
    hw = int(0.5 * prm.fx * prm.delta / zbar + 0.5)
    hh = int(0.5 * prm.fy * prm.delta / zbar + 0.5)
    r_lo, r_hi = max(0, r0 - hh), min(H - 1, r0 + hh)
    c_lo, c_hi = max(0, c0 - hw), min(W - 1, c0 + hw)
    stats[S_WINDOWS] += 1
    stats[S_VISITED] += (r_hi - r_lo + 1) * (c_hi - c_lo + 1)
    words = st[:len(st) - len(st) % 8].view(np.uint64)
    ones = np.uint64(0x0101010101010101)
    highs = np.uint64(0x8080808080808080)
    k = 0
    for r in range(r_lo, r_hi + 1):
        base = r * W
        rr = r << 16
        c = c_lo
        while c <= c_hi:  # eligible (1) becomes consumed (2) and is listed
            j = base + c
            if j & 7 == 0 and c + 8 <= c_hi + 1:  # eight pixels at a time (one word of st): all eligible, or none
                v = words[j >> 3]
                if v == ones:
                    for b in range(8):
                        wp[k + b] = rr | (c + b)
                    k += 8
                    words[j >> 3] = ones + ones
                    c += 8
                    continue
                u = v ^ ones
                if ((u - ones) & ~u & highs) == 0:  # no byte is 1
                    c += 8
                    continue
            s = st[j]  # one at a time, branch-free
            e = s == 1
            st[j] = s + e
            wp[k] = rr | c
            k += e
            c += 1
    return k


@njit(cache=True, error_model="numpy")
def _scratch_nb(subset):
    """The small per-frame buffers: the RANSAC subset (x, y, z, index), a ≤ 256-point sample of a plane with its
    pixels, the coherence test's copies and noise, a plane's moments, the window positions the sample is
    drawn from, and the sample's local normals."""
    f = np.float32
    return (np.empty(subset, f), np.empty(subset, f), np.empty(subset, f), np.empty(subset, np.int64),
            np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, np.int64),
            np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, f),
            np.empty(256, np.int64), np.empty(512), np.empty(9), np.empty(1024, np.int64),
            np.empty(256, f), np.empty(256, f), np.empty(256, f))


@njit(cache=True, error_model="numpy")
def _coherent_plane_nb(win, na, nx, ny, nz, d, cls, prm, axes, drop, state, sc, flat, W, H, stats):
    """The coherence test (_split_bridge_nb) on ≤ 256 of the plane's inliers sampled before it takes them: a plane
    that is not one surface shrinks to one of them: a layer along the surfaces' own normal, or its strongest
    sub-plane, which is tested once more (it may span two box tops). Returns the plane to take (n, d), its class
    and whether that class is dropped."""
    wp, tx, ty = win
    bx, by, bz, bidx, qx, qy, qz, ux, uy, uz, uidx, noise = sc[4:16]
    pick, lx, ly, lz = sc[17], sc[18], sc[19], sc[20]
    cam = (prm.fx, prm.fy, prm.cx, prm.cy)
    dropped = drop[cls]
    for _ in range(2):
        if dropped:
            break
        nb = _window_sample_nb(wp, flat, tx, ty, na, nx, ny, nz, d, prm.eps, W, pick, bx, by, bz, bidx)
        split, sx_, sy_, sz_, sd_ = _split_bridge_nb(bx, by, bz, bidx, nb, flat, W, H, cam, nx, ny, nz, d, prm.eps,
                                                     prm.beta, prm.max_iter, state, qx, qy, qz, ux, uy, uz, uidx,
                                                     noise, lx, ly, lz, np.cos(np.radians(2.0)))
        if split == 0:
            break
        stats[S_SPLIT] += 1
        nx, ny, nz, d = sx_, sy_, sz_, sd_
        cls = _classify_nb(nx, ny, nz, d, axes[0], axes[1], axes[2], prm.sl_min, prm.sl_max, prm.cam_h,
                           prm.ground_max_h)
        dropped = drop[cls]
        if split == 1:  # a layer along the surfaces' own normal is one surface already
            break
    return nx, ny, nz, d, cls, dropped


@njit(cache=True, error_model="numpy")
def _take_plane_nb(win, na, nx, ny, nz, d, cls, prm, axes, drop, state, sc, flat, W, H, st, lbl, out, n_out, n_pl,
                   stats):
    """A plane's inliers out of the window (_partition_nb), after the coherence test when it is on. Returns
    (points kept in the window, inliers, n_out, the plane's class, whether that class is dropped)."""
    wp, tx, ty = win
    tail = max(prm.tail_eps, 1.0) * prm.eps
    dropped = drop[cls]
    if prm.coherence:
        nx, ny, nz, d, cls, dropped = _coherent_plane_nb(win, na, nx, ny, nz, d, cls, prm, axes, drop, state, sc,
                                                         flat, W, H, stats)
    keep, n_in, n_tail, n_out = _partition_nb(wp, flat, tx, ty, na, nx, ny, nz, d, prm.eps, tail, dropped, W,
                                              st, lbl, n_pl, out[0], out[1], out[2], n_out, sc[16])
    stats[S_OUTLIERS] += n_tail
    return keep, n_in, n_out, cls, dropped


@njit(cache=True, error_model="numpy", inline="always")
def _plane_of_moments(mom, n, C):
    """The least-squares plane of n points from their moment sums (Σx, Σy, Σz, Σxx, Σxy, Σxz, Σyy, Σyz, Σzz): the
    covariance's eigenvalues (ascending) and its smallest eigenvector, rectified to d ≥ 0. C: a 3×3 scratch array."""
    inv = 1.0 / n
    mx, my, mz = mom[0] * inv, mom[1] * inv, mom[2] * inv
    C[0, 0] = mom[3] * inv - mx * mx
    C[0, 1] = C[1, 0] = mom[4] * inv - mx * my
    C[0, 2] = C[2, 0] = mom[5] * inv - mx * mz
    C[1, 1] = mom[6] * inv - my * my
    C[1, 2] = C[2, 1] = mom[7] * inv - my * mz
    C[2, 2] = mom[8] * inv - mz * mz
    ev, v = np.linalg.eigh(C)
    nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
    d = -(nx * mx + ny * my + nz * mz)
    if d < 0:
        nx, ny, nz, d = -nx, -ny, -nz, -d
    return ev, nx, ny, nz, d


@njit(cache=True, error_model="numpy")
def _accept_plane_nb(prm, mom, n_in, start, n_out, out_pts, bx, by, bz, stats):
    """The plane refitted from all its inliers' moments, rectified; rejected (ok False) when its inliers are a
    strip no wider than the inlier band (min_width: its plane is not determined) or bend like a strip of a curved
    surface (bend_max: a person, a pillar; tested on ≤ 256 of them, evenly strided, when their residual spread is
    not far below ε). Returns (ok, nx, ny, nz, d)."""
    ev, fx_, fy_, fz_, fd = _plane_of_moments(mom, n_in, np.empty((3, 3)))
    if ev[1] < (prm.min_width * prm.eps) ** 2:
        stats[S_THIN] += 1
        return False, 0.0, 0.0, 0.0, 0.0
    if prm.bend_max > 0 and ev[0] > (0.2 * prm.eps) ** 2:  # residual RMS below ε/5: flat enough, no bend test
        step = max(1, n_in // 256)
        nb = 0
        for a in range(start, n_out, step):
            if nb == 256:
                break
            bx[nb], by[nb], bz[nb] = out_pts[a, 0], out_pts[a, 1], out_pts[a, 2]
            nb += 1
        if _curved_nb(bx, by, bz, nb, fx_, fy_, fz_, fd, prm.eps, 0.5, prm.bend_max):
            stats[S_BENT] += 1
            return False, 0.0, 0.0, 0.0, 0.0
    return True, fx_, fy_, fz_, fd


@njit(cache=True, error_model="numpy")
def _refit_planes_nb(pl_n, pl_d, pl_cnt, pl_mom, n_pl):
    """Each plane refitted from its inliers' moments (after growing added some), rectified: the least-squares plane
    (the covariance's smallest eigenvector). Compiled, as a 3×3 eigh per plane costs less here than numpy's call."""
    C = np.empty((3, 3))
    for k in range(n_pl):
        _, nx, ny, nz, d = _plane_of_moments(pl_mom[k], pl_cnt[k], C)
        pl_n[k, 0], pl_n[k, 1], pl_n[k, 2] = nx, ny, nz
        pl_d[k] = d


@njit(cache=True, error_model="numpy")
def _record_plane_nb(out, n_pl, nx, ny, nz, d, cls, n_in, mom):
    pl_n, pl_d, pl_cls, pl_cnt, pl_mom = out[3], out[4], out[5], out[6], out[7]
    pl_n[n_pl, 0], pl_n[n_pl, 1], pl_n[n_pl, 2] = nx, ny, nz
    pl_d[n_pl] = d
    pl_cls[n_pl] = cls
    pl_cnt[n_pl] = n_in
    for a in range(9):
        pl_mom[n_pl, a] = mom[a]


@njit(cache=True, error_model="numpy")
def _ransac_window_nb(win, flat, W, na, eps, beta, subset, max_iter, state, sx, sy, sz, sidx):
    """RANSAC (thesis Alg. 5) over the window's first na points: fspf_kernels._ransac_nb on the packed window
    (the points made where drawn: the same draws, the same planes)."""
    wp, tx, ty = win
    if na <= subset:
        ns = na
        for s in range(na):
            _, _, _, sx[s], sy[s], sz[s] = window_point(wp, s, flat, W, tx, ty)
            sidx[s] = s
    else:
        ns = subset
        for s in range(subset):
            q = _randint(state, na)
            _, _, _, sx[s], sy[s], sz[s] = window_point(wp, q, flat, W, tx, ty)
            sidx[s] = q
    best = -1
    bx = by = bz = bd = 0.0
    need = float(max_iter)
    it = 0
    while it < need and it < max_iter:
        it += 1
        _, _, _, ax, ay, az = window_point(wp, _randint(state, na), flat, W, tx, ty)
        _, _, _, bx_, by_, bz_ = window_point(wp, _randint(state, na), flat, W, tx, ty)
        _, _, _, cx, cy, cz = window_point(wp, _randint(state, na), flat, W, tx, ty)
        ok, nx, ny, nz, d = plane_through(np.float64(ax), np.float64(ay), np.float64(az), bx_, by_, bz_, cx, cy, cz)
        if not ok:
            continue
        cnt = _score_nb(sx, sy, sz, ns, nx, ny, nz, d, eps)
        if cnt > best:
            best = cnt
            bx, by, bz, bd = nx, ny, nz, d
            need = _ransac_need(cnt, ns, beta, need)
    return best >= 3, bx, by, bz, bd


@njit(cache=True, error_model="numpy")
def _window_planes_nb(win, k, prm, axes, drop, state, sc, flat, W, H, st, lbl, out, n_out, n_pl, stats):
    """The planes of one window of k points (thesis Alg. 3's inner part): RANSAC (Alg. 5) and a least-squares
    refit, the class (Alg. 6), the inliers taken, planes of ≤ nMin inliers, dropped classes, thin strips and
    bent strips set apart; then again on the window's rest, up to per_window planes (1 = the thesis).
    Returns (n_out, n_pl)."""
    sx, sy, sz, sidx = sc[0], sc[1], sc[2], sc[3]
    bx, by, bz, mom = sc[4], sc[5], sc[6], sc[16]
    na = k
    for pw in range(prm.per_window):
        # a further plane only where enough of the window is left (a residue of < extra_min of it is mostly the
        # edges and noise of the planes found)
        if na <= prm.n_min or (pw > 0 and na < prm.extra_min * k):
            break
        ok, nx, ny, nz, d = _ransac_window_nb(win, flat, W, na, prm.eps, prm.beta, prm.subset, prm.max_iter, state,
                                              sx, sy, sz, sidx)
        if not ok:
            break
        # least-squares refit on the subset's inliers; the final plane is refitted from all its inliers' moments
        cnt, nx, ny, nz, d = _inlier_fit_nb(sx, sy, sz, min(na, prm.subset), nx, ny, nz, d, prm.eps)
        if cnt < 3:
            break
        if d < 0:  # rectify: the normal faces the camera
            nx, ny, nz, d = -nx, -ny, -nz, -d
        cls = _classify_nb(nx, ny, nz, d, axes[0], axes[1], axes[2], prm.sl_min, prm.sl_max, prm.cam_h,
                           prm.ground_max_h)
        start = n_out
        na, n_in, n_out, cls, dropped = _take_plane_nb(win, na, nx, ny, nz, d, cls, prm, axes, drop, state, sc, flat,
                                                       W, H, st, lbl, out, n_out, n_pl, stats)
        if n_in <= prm.n_min:  # too few inliers (thesis: nMin): they are outliers
            n_out = _unmark_nb(st, W, out[0], start, n_out)
            stats[S_OUTLIERS] += n_in
            break
        if dropped:
            stats[S_DROPPED] += n_in
            continue
        ok, nx, ny, nz, d = _accept_plane_nb(prm, mom, n_in, start, n_out, out[1], bx, by, bz, stats)
        if not ok:
            n_out = _unmark_nb(st, W, out[0], start, n_out)
            stats[S_OUTLIERS] += n_in
            continue
        _record_plane_nb(out, n_pl, nx, ny, nz, d, cls, n_in, mom)
        n_pl += 1
    stats[S_OUTLIERS] += na
    return n_out, n_pl


@njit(cache=True, error_model="numpy")
def fspf_plus_kernel(depth, prm, axes, drop, state, bufs, out, stats):
    """FSPF+ (thesis Alg. 3) on one depth image. prm: Params; axes: (up, forward, left); drop: bool per class;
    bufs: (st, cand, window, stack, plane label) of ≥ H·W entries, reused from frame to frame; out: (pixels,
    points, plane, normals, offsets, classes, counts, moments). Returns (points, planes) written to out."""
    H, W = depth.shape
    flat = depth.ravel()
    st, cand, wp, lbl = bufs[0], bufs[1], bufs[2], bufs[4]  # st: 0 ineligible, 1 eligible, 2 consumed, 3 a kept
    # plane's point
    stats[:] = 0
    m = _depth_constraints_nb(flat, prm.min_d, prm.max_d, st, cand)
    stats[S_PIXELS], stats[S_INELIGIBLE] = H * W, H * W - m
    remaining = m
    stop = (1.0 - prm.frac) * m  # nRequired: stop when this few eligible pixels are left unexamined
    tx = np.empty(W, np.float32)  # x = z·(c − cx)/fx, y = z·(r − cy)/fy
    ty = np.empty(H, np.float32)
    for c in range(W):
        tx[c] = (c - prm.cx) / prm.fx
    for r in range(H):
        ty[r] = (r - prm.cy) / prm.fy
    win = (wp, tx, ty)
    sc = _scratch_nb(prm.subset)
    n_out = n_pl = 0
    while remaining > stop and m > 0:
        i0, m = _draw_p0_nb(state, cand, m, st)
        if i0 < 0:
            continue
        zbar = _draw_p1_p2_nb(state, flat, st, i0, W, H, prm.omega)
        if zbar < 0:  # an isolated pixel: consumed as an outlier
            st[i0] = 2
            remaining -= 1
            stats[S_OUTLIERS] += 1
            continue
        k = _gather_window_nb(flat, st, i0, zbar, prm, W, H, wp, stats)
        remaining -= k
        if k <= prm.n_min:
            stats[S_OUTLIERS] += k
            continue
        n_out, n_pl = _window_planes_nb(win, k, prm, axes, drop, state, sc, flat, W, H, st, lbl, out, n_out, n_pl,
                                        stats)
    if prm.grow and remaining > 0:  # our extension: the unexamined pixels next to a plane join it
        n_out, grown = _grow_nb(flat, W, H, tx, ty, prm.eps, st, lbl, wp, bufs[3], out[3], out[4], out[6], out[7],
                                out[0], out[1], out[2], n_out)
        remaining -= grown
        stats[S_GROWN] = grown
        if grown:  # the grown planes refitted from their moments
            _refit_planes_nb(out[3], out[4], out[6], out[7], n_pl)
    stats[S_INLIERS] = n_out
    stats[S_REMAINING] = remaining
    return n_out, n_pl
