"""FSPF (Biswas & Veloso) and FSPF+ (thesis Alg. 1, 3–6): sampled plane filtering of depth images.

Both take a depth image in metres, the pinhole camera and an explicit seed, and return `Planes`
(frontend/planes.py). The inner loops run compiled with numba (docs/dependencies.md measured numpy-only FSPF+ at
18–20 ms per 512×424 frame against ~3 ms compiled); `backend="numpy"` keeps a vectorised numpy path of the
same algorithms for the benchmark's honesty (same steps and tests, not the same random draws: its RANSAC
scores hypotheses in batches and refits on all inliers).

FSPF+ (thesis Alg. 3): p0 a random eligible, unconsumed pixel; p1, p2 eligible within Ω of it; the search
window W = fx·Δ/z̄, H = fy·Δ/z̄ around p0 (the projection of the world size Δ at their mean depth z̄;
docs/design.md), clipped at the border; its eligible pixels become 3D points and are consumed; RANSAC (ε, β;
Alg. 5) finds the plane, refitted by least squares; the normal is rectified to face the camera and
classified (Alg. 6); planes of dropped classes and planes with ≤ nMin inliers are discarded; the loop stops
when fewer than (1 − analysed fraction) of the eligible pixels are unconsumed. RANSAC scores its hypotheses
on a random subset of the window (docs/dependencies.md), refits the winner on the subset's inliers, and the final plane
is the least-squares fit of all its inliers (their moments, accumulated in the one pass that writes them).

Our additions, each with a switch in FspfConfig: after the first plane, RANSAC runs again on the window's
remaining points (`planes_per_window`, 1 = the thesis), so a window that straddles a wall and the floor
keeps both; a plane's noise tail (ε … `tail_eps`·ε) seeds no further plane; planes whose inliers are a
thin strip (`min_width`) or bend like a strip of a cylinder (`bend_max`: people, bins, pillars) are
rejected; a plane whose inliers are not one surface (`coherence`: their spread about it exceeds the sensor
noise measured in the same pixels, as when a tilted plane cuts a strip of a table and of the box tops on it)
shrinks to its strongest sub-plane and takes its inliers again; after the stop, the unexamined pixels next to
a plane and within ε of it join it (`grow`, region growing on the organised image); coplanar planes are
merged when the merged plane stays one surface (frontend/planes.py).

Coverage against time: the thesis's stop (nRequired = analysed_fraction of the eligible pixels) leaves the
rest unexamined; windows land at random, so which 10 % that is varies by seed (the labelled mOSD table:
81–100 % of it on its plane at 0.90, 87–100 % at 0.99). Growing attaches those pixels at ~25 ns each, less
than a window's RANSAC costs, so the default keeps 0.90 and grows (100 % of the table at every seed); a
higher analysed_fraction only buys planes in regions no plane touches (small objects), at the windows' cost.
Measured: tests/tools/test_planes_real.py, tests/frontend/test_fspf_tabletop.py, tools/bench_planes.py. The
numpy path (`backend="numpy"`, for the benchmark) has neither the coherence test nor growing.
Simulated acceptance numbers: tests/frontend/test_fspf_sim.py; speed: tools/bench_planes.py.

FSPF (Biswas & Veloso 2012, thesis Alg. 1): random d0, d1, d2 within η; a plane through their points; l
local samples in the window of world size S around d0; accepted when the inlier fraction reaches α_in; stop
at n_max filtered points or k_max neighbourhoods. Its normal is refitted by least squares on the inliers.
"""

from __future__ import annotations

import threading
import time
from collections import namedtuple
from dataclasses import dataclass

import numpy as np
from numba import njit

from kosmap.frontend.camera import DepthConfig, camera_axes, depth_constraints
from kosmap.frontend.params import StageConfig, param
from kosmap.frontend.planes import (PLANE_CLASSES, FrameStats, Planes, fit_plane, merge_planes, moments_from_sums,
                                    ransac_plane, rectify, refit_from_moments)
from kosmap.frontend.records import CameraModel, Transform

__all__ = ["FspfConfig", "PLANE_CLASSES", "filter_planes", "fspf_plus", "fspf", "frame_seed", "warmup"]


@dataclass
class FspfConfig(StageConfig):
    """[fspf]: FSPF+ defaults from the thesis's Table 5.4 (real-time configuration); FSPF from Biswas's config."""

    section = "fspf"
    method: str = param("fspf+", choices=("fspf+", "fspf"), doc="FSPF+ (thesis) or FSPF (Biswas, baseline)")
    backend: str = param("numba", choices=("numba", "numpy"), doc="compiled inner loops, or numpy only (benchmarks)")
    n_min: int = param(40, lo=3, doc="FSPF+: planes with this many inliers or fewer are dropped (nMin)")
    omega_px: int = param(60, lo=2, doc="FSPF+: p1, p2 are drawn within this many pixels of p0 (Ω)", unit="px")
    delta_m: float = param(0.5, lo=0.0, lo_open=True, doc="world size of the search window (Δ; FSPF's S)", unit="m")
    epsilon_m: float = param(0.02, lo=0.0, lo_open=True, doc="FSPF+: RANSAC inlier distance (ε)", unit="m")
    beta: float = param(3.0, lo=0.0, doc="FSPF+: RANSAC stopping factor (β: standard deviations of the draw count)")
    analysed_fraction: float = param(0.90, lo=0.0, hi=1.0, lo_open=True,
                                     doc="FSPF+: stop when this fraction of eligible pixels is consumed (nRequired); with grow the rest "
                                     "next to a plane still joins it, so higher values only add planes where none was found, at the windows' cost")
    ransac_subset: int = param(128, lo=3, doc="FSPF+: hypotheses are scored on this many random window points")
    ransac_max_iter: int = param(100, lo=1, doc="FSPF+: at most this many RANSAC hypotheses per plane")
    planes_per_window: int = param(3, lo=1, doc="FSPF+: planes sought per window (1 = the thesis; more keeps corners)")
    extra_min_fraction: float = param(0.0, lo=0.0, hi=1.0, doc="FSPF+: a further plane in a window is sought only "
                                      "while at least this fraction of the window's points is left (0.1 is a little "
                                      "faster and cleaner, but loses small objects on big surfaces, e.g. a box on a table)")
    bend_max: float = param(1.0, lo=0.0, doc="FSPF+: reject a plane whose inliers bend by more than this many ε "
                            "(a quadratic explaining > 50 % of their residuals: strips of people, bins, pillars); 0 = off")
    min_width: float = param(0.5, lo=0.0, doc="FSPF+: reject a plane whose inliers spread less than this many ε "
                             "(std. dev.) across their second direction: a thin strip fits many planes; 0 = off")
    coherence: bool = param(True, doc="FSPF+: a plane whose inliers spread evenly over ±ε instead of crowding around it "
                            "bridges parallel surfaces (a table and the box tops on it): it shrinks to the strongest one")
    grow: bool = param(True, doc="FSPF+: after the stop (analysed_fraction), unexamined pixels within ε of a 4-neighbour's "
                       "plane join it (region growing): the coverage of a full pass for a fraction of its time")
    tail_eps: float = param(2.0, lo=1.0, doc="FSPF+: a plane's points from ε to this many ε are its noise tail: "
                            "outliers that seed no further plane in the window (1 = off)")
    fspf_max_points: int = param(2000, lo=1, doc="FSPF: stop after this many filtered points (n_max)")
    fspf_max_neighborhoods: int = param(20000, lo=1, doc="FSPF: stop after this many neighbourhoods (k_max)")
    fspf_local_samples: int = param(80, lo=3, doc="FSPF: local samples per neighbourhood (l; Biswas 50–100)")
    fspf_window_px: int = param(60, lo=2, doc="FSPF: d1, d2 are drawn within ±window/2 of d0 (η)", unit="px")
    fspf_error_m: float = param(0.03, lo=0.0, lo_open=True, doc="FSPF: plane inlier distance (ε)", unit="m")
    fspf_min_inlier_fraction: float = param(0.8, lo=0.0, hi=1.0, lo_open=True, doc="FSPF: accept at this inlier fraction (α_in)")
    slanted_min_deg: float = param(3.0, lo=0.0, hi=90.0, doc="tilted less than this from level: ground or ceiling "
                                   "(a 1:12 ramp is 4.8°)", unit="deg")
    slanted_max_deg: float = param(80.0, lo=0.0, hi=90.0, doc="tilted more than this: a wall; between: slanted", unit="deg")
    ground_max_height: float = param(0.15, doc="an up-facing level plane higher than this above the floor (from the "
                                     "mount) is 'raised' (a table top), not ground", unit="m")
    merge: bool = param(True, doc="merge coplanar patches into one refitted plane")
    merge_angle_deg: float = param(5.0, lo=0.0, hi=90.0, doc="merge: normals agree within this angle", unit="deg")
    merge_offset_m: float = param(0.05, lo=0.0, doc="merge: the patch's centroid within this distance of the merged plane "
                                    "(which must also stay one surface: its residual RMS grows by ε/20 at most)", unit="m")
    drop_classes: list = param(["ground", "ceiling"], choices=PLANE_CLASSES, doc="plane classes filtered out")
    seed: int = param(0, lo=0, doc="random seed (per frame, the frame index is added)")

    def __post_init__(self) -> None:
        super().__post_init__()
        from kosmap.frontend.errors import ConfigError

        if self.slanted_max_deg < self.slanted_min_deg:
            raise ConfigError(f"config [fspf] slanted_max_deg = {self.slanted_max_deg} must be ≥ slanted_min_deg = {self.slanted_min_deg}")


