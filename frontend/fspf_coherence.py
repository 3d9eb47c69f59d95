"""FSPF+'s test of a plane's coherence (docs/planes.md, "Bridging planes"): the surfaces' own normal from the image's
3D differences, the sensor's noise from its inverse-depth second differences, and the plane shrunk to one surface
(its most populated layer along that normal, or its strongest sub-plane) when its inliers span parallel surfaces.
Compiled with numba; the RANSAC and the refit it calls are fspf_kernels.py's."""

from __future__ import annotations

import numpy as np
from numba import njit

from kosmap.frontend.fspf_kernels import _inlier_fit_nb, _ransac_nb


@njit(cache=True, error_model="numpy", inline="always")
def _inv_d2(flat, j, step):
    """|1/z(j−step) − 2/z(j) + 1/z(j+step)|·z(j)²: 1/z is linear in the pixel coordinates on a plane, so this
    second difference is the sensor's depth noise (√6·σ), whatever the plane; −1 where a neighbour is missing."""
    z0, za, zb = flat[j], flat[j - step], flat[j + step]
    if not (za > 0 and zb > 0 and z0 > 0):
        return -1.0
    return abs(1.0 / za - 2.0 / z0 + 1.0 / zb) * z0 * z0


@njit(cache=True, error_model="numpy")
def _inliers_of_nb(sx, sy, sz, pix, ns, nx, ny, nz, d, eps, tx, ty, tz, tpix):
    """The sample's points within ε of (n, d), copied to tx, ty, tz (pixels to tpix). Returns (their count, their
    residual sum of squares). Branch-free: a sample's inliers and outliers alternate unpredictably."""
    m = 0
    ss = 0.0
    for s in range(ns):
        r = nx * sx[s] + ny * sy[s] + nz * sz[s] + d
        tx[m], ty[m], tz[m], tpix[m] = sx[s], sy[s], sz[s], pix[s]
        inlier = abs(r) < eps
        ss += r * r if inlier else 0.0
        m += inlier
    return m, ss


@njit(cache=True, error_model="numpy")
def _spread_beyond_noise_nb(pix, m, flat, W, H, noise, ss):
    """Whether m points with residual sum of squares ss spread about their plane beyond twice the sensor's depth
    noise σ in their pixels pix[:m] (ss ≥ m·(2σ)²). σ: the upper quartile of the second differences of inverse
    depth along the row and the column (_inv_d2), / (1.15·√6); robust: the upper quartile of |N(0, 6σ²)| is
    1.15·√6·σ, step edges among them do not count, and a sensor that quantises depth (disparity steps: many zero
    differences) still shows its step. False when fewer than 12 differences.
    The quartile is not selected but compared: with t the quartile that makes ss = m·(2σ)², counting the
    differences ≤ t tells on which side of t the two order statistics around the quartile lie; only when t falls
    between them is the quartile interpolated, from the largest difference ≤ t and the smallest above it (a pass
    instead of a quickselect, the same answer)."""
    nn = 0
    for s in range(m):
        q = pix[s]
        rr = q // W
        cc = q - rr * W
        if 0 < cc < W - 1:
            v = _inv_d2(flat, q, 1)
            noise[nn] = v
            nn += v >= 0
        if 0 < rr < H - 1:
            v = _inv_d2(flat, q, W)
            noise[nn] = v
            nn += v >= 0
    if nn < 12:
        return False
    k = 1.15 * np.sqrt(6.0)
    t = k * np.sqrt(ss / m) / 2.0
    # the upper quartile as np.percentile has it: linear between the order statistics lo and lo + 1 (< nn)
    pos = 0.75 * (nn - 1)
    lo = int(pos)
    below, a, b = 0, -np.inf, np.inf  # count ≤ t, the largest ≤ t, the smallest above t (branch-free)
    for i in range(nn):
        v = noise[i]
        le = v <= t
        below += le
        a = max(a, v if le else -np.inf)
        b = min(b, np.inf if le else v)
    if below >= lo + 2:  # both order statistics ≤ t: the quartile too
        return True
    if below <= lo:  # the lower one above t
        return False
    sigma = (a + (pos - lo) * (b - a)) / k
    return not ss < m * (2.0 * sigma) ** 2


