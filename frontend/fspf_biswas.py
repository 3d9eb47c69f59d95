"""The FSPF kernel (Biswas & Veloso 2012; thesis Algorithm 1), the baseline FSPF+ is measured against."""

from __future__ import annotations


import numpy as np
from numba import njit

from kosmap.frontend.fspf_kernels import _classify_nb, _randint, _refit_nb, _uniform, plane_through


# ---- FSPF (Biswas & Veloso; thesis Alg. 1) -----------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def fspf_kernel(depth, fx, fy, cx, cy, min_d, max_d, n_max, k_max, l, eta, size, eps, alpha, up, fwd, left,
             sl_min, sl_max, cam_h, ground_max_h, drop, state, st, out_pix, out_pts, out_plane, pl_n, pl_d, pl_cls, pl_cnt,
             stats):
    H, W = depth.shape
    npx = H * W
    flat = depth.ravel()
    # st (a reused buffer of ≥ npx): 0 ineligible, 1 eligible, 2 examined (outlier), 3 plane point, 4 dropped
    n_elig = 0
    for i in range(npx):  # branch-free depthConstraints
        z = flat[i]
        ok = (z > min_d) & (z <= max_d)
        st[i] = ok
        n_elig += ok
    n2 = 0  # pixels in state 2, kept as they change (no pass over the image at the end)
    li = np.empty(l, np.int64)
    lx = np.empty(l, np.float64)
    ly = np.empty(l, np.float64)
    lz = np.empty(l, np.float64)
    act = np.empty(l, np.int32)
    need = int(np.ceil(alpha * l - 1e-9))
    max_bad = l - need
    half = eta // 2
    n_out = 0
    n_pl = 0
    n_drop = 0
    for _k in range(k_max):
        if n_out + n_drop >= n_max:
            break
        r0 = _randint(state, H)
        c0 = _randint(state, W)
        i0 = r0 * W + c0
        if st[i0] == 0:
            continue
        r1 = r0 + _randint(state, eta + 1) - half
        c1 = c0 + _randint(state, eta + 1) - half
        r2 = r0 + _randint(state, eta + 1) - half
        c2 = c0 + _randint(state, eta + 1) - half
        if r1 < 0 or r1 >= H or c1 < 0 or c1 >= W or r2 < 0 or r2 >= H or c2 < 0 or c2 >= W:
            continue
        i1 = r1 * W + c1
        i2 = r2 * W + c2
        if st[i1] == 0 or st[i2] == 0:
            continue
        z0, z1, z2 = np.float64(flat[i0]), np.float64(flat[i1]), np.float64(flat[i2])
        x0, y0 = (c0 - cx) * z0 / fx, (r0 - cy) * z0 / fy
        x1, y1 = (c1 - cx) * z1 / fx, (r1 - cy) * z1 / fy
        x2, y2 = (c2 - cx) * z2 / fx, (r2 - cy) * z2 / fy
        ok, nx, ny, nz, d = plane_through(x0, y0, z0, x1, y1, z1, x2, y2, z2)
        if not ok:
            continue
        zbar = (z0 + z1 + z2) / 3.0
        ww = fx * size / zbar
        wh = fy * size / zbar
        n_in = 0
        n_bad = 0
        for _s in range(l):
            r = r0 + int(np.floor((_uniform(state) - 0.5) * wh + 0.5))
            c = c0 + int(np.floor((_uniform(state) - 0.5) * ww + 0.5))
            if r >= 0 and r < H and c >= 0 and c < W:
                j = r * W + c
                if st[j] != 0:
                    z = np.float64(flat[j])
                    x, y = (c - cx) * z / fx, (r - cy) * z / fy
                    if abs(nx * x + ny * y + nz * z + d) < eps:
                        li[n_in] = j
                        lx[n_in] = x
                        ly[n_in] = y
                        lz[n_in] = z
                        n_in += 1
                        continue
                    if st[j] == 1:
                        st[j] = 2
                        n2 += 1
            n_bad += 1
            if n_bad > max_bad:  # α_in can no longer be reached
                break
        if n_bad > max_bad:
            for a in range(n_in):
                if st[li[a]] == 1:
                    st[li[a]] = 2
                    n2 += 1
            continue
        if n_in < 3:
            continue
        for a in range(n_in):
            act[a] = a
        nx, ny, nz, d = _refit_nb(lx, ly, lz, act, n_in)
        if d < 0:
            nx, ny, nz, d = -nx, -ny, -nz, -d
        cls = _classify_nb(nx, ny, nz, d, up, fwd, left, sl_min, sl_max, cam_h, ground_max_h)
        if drop[cls]:
            for a in range(n_in):
                j = li[a]
                if st[j] == 1 or st[j] == 2:
                    n2 -= st[j] == 2
                    st[j] = 4
                    n_drop += 1
            continue
        added = 0
        for a in range(n_in):
            j = li[a]
            if st[j] == 1 or st[j] == 2:
                n2 -= st[j] == 2
                st[j] = 3
                out_pix[n_out, 0] = j // W
                out_pix[n_out, 1] = j - (j // W) * W
                out_pts[n_out, 0] = lx[a]
                out_pts[n_out, 1] = ly[a]
                out_pts[n_out, 2] = lz[a]
                out_plane[n_out] = n_pl
                n_out += 1
                added += 1
        if added > 0:
            pl_n[n_pl, 0] = nx
            pl_n[n_pl, 1] = ny
            pl_n[n_pl, 2] = nz
            pl_d[n_pl] = d
            pl_cls[n_pl] = cls
            pl_cnt[n_pl] = added
            n_pl += 1
    n_outl = n2
    remaining = n_elig - n_out - n_drop - n2
    stats[0] = npx
    stats[1] = npx - n_elig
    stats[2] = n_out
    stats[3] = n_drop
    stats[4] = n_outl
    stats[5] = remaining
    return n_out, n_pl