def frame_seed(cfg: FspfConfig, index: int) -> int:
    """The seed of frame `index` (the config's seed plus the index)."""
    return int(cfg.seed) + int(index)


# The kernels below use numba's numpy error model: a division is a plain division (inf/NaN on a zero divisor, as in
# numpy) instead of a test that raises ZeroDivisionError and ends the build. The same planes, bit for bit, on 300
# frames of the office log; 4–18 % less FSPF+ time in three alternating runs on this machine.

# ---- random numbers: xorshift64 seeded by splitmix64 (fast inside numba, reproducible) --------------------------------

_M64 = (1 << 64) - 1


def _rng_state(seed: int) -> np.ndarray:
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
def _classify_many_nb(normals, offsets, up, fwd, left, sl_min, sl_max, cam_h, ground_max_h):
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
    sx = sy = sz = sxx = sxy = sxz = syy = syz = szz = 0.0
    for a in range(na):
        x, y, z = np.float64(wx[a]), np.float64(wy[a]), np.float64(wz[a])
        if abs(nx * x + ny * y + nz * z + d) < eps:
            x -= ox
            y -= oy
            z -= oz
            cnt += 1
            sx += x
            sy += y
            sz += z
            sxx += x * x
            sxy += x * y
            sxz += x * z
            syy += y * y
            syz += y * z
            szz += z * z
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
        ax, ay, az = np.float64(wx[a]), np.float64(wy[a]), np.float64(wz[a])
        ux, uy, uz = wx[b] - ax, wy[b] - ay, wz[b] - az
        vx, vy, vz = wx[c] - ax, wy[c] - ay, wz[c] - az
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        if nn < 1e-12:
            continue
        nx /= nn
        ny /= nn
        nz /= nn
        d = -(nx * ax + ny * ay + nz * az)
        cnt = 0
        fx32, fy32, fz32, fd32, fe32 = np.float32(nx), np.float32(ny), np.float32(nz), np.float32(d), np.float32(eps)
        for s in range(ns):  # float32 so the scoring loop vectorises twice as wide
            if abs(fx32 * sx[s] + fy32 * sy[s] + fz32 * sz[s] + fd32) < fe32:
                cnt += 1
        if cnt > best:
            best = cnt
            bx, by, bz, bd = nx, ny, nz, d
            w3 = (cnt / ns) ** 3
            if w3 > 0:
                need = (1.0 + beta * np.sqrt(max(0.0, 1.0 - w3))) / w3
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
def _inv_d2(flat, j, step):
    """|1/z(j−step) − 2/z(j) + 1/z(j+step)|·z(j)²: 1/z is linear in the pixel coordinates on a plane, so this
    second difference is the sensor's depth noise (√6·σ), whatever the plane; −1 where a neighbour is missing."""
    z0, za, zb = flat[j], flat[j - step], flat[j + step]
    if not (za > 0 and zb > 0 and z0 > 0):
        return -1.0
    return abs(1.0 / za - 2.0 / z0 + 1.0 / zb) * z0 * z0