@njit(cache=True, error_model="numpy")
def _surface_normal_nb(pix, m, flat, W, H, fx, fy, cx, cy, nx, ny, nz, eps, lx, ly, lz):
    """The normal of the surfaces under the pixels pix[:m], from the image (after NCC-RANSAC, Qian & Ye 2014): at
    each pixel the cross product of the 3D differences across ±k pixels along its row and its column (k: a
    5 cm baseline at its depth; skipped across a depth step of ε), averaged robustly (mean shift from (n), within
    30°, 15° and 10°). A plane bridging parallel surfaces is tilted against theirs; one surface's local normals
    scatter about its own. Returns (count, g, the standard error of the mean's direction in radians); count 0
    when fewer than 24 local normals."""
    c_ok = 0
    for s in range(m):
        q = pix[s]
        r = q // W
        c = q - r * W
        z = np.float64(flat[q])
        k = max(2, int(0.025 * fx / z + 0.5))
        if r < k or r >= H - k or c < k or c >= W - k:
            continue
        zl, zr, zu, zd = np.float64(flat[q - k]), np.float64(flat[q + k]), np.float64(flat[q - k * W]), \
            np.float64(flat[q + k * W])
        if not (zl > 0 and zr > 0 and zu > 0 and zd > 0) or abs(zl + zr - 2 * z) > eps or abs(zu + zd - 2 * z) > eps:
            continue
        yr = (r - cy) / fy
        ux, uy, uz = zr * (c + k - cx) / fx - zl * (c - k - cx) / fx, (zr - zl) * yr, zr - zl
        xc = (c - cx) / fx
        vx, vy, vz = (zd - zu) * xc, zd * (r + k - cy) / fy - zu * (r - k - cy) / fy, zd - zu
        ax, ay, az = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        nn = np.sqrt(ax * ax + ay * ay + az * az)
        if nn <= 0:
            continue
        if ax * nx + ay * ny + az * nz < 0:
            nn = -nn
        lx[c_ok], ly[c_ok], lz[c_ok] = ax / nn, ay / nn, az / nn
        c_ok += 1
    if c_ok < 24:
        return 0, nx, ny, nz, 0.0
    gx, gy, gz = nx, ny, nz
    cnt = 0
    spread = 0.0
    for cos_w in (np.cos(np.radians(30.0)), np.cos(np.radians(15.0)), np.cos(np.radians(10.0))):
        sx = sy = sz = 0.0
        cnt = 0
        spread = 0.0
        for i in range(c_ok):
            dot = lx[i] * gx + ly[i] * gy + lz[i] * gz
            if dot > cos_w:
                sx += lx[i]
                sy += ly[i]
                sz += lz[i]
                spread += 1.0 - dot * dot
                cnt += 1
        if cnt < 24:
            return 0, nx, ny, nz, 0.0
        nrm = np.sqrt(sx * sx + sy * sy + sz * sz)
        gx, gy, gz = sx / nrm, sy / nrm, sz / nrm
    return cnt, gx, gy, gz, np.sqrt(spread / cnt) / np.sqrt(cnt)


@njit(cache=True, error_model="numpy")
def _strongest_layer_nb(tx, ty, tz, m, gx, gy, gz, band, res):
    """The most populated layer of the points along the direction g: the offset band of width 2·band holding most
    of them (a sliding window over their sorted offsets). Returns (count, −its mean offset: the plane's d)."""
    for k in range(m):
        res[k] = gx * tx[k] + gy * ty[k] + gz * tz[k]
    r = np.sort(res[:m])
    best, j0, j = 0, 0, 0
    for i in range(m):
        while r[i] - r[j] > 2.0 * band:
            j += 1
        if i - j + 1 > best:
            best, j0 = i - j + 1, j
    return best, -np.mean(r[j0:j0 + best])


