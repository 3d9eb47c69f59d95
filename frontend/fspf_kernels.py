"""The compiled pieces FSPF and FSPF+ share (frontend/fspf.py): reproducible random numbers, plane classes
(thesis Alg. 6), RANSAC (Alg. 5) and least-squares refits, and the tests and steps of kosmap's extensions
(bends, partitioning a window, region growing; the bridging planes' test is fspf_coherence.py's)."""

from __future__ import annotations


import numpy as np
from numba import njit


# ---- random numbers: xorshift64 seeded by splitmix64 (fast inside numba, reproducible) --------------------------------

_M64 = (1 << 64) - 1
_NO_MOMENTS = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def _moments_plus(s, x, y, z):  # pragma: no cover - compiled
    """The nine moment sums (Σx, Σy, Σz, Σxx, Σxy, Σxz, Σyy, Σyz, Σzz) with the point (x, y, z) added: a tuple,
    held in registers by the loops that sum into it."""
    return (s[0] + x, s[1] + y, s[2] + z, s[3] + x * x, s[4] + x * y, s[5] + x * z, s[6] + y * y, s[7] + y * z,
            s[8] + z * z)


def rng_state(seed: int) -> np.ndarray:
    z = (int(seed) + 0x9E3779B97F4A7C15) & _M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    z ^= z >> 31
    return np.array([z or 0x2545F4914F6CDD1D], dtype=np.uint64)


@njit(cache=True, error_model="numpy", inline="always")
def _next(state):
    x = state[0]
    x ^= x << np.uint64(13)
    x ^= x >> np.uint64(7)
    x ^= x << np.uint64(17)
    state[0] = x
    return x


@njit(cache=True, error_model="numpy", inline="always")
def _randint(state, n):
    """Uniform integer in [0, n)."""
    return np.int64((_next(state) >> np.uint64(11)) % np.uint64(n))