@njit(cache=True, error_model="numpy")
def _split_bridge_nb(sx, sy, sz, pix, ns, flat, W, H, nx, ny, nz, d, eps, beta, max_iter, state,
                     tx, ty, tz, ux, uy, uz, uidx, noise, cos_split):
    """Coherence of a plane's inliers (after NCC-RANSAC, Qian & Ye 2014): one surface, or a plane that bridges
    parallel surfaces (a table and the box tops on it) by cutting a strip of each?

    Tested on a sample of the plane's inliers (sx…, their pixels pix). One surface's inliers scatter
    about their least-squares plane by the sensor's noise, which the image itself gives in the same pixels: the
    second difference of inverse depth between each pixel and its row and column neighbours (noise: scratch).
    A bridging plane's inliers spread over ±ε instead (a tilted strip of each surface crosses the band). When
    their RMS exceeds both ε/5 and 4 noise σ, the plane shrinks to the strongest sub-plane at ε/3 (RANSAC on
    the same inliers, least-squares refit): one of the surfaces; the window's next plane finds the others.
    Returns (split, n, d).
    """
    m = 0
    ss = 0.0
    for s in range(ns):
        r = nx * sx[s] + ny * sy[s] + nz * sz[s] + d
        if abs(r) < eps:
            ss += r * r
            m += 1
    if m < 24 or ss < m * (0.2 * eps) ** 2:  # residual RMS below ε/5: one surface (the bend test's gate)
        return False, nx, ny, nz, d
    m = 0
    ss = 0.0
    nn = 0
    for s in range(ns):
        r = nx * sx[s] + ny * sy[s] + nz * sz[s] + d
        if abs(r) < eps:
            tx[m], ty[m], tz[m] = sx[s], sy[s], sz[s]
            ss += r * r
            m += 1
            q = pix[s]
            rr = q // W
            cc = q - rr * W
            if 0 < cc < W - 1:
                v = _inv_d2(flat, rr * W + cc, 1)
                if v >= 0:
                    noise[nn] = v
                    nn += 1
            if 0 < rr < H - 1:
                v = _inv_d2(flat, rr * W + cc, W)
                if v >= 0:
                    noise[nn] = v
                    nn += 1
    if nn < 12:
        return False, nx, ny, nz, d
    # robust: the upper quartile of |N(0, 6σ²)| is 1.15·√6·σ, step edges among them do not count, and a sensor
    # that quantises depth (disparity steps: many zero differences) still shows its step
    q = np.sort(noise[:nn])  # the upper quartile as np.percentile has it (linear), without its compile time
    pos = 0.75 * (nn - 1)
    lo = int(pos)
    sigma = (q[lo] + (pos - lo) * (q[min(lo + 1, nn - 1)] - q[lo])) / (1.15 * np.sqrt(6.0))
    if ss < m * (2.0 * sigma) ** 2:
        return False, nx, ny, nz, d
    ok, ax, ay, az, ad = _ransac_nb(tx, ty, tz, m, eps / 3.0, beta, m, max_iter, state, ux, uy, uz, uidx)
    if not ok:
        return False, nx, ny, nz, d
    cnt, ax, ay, az, ad = _inlier_fit_nb(tx, ty, tz, m, ax, ay, az, ad, eps / 3.0)
    if cnt < 12:
        return False, nx, ny, nz, d
    if ax * nx + ay * ny + az * nz < 0:
        ax, ay, az, ad = -ax, -ay, -az, -ad
    # the same plane within its noise (a noisy surface, not two): no split. Another plane tilts by degrees
    # (a strip of each surface) or, parallel, sits ε/3 or more away at the inliers' centre.
    cx, cy, cz = np.mean(tx[:m]), np.mean(ty[:m]), np.mean(tz[:m])
    if ax * nx + ay * ny + az * nz > cos_split and abs(ax * cx + ay * cy + az * cz + ad - (nx * cx + ny * cy + nz * cz + d)) < eps / 3.0:
        return False, nx, ny, nz, d
    if ad < 0:
        ax, ay, az, ad = -ax, -ay, -az, -ad
    return True, ax, ay, az, ad


@njit(cache=True, error_model="numpy")
def _partition_nb(wr, wc, wx, wy, wz, na, nx, ny, nz, d, eps, tail, dropped, W, st, lbl, n_pl, out_pix, out_pts,
                  out_plane, n_out, mom):
    """One pass over the window's na points: the plane's inliers (|n·p + d| < ε) go out as plane n_pl (unless
    its class is dropped; their moments Σp, Σppᵀ into mom), its noise tail (ε … tail) is left out, the rest is
    compacted to the front. Returns (points kept, inliers, tail, n_out)."""
    keep = 0
    n_in = 0
    n_tail = 0
    mom[:] = 0.0
    for a in range(na):
        x, y, z = np.float64(wx[a]), np.float64(wy[a]), np.float64(wz[a])
        e = abs(nx * x + ny * y + nz * z + d)
        if e >= eps and e < tail:  # the plane's noise tail: an outlier, but no seed for another plane
            n_tail += 1
            continue
        if e < eps:
            n_in += 1
            if not dropped:
                j = wr[a] * W + wc[a]
                st[j] = 3  # a kept plane's point (back to 2 if the plane is rejected), for grow
                lbl[j] = n_pl
                out_pix[n_out, 0] = wr[a]
                out_pix[n_out, 1] = wc[a]
                out_pts[n_out, 0] = wx[a]
                out_pts[n_out, 1] = wy[a]
                out_pts[n_out, 2] = wz[a]
                out_plane[n_out] = n_pl
                n_out += 1
                mom[0] += x
                mom[1] += y
                mom[2] += z
                mom[3] += x * x
                mom[4] += x * y
                mom[5] += x * z
                mom[6] += y * y
                mom[7] += y * z
                mom[8] += z * z
        else:
            wr[keep] = wr[a]
            wc[keep] = wc[a]
            wx[keep] = wx[a]
            wy[keep] = wy[a]
            wz[keep] = wz[a]
            keep += 1
    return keep, n_in, n_tail, n_out


@njit(cache=True, error_model="numpy")
def _restore_nb(wr, wc, wx, wy, wz, keep, out_pix, out_pts, start, n_out, st, W):
    """Put a plane's points (out[start:n_out]) back into the window after its kept points; returns the new count."""
    k = keep
    for a in range(start, n_out):
        wr[k], wc[k] = out_pix[a, 0], out_pix[a, 1]
        wx[k], wy[k], wz[k] = out_pts[a, 0], out_pts[a, 1], out_pts[a, 2]
        st[out_pix[a, 0] * W + out_pix[a, 1]] = 2
        k += 1
    return k