@njit(cache=True, error_model="numpy")
def _split_bridge_nb(sx, sy, sz, pix, ns, flat, W, H, cam, nx, ny, nz, d, eps, beta, max_iter, state,
                     tx, ty, tz, ux, uy, uz, uidx, noise, lx, ly, lz, cos_split):
    """Coherence of a plane's inliers (after NCC-RANSAC, Qian & Ye 2014): one surface, or a plane that bridges
    parallel surfaces (a table and the box tops on it) by cutting a strip of each?

    Tested on a sample of the plane's inliers (sx…, their pixels pix), when their residual RMS exceeds ε/5:
    1. the surfaces' own normal from the image (_surface_normal_nb): tilted against the plane's by more than
       max(3°, 3 standard errors), the plane is a bridge; it shrinks to the most populated layer of its inliers
       along that normal (±ε/3, least-squares refit): one of the surfaces.
    2. else the spread: one surface's inliers scatter about their plane by the sensor's noise σ, which the image
       itself gives in the same pixels (_spread_beyond_noise_nb); beyond 2σ, the strongest sub-plane at ε/3 (RANSAC on the
       same inliers, least-squares refit), when it is another plane (tilted by > acos(cos_split) or ε/3 off at the
       inliers' centre), is one of the surfaces.
    The window's next plane finds the others. cam: (fx, fy, cx, cy). Returns (how: 0 one surface, 1 a layer along
    the surfaces' normal, 2 the strongest sub-plane; n, d).
    """
    m, ss = _inliers_of_nb(sx, sy, sz, pix, ns, nx, ny, nz, d, eps, tx, ty, tz, uidx)
    if m < 24 or ss < m * (0.2 * eps) ** 2:  # residual RMS below ε/5: one surface (the bend test's gate)
        return 0, nx, ny, nz, d
    cnt, gx, gy, gz, se = _surface_normal_nb(uidx, m, flat, W, H, cam[0], cam[1], cam[2], cam[3], nx, ny, nz, eps,
                                            lx, ly, lz)
    if cnt > 0 and gx * nx + gy * ny + gz * nz < np.cos(max(np.radians(3.0), 3.0 * se)):
        n_l, gd = _strongest_layer_nb(tx, ty, tz, m, gx, gy, gz, eps / 3.0, noise)
        if n_l >= 12:
            c2, ax, ay, az, ad = _inlier_fit_nb(tx, ty, tz, m, gx, gy, gz, gd, eps / 3.0)
            if c2 >= 12:
                if ad < 0:
                    ax, ay, az, ad = -ax, -ay, -az, -ad
                return 1, ax, ay, az, ad
    if not _spread_beyond_noise_nb(uidx, m, flat, W, H, noise, ss):
        return 0, nx, ny, nz, d
    # hypotheses scored on the whole sample (≤ 256 points): a box top may be a small share of a bridging plane's
    # inliers (docs/planes.md)
    ok, ax, ay, az, ad = _ransac_nb(tx, ty, tz, m, eps / 3.0, beta, m, max_iter, state, ux, uy, uz, uidx)
    if not ok:
        return 0, nx, ny, nz, d
    cnt, ax, ay, az, ad = _inlier_fit_nb(tx, ty, tz, m, ax, ay, az, ad, eps / 3.0)
    if cnt < 12:
        return 0, nx, ny, nz, d
    if ax * nx + ay * ny + az * nz < 0:
        ax, ay, az, ad = -ax, -ay, -az, -ad
    # the same plane within its noise (a noisy surface, not two): no split. Another plane tilts by degrees
    # (a strip of each surface) or, parallel, sits ε/3 or more away at the inliers' centre.
    cx, cy, cz = np.mean(tx[:m]), np.mean(ty[:m]), np.mean(tz[:m])
    if ax * nx + ay * ny + az * nz > cos_split and abs(ax * cx + ay * cy + az * cz + ad - (nx * cx + ny * cy + nz * cz + d)) < eps / 3.0:
        return 0, nx, ny, nz, d
    if ad < 0:
        ax, ay, az, ad = -ax, -ay, -az, -ad
    return 2, ax, ay, az, ad