@njit(cache=True, error_model="numpy", inline="always")
def _uniform(state):
    """Uniform float in [0, 1)."""
    return np.float64(_next(state) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


# ---- shared numba pieces -------------------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy", inline="always")
def plane_through(ax, ay, az, bx, by, bz, cx, cy, cz):
    """(ok, nx, ny, nz, d): the unit-normal plane through three points (a float64); ok False when they are collinear."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
    if nn < 1e-12:
        return False, 0.0, 0.0, 0.0, 0.0
    nx /= nn
    ny /= nn
    nz /= nn
    return True, nx, ny, nz, -(nx * ax + ny * ay + nz * az)


@njit(cache=True, error_model="numpy")
def _classify_nb(nx, ny, nz, d, up, fwd, left, sl_min, sl_max, cam_h, ground_max_h):
    """planes.classify for one normal (thesis Alg. 6, plus slanted and raised); keep the two identical."""
    cu = nx * up[0] + ny * up[1] + nz * up[2]
    a = abs(cu)
    if a > 1.0:
        a = 1.0
    tilt = np.degrees(np.arccos(a))
    if tilt < sl_min:
        if cu <= 0:
            return 1
        if cam_h == cam_h and cam_h - d * cu > ground_max_h:  # cam_h is NaN without a mount
            return 6
        return 0
    if tilt > sl_max:
        hx, hy, hz = nx - cu * up[0], ny - cu * up[1], nz - cu * up[2]
        hf = hx * fwd[0] + hy * fwd[1] + hz * fwd[2]
        hl = hx * left[0] + hy * left[1] + hz * left[2]
        if -hf >= abs(hl):
            return 4
        return 2 if hl < 0 else 3
    return 5


@njit(cache=True, error_model="numpy")
def classify_many(normals, offsets, up, fwd, left, sl_min, sl_max, cam_h, ground_max_h):
    out = np.empty(len(offsets), np.int8)
    for k in range(len(offsets)):
        out[k] = _classify_nb(normals[k, 0], normals[k, 1], normals[k, 2], offsets[k], up, fwd, left, sl_min, sl_max,
                              cam_h, ground_max_h)
    return out


@njit(cache=True, error_model="numpy")
def _refit_nb(wx, wy, wz, act, n):
    """Least-squares plane through the points act[:n]: smallest eigenvector of their covariance."""
    mx = my = mz = 0.0
    for a in range(n):
        q = act[a]
        mx += wx[q]
        my += wy[q]
        mz += wz[q]
    mx /= n
    my /= n
    mz /= n
    C = np.zeros((3, 3))
    for a in range(n):
        q = act[a]
        dx, dy, dz = wx[q] - mx, wy[q] - my, wz[q] - mz
        C[0, 0] += dx * dx
        C[0, 1] += dx * dy
        C[0, 2] += dx * dz
        C[1, 1] += dy * dy
        C[1, 2] += dy * dz
        C[2, 2] += dz * dz
    C[1, 0] = C[0, 1]
    C[2, 0] = C[0, 2]
    C[2, 1] = C[1, 2]
    _, v = np.linalg.eigh(C)
    nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
    return nx, ny, nz, -(nx * mx + ny * my + nz * mz)


@njit(cache=True, error_model="numpy")
def _inlier_fit_nb(wx, wy, wz, na, nx, ny, nz, d, eps):
    """Least-squares refit on the inliers of (n, d) among the first na points, in one pass over the moments.

    Moments are taken about the first point so that Σppᵀ/n − c·cᵀ stays accurate. Returns (count, n, d).
    """
    ox, oy, oz = np.float64(wx[0]), np.float64(wy[0]), np.float64(wz[0])
    cnt = 0
    s = _NO_MOMENTS
    for a in range(na):
        x, y, z = np.float64(wx[a]), np.float64(wy[a]), np.float64(wz[a])
        if abs(nx * x + ny * y + nz * z + d) < eps:
            cnt += 1
            s = _moments_plus(s, x - ox, y - oy, z - oz)
    sx, sy, sz, sxx, sxy, sxz, syy, syz, szz = s
    if cnt < 3:
        return cnt, nx, ny, nz, d
    mx, my, mz = sx / cnt, sy / cnt, sz / cnt
    C = np.empty((3, 3))
    C[0, 0] = sxx / cnt - mx * mx
    C[0, 1] = C[1, 0] = sxy / cnt - mx * my
    C[0, 2] = C[2, 0] = sxz / cnt - mx * mz
    C[1, 1] = syy / cnt - my * my
    C[1, 2] = C[2, 1] = syz / cnt - my * mz
    C[2, 2] = szz / cnt - mz * mz
    _, v = np.linalg.eigh(C)
    rx, ry, rz = v[0, 0], v[1, 0], v[2, 0]
    return cnt, rx, ry, rz, -(rx * (mx + ox) + ry * (my + oy) + rz * (mz + oz))


@njit(cache=True, error_model="numpy", inline="always")
def _score_nb(sx, sy, sz, ns, nx, ny, nz, d, eps):
    """How many of the points (sx, sy, sz)[:ns] lie within eps of the plane (n, d)."""
    cnt = 0
    fx32, fy32, fz32, fd32, fe32 = np.float32(nx), np.float32(ny), np.float32(nz), np.float32(d), np.float32(eps)
    for s in range(ns):  # float32 so the scoring loop vectorises twice as wide
        if abs(fx32 * sx[s] + fy32 * sy[s] + fz32 * sz[s] + fd32) < fe32:
            cnt += 1
    return cnt


@njit(cache=True, error_model="numpy", inline="always")
def _ransac_need(cnt, ns, beta, need):
    """The adaptive stop of thesis Alg. 5 after a best count cnt of ns: k = (1 + β·√(1 − w³)) / w³."""
    w3 = (cnt / ns) ** 3
    if w3 > 0:
        return (1.0 + beta * np.sqrt(max(0.0, 1.0 - w3))) / w3
    return need


@njit(cache=True, error_model="numpy")
def _ransac_nb(wx, wy, wz, na, eps, beta, subset, max_iter, state, sx, sy, sz, sidx):
    """RANSAC (thesis Alg. 5) over the first na points: 3-point hypotheses scored on ≤ subset random
    points (copied to sx, sy, sz; their indices to sidx), adaptive stop k = (1 + β·√(1 − w³)) / w³."""
    if na <= subset:
        ns = na
        for s in range(na):
            sx[s], sy[s], sz[s] = wx[s], wy[s], wz[s]
            sidx[s] = s
    else:
        ns = subset
        for s in range(subset):
            q = _randint(state, na)
            sx[s], sy[s], sz[s] = wx[q], wy[q], wz[q]
            sidx[s] = q
    best = -1
    bx = by = bz = bd = 0.0
    need = float(max_iter)
    it = 0
    while it < need and it < max_iter:
        it += 1
        a = _randint(state, na)
        b = _randint(state, na)
        c = _randint(state, na)
        ok, nx, ny, nz, d = plane_through(np.float64(wx[a]), np.float64(wy[a]), np.float64(wz[a]),
                                          wx[b], wy[b], wz[b], wx[c], wy[c], wz[c])
        if not ok:
            continue
        cnt = _score_nb(sx, sy, sz, ns, nx, ny, nz, d, eps)
        if cnt > best:
            best = cnt
            bx, by, bz, bd = nx, ny, nz, d
            need = _ransac_need(cnt, ns, beta, need)
    return best >= 3, bx, by, bz, bd


@njit(cache=True, error_model="numpy")
def _solve_nb(A, b):
    """x with A·x = b for a small square A: LU with partial pivoting (LAPACK's dgetf2 + dgetrs, written out;
    np.linalg.solve's shape checks cost ~5 s of numba compiling on a fresh machine). A and b are overwritten."""
    n = len(b)
    piv = np.empty(n, np.int64)
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(A[i, k]) > abs(A[p, k]):
                p = i
        piv[k] = p
        if p != k:
            for j in range(n):
                A[k, j], A[p, j] = A[p, j], A[k, j]
        r = 1.0 / A[k, k]
        for i in range(k + 1, n):
            A[i, k] *= r
        for i in range(k + 1, n):
            for j in range(k + 1, n):
                A[i, j] -= A[i, k] * A[k, j]
    for k in range(n):
        p = piv[k]
        if p != k:
            b[k], b[p] = b[p], b[k]
    for i in range(n):
        for j in range(i):
            b[i] -= A[i, j] * b[j]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            b[i] -= A[i, j] * b[j]
        b[i] /= A[i, i]
    return b


@njit(cache=True, error_model="numpy")
def _curved_nb(sx, sy, sz, ns, nx, ny, nz, d, eps, r2_max, bend_max):
    """True when the plane's inliers among the RANSAC subset bend: a quadratic in the in-plane coordinates
    explains more than r2_max of their residual variance and rises by more than bend_max·ε over them.

    Rejects the flat-looking strips RANSAC cuts from curved surfaces (a person, a bin, a pillar): within ε
    a cylinder of radius r gives a strip of width ~2·√(2rε); noise on a true plane has no such structure.
    """
    # an orthonormal basis (e1, e2) of the plane
    if abs(nx) < 0.9:
        ax, ay, az = 1.0, 0.0, 0.0
    else:
        ax, ay, az = 0.0, 1.0, 0.0
    e1x, e1y, e1z = ay * nz - az * ny, az * nx - ax * nz, ax * ny - ay * nx
    e1n = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / e1n, e1y / e1n, e1z / e1n
    e2x, e2y, e2z = ny * e1z - nz * e1y, nz * e1x - nx * e1z, nx * e1y - ny * e1x
    A = np.zeros((6, 6))
    b = np.zeros(6)
    row = np.empty(6)
    rs = np.empty(ns)
    us = np.empty(ns)
    vs = np.empty(ns)
    m = 0
    for s in range(ns):
        x, y, z = np.float64(sx[s]), np.float64(sy[s]), np.float64(sz[s])
        r = nx * x + ny * y + nz * z + d
        if abs(r) < eps:
            rs[m] = r
            us[m] = e1x * x + e1y * y + e1z * z
            vs[m] = e2x * x + e2y * y + e2z * z
            m += 1
    if m < 24:
        return False
    uc = np.mean(us[:m])
    vc = np.mean(vs[:m])
    scale = 0.0
    for k in range(m):
        us[k] -= uc
        vs[k] -= vc
        scale = max(scale, abs(us[k]), abs(vs[k]))
    if scale <= 0:
        return False
    for k in range(m):
        u, v = us[k] / scale, vs[k] / scale
        row[0], row[1], row[2], row[3], row[4], row[5] = 1.0, u, v, u * u, v * v, u * v
        for i in range(6):
            b[i] += row[i] * rs[k]
            for j in range(i, 6):
                A[i, j] += row[i] * row[j]
    for i in range(6):
        A[i, i] += 1e-9
        for j in range(i):
            A[i, j] = A[j, i]
    coef = _solve_nb(A, b)
    rm = np.mean(rs[:m])
    tot = 0.0
    res = 0.0
    qmin = 1e30
    qmax = -1e30
    for k in range(m):
        u, v = us[k] / scale, vs[k] / scale
        q = coef[0] + coef[1] * u + coef[2] * v + coef[3] * u * u + coef[4] * v * v + coef[5] * u * v
        # the bend: the quadratic part only (the linear part is a tilt of the plane)
        qb = coef[3] * u * u + coef[4] * v * v + coef[5] * u * v
        qmin = min(qmin, qb)
        qmax = max(qmax, qb)
        tot += (rs[k] - rm) ** 2
        res += (rs[k] - q) ** 2
    if tot <= 0:
        return False
    return 1.0 - res / tot > r2_max and qmax - qmin > bend_max * eps


@njit(cache=True, error_model="numpy", inline="always")
def window_point(wp, a, flat, W, tx, ty):
    """Point a of a window held as packed pixels (row << 16 | column, thesis Alg. 3's window in image order):
    (row, column, flat index, x, y, z), x = z·(c − cx)/fx and y = z·(r − cy)/fy from the per-column and per-row
    factors tx, ty. The window keeps one int32 per point instead of five arrays: gathering a window and taking a
    plane's inliers out of it cost stores, not arithmetic."""
    q = wp[a]
    r = q >> 16
    c = q & 0xFFFF
    j = r * W + c
    z = flat[j]
    return r, c, j, z * tx[c], z * ty[r], z


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _partition_nb(wp, flat, tx, ty, na, nx, ny, nz, d, eps, tail, dropped, W, st, lbl, n_pl, out_pix, out_pts,
                  out_plane, n_out, mom):
    """One pass over the window's na points (packed pixels, window_point): the plane's inliers (|n·p + d| < ε) go
    out as plane n_pl (unless its class is dropped; their moments Σp, Σppᵀ into mom), its noise tail (ε … tail)
    is left out, the rest is compacted to the front. Returns (points kept, inliers, tail, n_out).
    The moments are summed in locals and stored once: summed into mom, each sum would go through memory every
    point (the compiler cannot tell mom from the output arrays), a chain of store-to-load latencies."""
    keep = 0
    n_in = 0
    n_tail = 0
    s = _NO_MOMENTS
    # the residual in float32, as RANSAC scores (the points are float32; a float64 residual cost a fifth of the pass)
    fx, fy, fz, fd = np.float32(nx), np.float32(ny), np.float32(nz), np.float32(d)
    eps, tail = np.float32(eps), np.float32(tail)
    for a in range(na):
        r, c, j, x32, y32, z32 = window_point(wp, a, flat, W, tx, ty)
        e = abs(fx * x32 + fy * y32 + fz * z32 + fd)
        if e >= eps and e < tail:  # the plane's noise tail: an outlier, but no seed for another plane
            n_tail += 1
            continue
        if e < eps:
            n_in += 1
            if not dropped:
                st[j] = 3  # a kept plane's point (back to 2 if the plane is rejected), for grow
                lbl[j] = n_pl
                out_pix[n_out, 0] = r
                out_pix[n_out, 1] = c
                out_pts[n_out, 0] = x32
                out_pts[n_out, 1] = y32
                out_pts[n_out, 2] = z32
                out_plane[n_out] = n_pl
                n_out += 1
                s = _moments_plus(s, np.float64(x32), np.float64(y32), np.float64(z32))
        else:
            wp[keep] = wp[a]
            keep += 1
    mom[0], mom[1], mom[2], mom[3], mom[4], mom[5], mom[6], mom[7], mom[8] = s
    return keep, n_in, n_tail, n_out


@njit(cache=True, error_model="numpy")
def _window_sample_nb(wp, flat, tx, ty, na, nx, ny, nz, d, eps, W, pick, bx, by, bz, bidx):
    """≤ 256 of the plane's inliers among the window's na points (|n·p + d| < ε), with their flat pixel indices,
    before it takes them: ≤ 1024 points tested, evenly strided over the window (its points are in image order),
    and ≤ 256 of their inliers kept, evenly spread. Testing before the take spares a rejected plane's second
    pass over the window. Returns their count."""
    step = max(1, na // 1024)
    c = 0
    for a in range(0, na, step):  # branch-free: a strided sample's inliers and outliers alternate unpredictably
        if c == len(pick):
            break
        _, _, _, x, y, z = window_point(wp, a, flat, W, tx, ty)
        pick[c] = a
        c += abs(nx * x + ny * y + nz * z + d) < eps
    nb = min(c, 256)
    q, rem = 0, 0  # q = ⌊k·c/nb⌋, stepped without a division per k
    for k in range(nb):
        _, _, j, x, y, z = window_point(wp, pick[q], flat, W, tx, ty)
        bx[k], by[k], bz[k] = x, y, z
        bidx[k] = j
        q += c // nb
        rem += c % nb
        if rem >= nb:
            q += 1
            rem -= nb
    return nb


@njit(cache=True, error_model="numpy")
def _unmark_nb(st, W, out_pix, start, n_out):
    """A rejected plane's points (out_pix[start:n_out]) are consumed outliers again, not plane points; returns start."""
    for a in range(start, n_out):
        st[out_pix[a, 0] * W + out_pix[a, 1]] = 2
    return start


@njit(cache=True, error_model="numpy", inline="always")
def _grow_take_nb(r, c, flat, W, tx, ty, nx, ny, nz, d, eps, k, st, lbl, out_pix, out_pts, out_plane, n_out):
    """Pixel (r, c) joins plane k when within ε of it (appended to the output): (joined, x, y, z)."""
    j = r * W + c
    z = np.float64(flat[j])
    x, y = z * tx[c], z * ty[r]
    if abs(nx * x + ny * y + nz * z + d) >= eps:
        return False, x, y, z
    st[j] = 3
    lbl[j] = k
    out_pix[n_out, 0], out_pix[n_out, 1] = r, c
    out_pts[n_out, 0], out_pts[n_out, 1], out_pts[n_out, 2] = x, y, z
    out_plane[n_out] = k
    return True, x, y, z


@njit(cache=True, error_model="numpy")
def _grow_nb(flat, W, H, tx, ty, eps, st, lbl, stack_r, stack_c, pl_n, pl_d, pl_cnt, pl_mom, out_pix, out_pts,
             out_plane, n_out):
    """Attach the eligible pixels never examined (the thesis stops at nRequired) to the plane of a 4-neighbour
    when within ε of it, flood-filling from there: region growing on the organised image, one test per pixel
    and neighbour. st: 1 unexamined, 3 a kept plane's point (its plane in lbl). The flood keeps rows and columns
    on two stacks (stack_r, stack_c: scratch of ≥ H·W), sparing an integer division per pixel. Returns (n_out,
    pixels grown). A flood's moments are summed in locals (see _partition_nb) and added to its plane's at its end."""
    n0 = n_out
    npx = H * W
    words = st[:npx - npx % 8].view(np.uint64)
    ones = np.uint64(0x0101010101010101)
    highs = np.uint64(0x8080808080808080)
    i = -1
    while i + 1 < npx:  # in image order: a sequential pass beats the (unordered) candidate list
        i += 1
        if i % 8 == 0 and i + 8 <= npx:
            # eight pixels at a time: skip a word none of whose bytes is 1 (the zero-byte test on st XOR 0x01…01)
            v = words[i // 8] ^ ones
            if ((v - ones) & ~v & highs) == 0:
                i += 7
                continue
        if st[i] != 1:
            continue
        r = i // W
        c = i - r * W
        k = -1
        if c > 0 and st[i - 1] == 3:
            k = lbl[i - 1]
        elif c < W - 1 and st[i + 1] == 3:
            k = lbl[i + 1]
        elif r > 0 and st[i - W] == 3:
            k = lbl[i - W]
        elif r < H - 1 and st[i + W] == 3:
            k = lbl[i + W]
        if k < 0:
            continue
        nx, ny, nz, d = pl_n[k, 0], pl_n[k, 1], pl_n[k, 2], pl_d[k]
        start = n_out
        took, x, y, z = _grow_take_nb(r, c, flat, W, tx, ty, nx, ny, nz, d, eps, k, st, lbl, out_pix, out_pts,
                                      out_plane, n_out)
        if not took:
            continue
        n_out += 1
        s = _moments_plus(_NO_MOMENTS, x, y, z)
        stack_r[0], stack_c[0] = r, c
        top = 1
        while top > 0:  # depth-first flood of plane k through unexamined pixels within ε of it
            top -= 1
            rj, cj = stack_r[top], stack_c[top]
            for t in range(4):
                rq, cq = rj, cj
                if t == 0:
                    cq -= 1
                elif t == 1:
                    cq += 1
                elif t == 2:
                    rq -= 1
                else:
                    rq += 1
                if rq < 0 or rq >= H or cq < 0 or cq >= W or st[rq * W + cq] != 1:
                    continue
                took, x, y, z = _grow_take_nb(rq, cq, flat, W, tx, ty, nx, ny, nz, d, eps, k, st, lbl, out_pix,
                                              out_pts, out_plane, n_out)
                if took:
                    n_out += 1
                    s = _moments_plus(s, x, y, z)
                    stack_r[top], stack_c[top] = rq, cq
                    top += 1
        pl_cnt[k] += n_out - start
        for j in range(9):
            pl_mom[k, j] += s[j]
    return n_out, n_out - n0