@njit(cache=True, error_model="numpy")
def _stride_sample_nb(out_pts, out_pix, start, n_out, bx, by, bz, bidx, W):
    """≤ 256 of a plane's points (out[start:n_out]), evenly strided, with their flat pixel indices."""
    step = max(1, (n_out - start) // 256)
    nb = 0
    for a in range(start, n_out, step):
        if nb == 256:
            break
        bx[nb], by[nb], bz[nb] = out_pts[a, 0], out_pts[a, 1], out_pts[a, 2]
        bidx[nb] = out_pix[a, 0] * W + out_pix[a, 1]
        nb += 1
    return nb


@njit(cache=True, error_model="numpy")
def _unmark_nb(st, W, out_pix, start, n_out):
    """A rejected plane's points (out_pix[start:n_out]) are consumed outliers again, not plane points; returns start."""
    for a in range(start, n_out):
        st[out_pix[a, 0] * W + out_pix[a, 1]] = 2
    return start


@njit(cache=True, error_model="numpy", inline="always")
def _grow_take_nb(j, flat, W, tx, ty, nx, ny, nz, d, eps, k, st, lbl, out_pix, out_pts, out_plane, n_out, mom):
    """Pixel j joins plane k when within ε of it (appended to the output, its moments added): the new n_out."""
    r = j // W
    c = j - r * W
    z = np.float64(flat[j])
    x, y = z * tx[c], z * ty[r]
    if abs(nx * x + ny * y + nz * z + d) >= eps:
        return n_out
    st[j] = 3
    lbl[j] = k
    out_pix[n_out, 0], out_pix[n_out, 1] = r, c
    out_pts[n_out, 0], out_pts[n_out, 1], out_pts[n_out, 2] = x, y, z
    out_plane[n_out] = k
    mom[0] += x
    mom[1] += y
    mom[2] += z
    mom[3] += x * x
    mom[4] += x * y
    mom[5] += x * z
    mom[6] += y * y
    mom[7] += y * z
    mom[8] += z * z
    return n_out + 1


@njit(cache=True, error_model="numpy")
def _grow_nb(flat, W, H, tx, ty, eps, st, lbl, stack, pl_n, pl_d, pl_cnt, pl_mom, out_pix, out_pts, out_plane, n_out):
    """Attach the eligible pixels never examined (the thesis stops at nRequired) to the plane of a 4-neighbour
    when within ε of it, flood-filling from there: region growing on the organised image, one test per pixel
    and neighbour. st: 1 unexamined, 3 a kept plane's point (its plane in lbl). Returns (n_out, pixels grown)."""
    n0 = n_out
    mom = np.zeros(9)
    for i in range(H * W):  # in image order: a sequential pass beats the (unordered) candidate list
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
        mom[:] = 0.0
        start = n_out
        n_out = _grow_take_nb(i, flat, W, tx, ty, nx, ny, nz, d, eps, k, st, lbl, out_pix, out_pts, out_plane,
                              n_out, mom)
        top = 0
        if n_out > start:
            stack[0] = i
            top = 1
        while top > 0:  # depth-first flood of plane k through unexamined pixels within ε of it
            top -= 1
            j = stack[top]
            cj = j % W
            for q in (j - 1, j + 1, j - W, j + W):
                if q < 0 or q >= H * W or st[q] != 1 or (q == j - 1 and cj == 0) or (q == j + 1 and cj == W - 1):
                    continue
                m0 = n_out
                n_out = _grow_take_nb(q, flat, W, tx, ty, nx, ny, nz, d, eps, k, st, lbl, out_pix, out_pts,
                                      out_plane, n_out, mom)
                if n_out > m0:
                    stack[top] = q
                    top += 1
        pl_cnt[k] += n_out - start
        for a in range(9):
            pl_mom[k, a] += mom[a]
    return n_out, n_out - n0


# ---- FSPF+ (thesis Alg. 3, 5, 6) -----------------------------------------------------------------------------------------

# The FSPF+ kernel: its parameters in one record (Params), its buffers in two tuples, its counters in `stats`
# (S_* indices), and its main loop as the thesis's Algorithm 3, each step and each of our extensions a helper.

Params = namedtuple("Params", "fx fy cx cy min_d max_d n_min omega delta eps beta frac subset max_iter per_window "
                              "extra_min bend_max min_width tail_eps coherence grow sl_min sl_max cam_h ground_max_h")
S_PIXELS, S_INELIGIBLE, S_INLIERS, S_DROPPED, S_OUTLIERS, S_REMAINING, S_WINDOWS, S_VISITED, S_BENT, S_THIN, \
    S_SPLIT, S_GROWN = range(12)


@njit(cache=True, error_model="numpy")
def _depth_constraints_nb(flat, min_d, max_d, st, cand):
    """depthConstraints (thesis Alg. 4): st = 1 for eligible pixels (NaN compares false), 0 else; their indices
    into cand. Branch-free. Returns their count."""
    m = 0
    for i in range(len(flat)):
        z = flat[i]
        ok = (z > min_d) & (z <= max_d)
        st[i] = ok
        cand[m] = i
        m += ok
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
def _gather_window_nb(flat, st, i0, zbar, prm, W, H, tx, ty, win, stats):
    """The search window: the world size Δ at the mean depth, W = fx·Δ/z̄, H = fy·Δ/z̄ around p0, clipped at the
    border; its eligible pixels become 3D points (win: rows, cols, x, y, z) and are consumed. Returns their count."""
    wr, wc, wx, wy, wz = win
    r0 = i0 // W
    c0 = i0 - r0 * W
    hw = int(0.5 * prm.fx * prm.delta / zbar + 0.5)
    hh = int(0.5 * prm.fy * prm.delta / zbar + 0.5)
    r_lo, r_hi = max(0, r0 - hh), min(H - 1, r0 + hh)
    c_lo, c_hi = max(0, c0 - hw), min(W - 1, c0 + hw)
    stats[S_WINDOWS] += 1
    stats[S_VISITED] += (r_hi - r_lo + 1) * (c_hi - c_lo + 1)
    k = 0
    for r in range(r_lo, r_hi + 1):
        base = r * W
        yr = ty[r]
        for c in range(c_lo, c_hi + 1):
            j = base + c
            if st[j] == 1:
                st[j] = 2
                z = flat[j]
                wr[k] = r
                wc[k] = c
                wx[k] = z * tx[c]
                wy[k] = z * yr
                wz[k] = z
                k += 1
    return k


@njit(cache=True, error_model="numpy")
def _scratch_nb(subset):
    """The small per-frame buffers: the RANSAC subset (x, y, z, index), a ≤ 256-point sample of a plane with its
    pixels, the coherence test's copies and noise, and a plane's moments."""
    f = np.float32
    return (np.empty(subset, f), np.empty(subset, f), np.empty(subset, f), np.empty(subset, np.int64),
            np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, np.int64),
            np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, f), np.empty(256, f),
            np.empty(256, np.int64), np.empty(512), np.empty(9))


@njit(cache=True, error_model="numpy")
def _take_plane_nb(win, na, nx, ny, nz, d, cls, prm, axes, drop, state, sc, flat, W, H, st, lbl, out, n_out, n_pl,
                   stats):
    """A plane's inliers out of the window (_partition_nb); with the coherence test on, a plane that is not one
    surface shrinks to its strongest sub-plane and takes again. Returns (points kept in the window, inliers, n_out,
    the plane's class, whether that class is dropped)."""
    wr, wc, wx, wy, wz = win
    out_pix, out_pts, out_plane = out[0], out[1], out[2]
    bx, by, bz, bidx, qx, qy, qz, ux, uy, uz, uidx, noise, mom = sc[4:]
    tail = max(prm.tail_eps, 1.0) * prm.eps
    start = n_out
    dropped = drop[cls]
    keep, n_in = 0, 0
    for attempt in range(2):
        keep, n_in, n_tail, n_out = _partition_nb(wr, wc, wx, wy, wz, na, nx, ny, nz, d, prm.eps, tail, dropped, W,
                                                  st, lbl, n_pl, out_pix, out_pts, out_plane, n_out, mom)
        stats[S_OUTLIERS] += n_tail
        if attempt == 1 or not prm.coherence or dropped or n_in <= prm.n_min:
            break
        nb = _stride_sample_nb(out_pts, out_pix, start, n_out, bx, by, bz, bidx, W)
        split, sx_, sy_, sz_, sd_ = _split_bridge_nb(bx, by, bz, bidx, nb, flat, W, H, nx, ny, nz, d, prm.eps,
                                                     prm.beta, prm.max_iter, state, qx, qy, qz, ux, uy, uz, uidx,
                                                     noise, np.cos(np.radians(2.0)))
        if not split:
            break
        stats[S_SPLIT] += 1
        na = _restore_nb(wr, wc, wx, wy, wz, keep, out_pix, out_pts, start, n_out, st, W)
        n_out = start
        nx, ny, nz, d = sx_, sy_, sz_, sd_
        cls = _classify_nb(nx, ny, nz, d, axes[0], axes[1], axes[2], prm.sl_min, prm.sl_max, prm.cam_h,
                           prm.ground_max_h)
        dropped = drop[cls]
    return keep, n_in, n_out, cls, dropped


@njit(cache=True, error_model="numpy")
def _accept_plane_nb(prm, mom, n_in, start, n_out, out_pts, bx, by, bz, stats):
    """The plane refitted from all its inliers' moments, rectified; rejected (ok False) when its inliers are a
    strip no wider than the inlier band (min_width: its plane is not determined) or bend like a strip of a curved
    surface (bend_max: a person, a pillar; tested on ≤ 256 of them, evenly strided, when their residual spread is
    not far below ε). Returns (ok, nx, ny, nz, d)."""
    inv = 1.0 / n_in
    mx, my, mz = mom[0] * inv, mom[1] * inv, mom[2] * inv
    C = np.empty((3, 3))
    C[0, 0] = mom[3] * inv - mx * mx
    C[0, 1] = C[1, 0] = mom[4] * inv - mx * my
    C[0, 2] = C[2, 0] = mom[5] * inv - mx * mz
    C[1, 1] = mom[6] * inv - my * my
    C[1, 2] = C[2, 1] = mom[7] * inv - my * mz
    C[2, 2] = mom[8] * inv - mz * mz
    ev, v = np.linalg.eigh(C)
    if ev[1] < (prm.min_width * prm.eps) ** 2:
        stats[S_THIN] += 1
        return False, 0.0, 0.0, 0.0, 0.0
    fx_, fy_, fz_ = v[0, 0], v[1, 0], v[2, 0]
    fd = -(fx_ * mx + fy_ * my + fz_ * mz)
    if fd < 0:
        fx_, fy_, fz_, fd = -fx_, -fy_, -fz_, -fd
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
def _record_plane_nb(out, n_pl, nx, ny, nz, d, cls, n_in, mom):
    pl_n, pl_d, pl_cls, pl_cnt, pl_mom = out[3], out[4], out[5], out[6], out[7]
    pl_n[n_pl, 0], pl_n[n_pl, 1], pl_n[n_pl, 2] = nx, ny, nz
    pl_d[n_pl] = d
    pl_cls[n_pl] = cls
    pl_cnt[n_pl] = n_in
    for a in range(9):
        pl_mom[n_pl, a] = mom[a]


@njit(cache=True, error_model="numpy")
def _window_planes_nb(win, k, prm, axes, drop, state, sc, flat, W, H, st, lbl, out, n_out, n_pl, stats):
    """The planes of one window of k points (thesis Alg. 3's inner part): RANSAC (Alg. 5) and a least-squares
    refit, the class (Alg. 6), the inliers taken, planes of ≤ nMin inliers, dropped classes, thin strips and
    bent strips set apart; then again on the window's rest, up to per_window planes (1 = the thesis).
    Returns (n_out, n_pl)."""
    wx, wy, wz = win[2], win[3], win[4]
    sx, sy, sz, sidx = sc[0], sc[1], sc[2], sc[3]
    bx, by, bz, mom = sc[4], sc[5], sc[6], sc[16]
    na = k
    for pw in range(prm.per_window):
        # a further plane only where enough of the window is left (a residue of < extra_min of it is mostly the
        # edges and noise of the planes found)
        if na <= prm.n_min or (pw > 0 and na < prm.extra_min * k):
            break
        ok, nx, ny, nz, d = _ransac_nb(wx, wy, wz, na, prm.eps, prm.beta, prm.subset, prm.max_iter, state, sx, sy,
                                       sz, sidx)
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
def _fspf_plus_nb(depth, prm, axes, drop, state, bufs, out, stats):
    """FSPF+ (thesis Alg. 3) on one depth image. prm: Params; axes: (up, forward, left); drop: bool per class;
    bufs: (st, cand, rows, cols, x, y, z, plane label) of ≥ H·W entries, reused from frame to frame; out: (pixels,
    points, plane, normals, offsets, classes, counts, moments). Returns (points, planes) written to out."""
    H, W = depth.shape
    flat = depth.ravel()
    st, cand, lbl = bufs[0], bufs[1], bufs[7]  # st: 0 ineligible, 1 eligible, 2 consumed, 3 a kept plane's point
    win = (bufs[2], bufs[3], bufs[4], bufs[5], bufs[6])
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
        k = _gather_window_nb(flat, st, i0, zbar, prm, W, H, tx, ty, win, stats)
        remaining -= k
        if k <= prm.n_min:
            stats[S_OUTLIERS] += k
            continue
        n_out, n_pl = _window_planes_nb(win, k, prm, axes, drop, state, sc, flat, W, H, st, lbl, out, n_out, n_pl,
                                        stats)
    if prm.grow and remaining > 0:  # our extension: the unexamined pixels next to a plane join it
        n_out, grown = _grow_nb(flat, W, H, tx, ty, prm.eps, st, lbl, win[0], out[3], out[4], out[6], out[7], out[0],
                                out[1], out[2], n_out)
        remaining -= grown
        stats[S_GROWN] = grown
    stats[S_INLIERS] = n_out
    stats[S_REMAINING] = remaining
    return n_out, n_pl


# ---- FSPF (Biswas & Veloso; thesis Alg. 1) -----------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _fspf_nb(depth, fx, fy, cx, cy, min_d, max_d, n_max, k_max, l, eta, size, eps, alpha, up, fwd, left,
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
        ux, uy, uz = x1 - x0, y1 - y0, z1 - z0
        vx, vy, vz = x2 - x0, y2 - y0, z2 - z0
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        if nn < 1e-12:
            continue
        nx /= nn
        ny /= nn
        nz /= nn
        d = -(nx * x0 + ny * y0 + nz * z0)
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


# ---- numpy paths (same algorithms, vectorised per window; for the benchmark) ---------------------------------------------

def _fspf_plus_np(depth, cam, cfg, dcfg, classes_of, drop, rng):
    H, W = depth.shape
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    elig = depth_constraints(depth, dcfg.min_depth, dcfg.max_depth)
    st = elig.astype(np.uint8)
    cand = np.flatnonzero(elig)
    n_elig = len(cand)
    remaining = n_elig
    stop = (1.0 - cfg.analysed_fraction) * n_elig
    om = cfg.omega_px
    pix, pts, plane, normals, offsets, classes, counts = [], [], [], [], [], [], []
    n_drop = n_outl = 0
    flat_st = st.reshape(-1)
    misses = 0
    while remaining > stop and len(cand):
        i0 = int(cand[rng.integers(len(cand))])
        if flat_st[i0] != 1:
            misses += 1
            if misses > 16:  # compact the candidates once many have been consumed
                cand = cand[flat_st[cand] == 1]
                misses = 0
            continue
        r0, c0 = divmod(i0, W)
        off = rng.integers(-om, om + 1, (40, 2))
        rr, cc = r0 + off[:, 0], c0 + off[:, 1]
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        rr, cc = rr[ok], cc[ok]
        jj = rr * W + cc
        ok = (flat_st[jj] == 1) & (jj != i0)
        jj = jj[ok]
        _, first = np.unique(jj, return_index=True)
        jj = jj[np.sort(first)][:2]
        if len(jj) < 2:
            flat_st[i0] = 2
            remaining -= 1
            n_outl += 1
            continue
        zbar = (depth.flat[i0] + depth.flat[jj[0]] + depth.flat[jj[1]]) / 3.0
        hw, hh = int(0.5 * fx * cfg.delta_m / zbar + 0.5), int(0.5 * fy * cfg.delta_m / zbar + 0.5)
        r_lo, r_hi, c_lo, c_hi = max(0, r0 - hh), min(H - 1, r0 + hh), max(0, c0 - hw), min(W - 1, c0 + hw)
        win = st[r_lo:r_hi + 1, c_lo:c_hi + 1]
        m = win == 1
        wr, wc = np.nonzero(m)
        win[m] = 2
        k = len(wr)
        remaining -= k
        if k <= cfg.n_min:
            n_outl += k
            continue
        wr += r_lo
        wc += c_lo
        z = depth[wr, wc].astype(np.float64)
        P = np.column_stack(((wc - cx) * z / fx, (wr - cy) * z / fy, z))
        active = np.arange(k)
        eps = cfg.epsilon_m
        for pw in range(cfg.planes_per_window):
            if len(active) <= cfg.n_min or (pw > 0 and len(active) < cfg.extra_min_fraction * k):
                break
            n, d, inl = ransac_plane(P[active], eps, cfg.beta, rng, cfg.ransac_subset, cfg.ransac_max_iter)
            n_in = int(inl.sum())
            if n_in <= cfg.n_min:
                break
            # the noise tail (ε … tail_eps·ε) leaves the window as outliers
            res = np.abs(P[active] @ n + d)
            tail = ~inl & (res < max(cfg.tail_eps, 1.0) * eps)
            n_outl += int(tail.sum())
            cls = int(classes_of(n[None], np.array([d]))[0])
            sel = active[inl]
            active = active[~inl & ~tail]
            if drop[cls]:
                n_drop += n_in
                continue
            q = P[sel] - P[sel].mean(axis=0)
            ev = np.linalg.eigvalsh(q.T @ q / n_in)
            if ev[1] < (cfg.min_width * eps) ** 2 or (cfg.bend_max > 0 and ev[0] > (0.2 * eps) ** 2
                                                    and _bends(P[sel][:: max(1, n_in // 256)][:256], n, d, eps,
                                                               cfg.bend_max)):
                n_outl += n_in  # a thin strip, or a strip of a curved surface
                continue
            else:
                plane.append(np.full(n_in, len(normals), np.int32))
                pix.append(np.column_stack((wr[sel], wc[sel])).astype(np.int32))
                pts.append(P[sel].astype(np.float32))
                normals.append(n)
                offsets.append(d)
                classes.append(cls)
                counts.append(n_in)
        n_outl += len(active)
    stats = FrameStats(H * W, H * W - n_elig, int(sum(counts)), n_drop, n_outl, remaining)
    return _assemble(pix, pts, plane, normals, offsets, classes, counts, stats, (H, W), "fspf+")


def _bends(p: np.ndarray, n: np.ndarray, d: float, eps: float, bend_max: float, r2_max: float = 0.5) -> bool:
    """_curved_nb in numpy: a quadratic in the in-plane coordinates explains > r2_max of the residuals and
    bends by more than bend_max·ε."""
    r = p @ n + d
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    u, v = (p - p.mean(axis=0)) @ e1, (p - p.mean(axis=0)) @ e2
    scale = max(np.abs(u).max(), np.abs(v).max(), 1e-12)
    u, v = u / scale, v / scale
    A = np.column_stack((np.ones_like(u), u, v, u * u, v * v, u * v))
    if len(r) < 24:
        return False
    coef = np.linalg.lstsq(A, r, rcond=None)[0]
    tot = np.sum((r - r.mean()) ** 2)
    if tot <= 0:
        return False
    bend = A[:, 3:] @ coef[3:]
    return 1.0 - np.sum((r - A @ coef) ** 2) / tot > r2_max and bend.max() - bend.min() > bend_max * eps


def _fspf_np(depth, cam, cfg, dcfg, classes_of, drop, rng, batch: int = 256):
    """FSPF in numpy: neighbourhoods are drawn and tested a batch at a time; the accepted ones are then taken
    in order (they alone change the state), up to n_max points."""
    H, W = depth.shape
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    elig = depth_constraints(depth, dcfg.min_depth, dcfg.max_depth)
    st = elig.astype(np.uint8).reshape(-1)  # 0 ineligible, 1 eligible, 2 examined, 3 plane point, 4 dropped
    zf = depth.reshape(-1).astype(np.float64)
    l, eta, half = cfg.fspf_local_samples, cfg.fspf_window_px, cfg.fspf_window_px // 2
    need = int(np.ceil(cfg.fspf_min_inlier_fraction * l - 1e-9))
    pix, pts, plane, normals, offsets, classes, counts = [], [], [], [], [], [], []
    n_out = n_drop = 0
    done = 0
    while done < cfg.fspf_max_neighborhoods and n_out + n_drop < cfg.fspf_max_points:
        B = min(batch, cfg.fspf_max_neighborhoods - done)
        done += B
        rs = np.empty((B, 3), np.int64)
        cs = np.empty((B, 3), np.int64)
        rs[:, 0], cs[:, 0] = rng.integers(0, H, B), rng.integers(0, W, B)
        rs[:, 1:] = rs[:, :1] + rng.integers(0, eta + 1, (B, 2)) - half
        cs[:, 1:] = cs[:, :1] + rng.integers(0, eta + 1, (B, 2)) - half
        ok = ((rs >= 0) & (rs < H) & (cs >= 0) & (cs < W)).all(axis=1)
        rs, cs = rs[ok], cs[ok]
        j3 = rs * W + cs
        ok = (st[j3] != 0).all(axis=1)
        rs, cs, j3 = rs[ok], cs[ok], j3[ok]
        if not len(rs):
            continue
        z3 = zf[j3]
        p3 = np.stack(((cs - cx) * z3 / fx, (rs - cy) * z3 / fy, z3), axis=-1)  # K×3×3
        n = np.cross(p3[:, 1] - p3[:, 0], p3[:, 2] - p3[:, 0])
        nn = np.linalg.norm(n, axis=1)
        ok = nn > 1e-12
        if not ok.any():
            continue
        rs, cs, p3, n, nn, z3 = rs[ok], cs[ok], p3[ok], n[ok], nn[ok], z3[ok]
        n /= nn[:, None]
        d = -np.einsum("ij,ij->i", n, p3[:, 0])
        zbar = z3.mean(axis=1)
        u = rng.random((len(rs), l, 2)) - 0.5
        lr = rs[:, :1] + np.floor(u[..., 0] * (fy * cfg.delta_m / zbar)[:, None] + 0.5).astype(np.int64)
        lc = cs[:, :1] + np.floor(u[..., 1] * (fx * cfg.delta_m / zbar)[:, None] + 0.5).astype(np.int64)
        inside = (lr >= 0) & (lr < H) & (lc >= 0) & (lc < W)
        j = np.where(inside, lr * W + lc, 0)
        valid = inside & (st[j] != 0)
        z = zf[j]
        P = np.stack(((j % W - cx) * z / fx, (j // W - cy) * z / fy, z), axis=-1)  # K×l×3
        inl = valid & (np.abs(np.einsum("kij,kj->ki", P, n) + d[:, None]) < cfg.fspf_error_m)
        accepted = inl.sum(axis=1) >= need
        last = len(rs)
        for k in np.flatnonzero(accepted):
            if n_out + n_drop >= cfg.fspf_max_points:
                last = k
                break
            jk, Pk = j[k][inl[k]], P[k][inl[k]]
            nk, dk = rectify(*fit_plane(Pk))
            cls = int(classes_of(nk[None], np.array([dk]))[0])
            jk, first = np.unique(jk, return_index=True)
            Pk = Pk[first]
            new = (st[jk] == 1) | (st[jk] == 2)
            if drop[cls]:
                st[jk[new]] = 4
                n_drop += int(new.sum())
                continue
            if not new.any():
                continue
            jk, Pk = jk[new], Pk[new]
            st[jk] = 3
            plane.append(np.full(len(jk), len(normals), np.int32))
            pix.append(np.column_stack((jk // W, jk % W)).astype(np.int32))
            pts.append(Pk.astype(np.float32))
            normals.append(nk)
            offsets.append(float(dk))
            classes.append(cls)
            counts.append(len(jk))
            n_out += len(jk)
        # the rejected neighbourhoods before the stop: their examined samples are outliers
        rej = valid[:last] & ~accepted[:last, None]
        jr = j[:last][rej]
        st[jr[st[jr] == 1]] = 2
    stats = FrameStats(H * W, int((st == 0).sum()), n_out, n_drop, int((st == 2).sum()), int((st == 1).sum()))
    return _assemble(pix, pts, plane, normals, offsets, classes, counts, stats, (H, W), "fspf")


def _assemble(pix, pts, plane, normals, offsets, classes, counts, stats, shape, method) -> Planes:
    if not normals:
        return Planes.empty(shape, stats, method)
    return Planes(np.concatenate(pts), np.concatenate(plane), np.concatenate(pix), np.array(normals, float),
                  np.array(offsets, float), np.array(classes, np.int8), np.array(counts, np.int64), stats, shape, method)


# ---- the public entry points ---------------------------------------------------------------------------------------------

def _prepare(depth_m, cam: CameraModel):
    depth = np.ascontiguousarray(depth_m, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth image must be 2-D, got shape {depth.shape}")
    if (cam.height, cam.width) != depth.shape:
        raise ValueError(f"camera is {cam.width}×{cam.height} but the depth image is {depth.shape[1]}×{depth.shape[0]}; "
                         "use frontend.camera.camera_for")
    return depth


_AXES: dict[bytes | None, tuple] = {}


def _axes(mount: Transform | None) -> tuple:
    """camera_axes, remembered per mount rotation (a frame's mount arrives as a new object in a worker; the
    numpy of camera_axes cost ~0.1 ms a frame)."""
    key = None if mount is None else np.asarray(mount.rotation, np.float64).tobytes()
    axes = _AXES.get(key)
    if axes is None:
        if len(_AXES) > 64:
            _AXES.clear()
        axes = _AXES[key] = camera_axes(mount)
    return axes


class _Classes:
    """Plane classes for one camera: gravity axes and height from the mount, bounds from the config."""

    def __init__(self, cfg: FspfConfig, mount: Transform | None) -> None:
        self.up, self.fwd, self.left = _axes(mount)
        self.cam_h = float(mount.translation[2]) if mount is not None else float("nan")
        self.cfg = cfg

    def __call__(self, normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """planes.classify, compiled (the same rules: tests/frontend/test_fspf.py checks they agree)."""
        return _classify_many_nb(np.ascontiguousarray(normals, np.float64), np.ascontiguousarray(offsets, np.float64),
                                 *self.args())

    def args(self) -> tuple:
        c = self.cfg
        return (self.up, self.fwd, self.left, c.slanted_min_deg, c.slanted_max_deg, self.cam_h, c.ground_max_height)


_WORK = threading.local()
_DEFAULT_DEPTH = DepthConfig()


def _workspace(npx: int, p_cap: int) -> dict:
    """Buffers the FSPF+ kernel reuses from frame to frame (per thread): fresh memory costs a page fault per
    4 KiB on first touch, which on a virtual machine was a third of a frame's time."""
    ws = getattr(_WORK, "ws", None)
    if ws is None or ws["npx"] < npx or ws["p_cap"] < p_cap:
        ws = {"npx": npx, "p_cap": p_cap, "st": np.empty(npx, np.uint8), "cand": np.empty(npx, np.int32),
              "wr": np.empty(npx, np.int32), "wc": np.empty(npx, np.int32), "wx": np.empty(npx, np.float32),
              "wy": np.empty(npx, np.float32), "wz": np.empty(npx, np.float32), "lbl": np.empty(npx, np.int32),
              "out_pix": np.empty((npx, 2), np.int32), "out_pts": np.empty((npx, 3), np.float32),
              "out_plane": np.empty(npx, np.int32), "pl_n": np.empty((p_cap, 3)), "pl_d": np.empty(p_cap),
              "pl_cls": np.empty(p_cap, np.int8), "pl_cnt": np.empty(p_cap, np.int64), "pl_mom": np.empty((p_cap, 9))}
        _WORK.ws = ws
    return ws


def _finish(planes: Planes, cfg: FspfConfig, classes_of: _Classes, t0: float, moments=None) -> Planes:
    if cfg.merge and len(planes) > 1:
        drop = tuple(PLANE_CLASSES.index(c) for c in cfg.drop_classes)
        # merged planes stay one surface: their residual RMS may grow by ε/20 at most (planes.merge_planes)
        eps = cfg.fspf_error_m if planes.method == "fspf" else cfg.epsilon_m
        planes = merge_planes(planes, cfg.merge_angle_deg, cfg.merge_offset_m, classes_of, drop, moments,
                              inplace=True, rms_step=eps / 20.0)
    planes.stats.planes = len(planes)
    planes.stats.elapsed_ms = (time.thread_time() - t0) * 1e3  # this thread's CPU time: the algorithm's own
    return planes


def _drop_mask(cfg: FspfConfig) -> np.ndarray:
    return np.array([c in cfg.drop_classes for c in PLANE_CLASSES], dtype=np.bool_)


def fspf_plus(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None, depth_cfg: DepthConfig | None = None,
              mount: Transform | None = None, seed: int | None = None, backend: str | None = None,
              copy: bool = True) -> Planes:
    """FSPF+ (thesis Alg. 3, 5, 6) on one depth image (H×W metres; 0/NaN invalid). Same seed, same result.

    `mount` (base_link ← optical, frontend.camera.camera_mount) gives gravity for the classes; None = level.
    `copy=False` returns the points, plane indices and pixels as views of this thread's scratch buffers, valid
    only until its next call: for a caller that uses them at once (kosframe.py; copying them cost ~0.5 ms a frame).
    """
    t0 = time.thread_time()
    cfg = cfg or FspfConfig()
    dcfg = depth_cfg or _DEFAULT_DEPTH
    depth = _prepare(depth_m, cam)
    classes_of = _Classes(cfg, mount)
    seed = cfg.seed if seed is None else seed
    if (backend or cfg.backend) == "numpy":
        planes = _fspf_plus_np(depth, cam, cfg, dcfg, classes_of, _drop_mask(cfg), np.random.default_rng(seed))
        return _finish(planes, cfg, classes_of, t0)
    H, W = depth.shape
    ws = _workspace(H * W, H * W // (cfg.n_min + 1) + 1)
    out_pix, out_pts, out_plane = ws["out_pix"], ws["out_pts"], ws["out_plane"]
    pl_n, pl_d, pl_cls, pl_cnt, pl_mom = ws["pl_n"], ws["pl_d"], ws["pl_cls"], ws["pl_cnt"], ws["pl_mom"]
    stats = np.zeros(12, np.int64)
    prm = Params(float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy), float(dcfg.min_depth),
                 float(dcfg.max_depth), int(cfg.n_min), int(cfg.omega_px), float(cfg.delta_m), float(cfg.epsilon_m),
                 float(cfg.beta), float(cfg.analysed_fraction), int(cfg.ransac_subset), int(cfg.ransac_max_iter),
                 int(cfg.planes_per_window), float(cfg.extra_min_fraction), float(cfg.bend_max), float(cfg.min_width),
                 float(cfg.tail_eps), bool(cfg.coherence), bool(cfg.grow), float(cfg.slanted_min_deg),
                 float(cfg.slanted_max_deg), float(classes_of.cam_h), float(cfg.ground_max_height))
    bufs = (ws["st"], ws["cand"], ws["wr"], ws["wc"], ws["wx"], ws["wy"], ws["wz"], ws["lbl"])
    out = (out_pix, out_pts, out_plane, pl_n, pl_d, pl_cls, pl_cnt, pl_mom)
    n, p = _fspf_plus_nb(depth, prm, (classes_of.up, classes_of.fwd, classes_of.left), _drop_mask(cfg),
                         _rng_state(seed), bufs, out, stats)
    pts, plane, pix = (out_pts[:n].copy(), out_plane[:n].copy(), out_pix[:n].copy()) if copy else \
        (out_pts[:n], out_plane[:n], out_pix[:n])
    planes = Planes(pts, plane, pix, pl_n[:p].copy(), pl_d[:p].copy(),
                    pl_cls[:p].copy(), pl_cnt[:p].copy(), FrameStats(*(int(s) for s in stats[:6])), (H, W), "fspf+")
    planes.stats.windows, planes.stats.visited = int(stats[6]), int(stats[7])
    planes.stats.bent, planes.stats.thin = int(stats[8]), int(stats[9])
    planes.stats.split, planes.stats.grown = int(stats[10]), int(stats[11])
    s1, s2 = moments_from_sums(pl_mom[:p])
    if planes.stats.grown and p:  # the grown planes refitted from their moments
        planes.normals, planes.offsets = refit_from_moments(planes.counts.astype(np.float64), s1, s2)
    return _finish(planes, cfg, classes_of, t0, (planes.counts.astype(np.float64), s1, s2))


def fspf(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None, depth_cfg: DepthConfig | None = None,
         mount: Transform | None = None, seed: int | None = None, backend: str | None = None) -> Planes:
    """FSPF (Biswas & Veloso; thesis Alg. 1), the baseline, with the same classes, dropping and merging."""
    t0 = time.thread_time()
    cfg = cfg or FspfConfig()
    dcfg = depth_cfg or _DEFAULT_DEPTH
    depth = _prepare(depth_m, cam)
    classes_of = _Classes(cfg, mount)
    seed = cfg.seed if seed is None else seed
    if (backend or cfg.backend) == "numpy":
        planes = _fspf_np(depth, cam, cfg, dcfg, classes_of, _drop_mask(cfg), np.random.default_rng(seed))
        return _finish(planes, cfg, classes_of, t0)
    H, W = depth.shape
    l = cfg.fspf_local_samples
    n_cap = cfg.fspf_max_points + l
    p_cap = cfg.fspf_max_points + 1
    out_pix = np.empty((n_cap, 2), np.int32)
    out_pts = np.empty((n_cap, 3), np.float32)
    out_plane = np.empty(n_cap, np.int32)
    pl_n, pl_d = np.empty((p_cap, 3)), np.empty(p_cap)
    pl_cls, pl_cnt = np.empty(p_cap, np.int8), np.empty(p_cap, np.int64)
    stats = np.zeros(6, np.int64)
    n, p = _fspf_nb(depth, cam.fx, cam.fy, cam.cx, cam.cy, dcfg.min_depth, dcfg.max_depth, cfg.fspf_max_points,
                    cfg.fspf_max_neighborhoods, l, cfg.fspf_window_px, cfg.delta_m, cfg.fspf_error_m,
                    cfg.fspf_min_inlier_fraction, *classes_of.args(), _drop_mask(cfg),
                    _rng_state(seed), _workspace(H * W, 1)["st"], out_pix, out_pts, out_plane, pl_n, pl_d, pl_cls,
                    pl_cnt, stats)
    planes = Planes(out_pts[:n].copy(), out_plane[:n].copy(), out_pix[:n].copy(), pl_n[:p].copy(), pl_d[:p].copy(),
                    pl_cls[:p].copy(), pl_cnt[:p].copy(), FrameStats(*(int(s) for s in stats)), (H, W), "fspf")
    return _finish(planes, cfg, classes_of, t0)


def filter_planes(depth_m: np.ndarray, cam: CameraModel, cfg: FspfConfig | None = None,
                  depth_cfg: DepthConfig | None = None, mount: Transform | None = None, seed: int | None = None,
                  copy: bool = True) -> Planes:
    """FSPF+ or FSPF as `cfg.method` says (`copy`: see fspf_plus; FSPF's arrays are its own)."""
    cfg = cfg or FspfConfig()
    if cfg.method == "fspf":
        return fspf(depth_m, cam, cfg, depth_cfg, mount, seed)
    return fspf_plus(depth_m, cam, cfg, depth_cfg, mount, seed, copy=copy)


def warmup(method: str | None = None, shape: tuple[int, int] | None = None) -> None:
    """Compile (or load from numba's cache) the kernel of `method` ("fspf+" or "fspf"; None: both) on a tiny image:
    on a fresh machine FSPF's costs 5 s that a build with FSPF+ never needs. With `shape` (rows, cols), FSPF+'s
    buffers for frames of that size are made too, so that the first frame's time is the algorithm's alone."""
    if shape is not None and method in (None, "fspf+"):
        h, w = int(shape[0]), int(shape[1])
        fspf_plus(np.zeros((h, w), np.float32), CameraModel.from_fov(w, h, np.radians(70.0), np.radians(60.0)))
    cam = CameraModel.from_fov(32, 24, np.radians(70.0), np.radians(60.0))
    d = np.full((24, 32), 2.0, np.float32)
    d[:, 16:] = 2.0 + 0.05 * np.arange(16)  # a fold: two planes, so merging compiles too
    if method in (None, "fspf+"):
        fspf_plus(d, cam, FspfConfig(n_min=3, delta_m=0.2))
    if method in (None, "fspf"):
        fspf(d, cam, FspfConfig(fspf_max_neighborhoods=10))
