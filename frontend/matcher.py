"""Scan-to-map matching against a likelihood field (frontend/likelihood.py): three searches, numba kernels.

- `correlative_search`: brute force over a small (x, y, yaw) window around a prediction, nearest-cell
  scores (Olson, "Real-time correlative scan matching", ICRA 2009); survives a guess a few cm / degrees off.
- `gauss_newton`: sub-cell refinement on the bilinearly interpolated field (Kohlbrecher et al., hector_mapping,
  2011, eq. 7–13) with a quadratic prior towards the predicted pose (odometry), which may be stronger
  along the direction of travel than across it (a narrow depth scan sees one wall: docs/dependencies.md).
- `SearchGrids` + `branch_and_bound`: the exact correlative search over a large window for loop closure
  (Hess et al., "Real-time loop closure in 2D LIDAR SLAM", ICRA 2016, §V: precomputed max grids, DFS).

These are written by hand, not taken from kiss-icp: kiss-icp's point-to-point ICP with a constant-velocity
guess diverges on the sparse 180° laser logs (1° beams, 5 Hz, fast turns) and on narrow depth-camera scans
(one wall in view), metres of error in docs/dependencies.md; likelihood-field matching with an odometry prior reached
Cartographer's accuracy there. numba pays: one correlative search 0.94 ms vs 3.6 ms in numpy (docs/dependencies.md).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from kosmap.frontend.likelihood import LikelihoodField, mean_score, sample


@njit(cache=True)
def _wrap(a):
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


@njit(cache=True)
def gauss_newton(field, ox, oy, res, pts, pose0, prior, weight, max_iter, welsch=True, sigma=0.05):
    """Minimise (1/N)·Σ ρ_k + (ξ − ξp)ᵀ W (ξ − ξp) over ξ = (x, y, yaw) from pose0.

    ρ_k = 1 − M(q_k) (`welsch`, the default): with M = exp(−d²/2σ²) this is the Welsch robust kernel of
    the point's distance d to the map, quadratic (d²/2σ²) near the optimum and flat for outliers. Solved by
    iteratively reweighted least squares, point to line: the field gives each point's distance
    d = σ²·|∇M|/M and the line's normal −∇M/|∇M|, the weight is M (Holland & Welsch 1977). ρ_k = (1 − M)²
    (hector_mapping's cost, Kohlbrecher et al. 2011) is quartic in d near the optimum, so there even a weak
    prior biases the answer.
    Returns (pose, H, score): H = (1/N)·Σ JᵀJ, the data term's Gauss–Newton information, and the final
    mean field value.
    """
    n = pts.shape[0]
    x = pose0.copy()
    inv_n = 1.0 / max(n, 1)
    hd = np.zeros((3, 3))
    best_cost = 1e300
    best = x.copy()
    for _ in range(max_iter):
        c = math.cos(x[2])
        s = math.sin(x[2])
        h = np.zeros((3, 3))
        g = np.zeros(3)
        cost = 0.0
        for k in range(n):
            px = pts[k, 0]
            py = pts[k, 1]
            qx = x[0] + c * px - s * py
            qy = x[1] + s * px + c * py
            v, gx, gy = sample(field, (qx - ox) / res - 0.5, (qy - oy) / res - 0.5)
            if welsch:
                cost += 1.0 - v
                gn = math.hypot(gx, gy)
                if v < 1e-6 or gn < 1e-12:
                    continue
                # unit normal away from the map, signed distance along it, Welsch weight M/σ²
                nx = -gx / gn
                ny = -gy / gn
                r = sigma * sigma * (gn / res) / v
                wk = math.sqrt(v) / sigma
                r *= wk
                j0 = nx * wk
                j1 = ny * wk
            else:
                r = 1.0 - v
                cost += r * r
                j0 = -gx / res
                j1 = -gy / res
            # dq/dyaw = (−s·px − c·py, c·px − s·py)
            j2 = j0 * (-s * px - c * py) + j1 * (c * px - s * py)
            h[0, 0] += j0 * j0
            h[0, 1] += j0 * j1
            h[0, 2] += j0 * j2
            h[1, 1] += j1 * j1
            h[1, 2] += j1 * j2
            h[2, 2] += j2 * j2
            g[0] += j0 * r
            g[1] += j1 * r
            g[2] += j2 * r
        h[1, 0] = h[0, 1]
        h[2, 0] = h[0, 2]
        h[2, 1] = h[1, 2]
        h *= inv_n
        g *= inv_n
        cost *= inv_n
        e = np.empty(3)
        e[0] = x[0] - prior[0]
        e[1] = x[1] - prior[1]
        e[2] = _wrap(x[2] - prior[2])
        we = weight @ e
        cost += e @ we
        if cost > best_cost:
            break
        best_cost = cost
        best[:] = x
        hd[:, :] = h
        a = h + weight
        b = g + we
        for i in range(3):
            a[i, i] += 1e-9
        step = np.linalg.solve(a, -b)
        x = x + step
        x[2] = _wrap(x[2])
        if abs(step[0]) < 1e-5 and abs(step[1]) < 1e-5 and abs(step[2]) < 1e-5:
            best_cost = 1e300  # accept this last step and stop below
            best[:] = x
            break
    score = 0.0
    c = math.cos(best[2])
    s = math.sin(best[2])
    for k in range(n):
        qx = best[0] + c * pts[k, 0] - s * pts[k, 1]
        qy = best[1] + s * pts[k, 0] + c * pts[k, 1]
        v, _, _ = sample(field, (qx - ox) / res - 0.5, (qy - oy) / res - 0.5)
        score += v
    return best, hd, score * inv_n


@njit(cache=True)
def correlative_search(field, ox, oy, res, pts, center, lin_window, lin_step, ang_window, ang_step, w_t, w_r):
    """Best pose on a grid of (dx, dy, dyaw) around `center` by mean nearest-cell score × exp(−w_t·|dt|² − w_r·dyaw²).

    Returns (pose, raw score of that pose).
    """
    h, w = field.shape
    n = pts.shape[0]
    nl = int(round(lin_window / lin_step)) if lin_step > 0 else 0
    na = int(round(ang_window / ang_step)) if ang_step > 0 else 0
    best = center.copy()
    best_val = -1.0
    best_raw = 0.0
    fx = np.empty(n)
    fy = np.empty(n)
    step_c = lin_step / res
    for ia in range(-na, na + 1):
        da = ia * ang_step
        th = center[2] + da
        c = math.cos(th)
        s = math.sin(th)
        for k in range(n):
            fx[k] = (center[0] + c * pts[k, 0] - s * pts[k, 1] - ox) / res
            fy[k] = (center[1] + s * pts[k, 0] + c * pts[k, 1] - oy) / res
        pen_a = w_r * da * da
        for iy in range(-nl, nl + 1):
            dyc = iy * step_c
            for ix in range(-nl, nl + 1):
                dxc = ix * step_c
                acc = 0.0
                for k in range(n):
                    cx = int(math.floor(fx[k] + dxc))
                    cy = int(math.floor(fy[k] + dyc))
                    if cx >= 0 and cy >= 0 and cx < w and cy < h:
                        acc += field[cy, cx]
                raw = acc / max(n, 1)
                dt2 = (ix * lin_step) ** 2 + (iy * lin_step) ** 2
                val = raw * math.exp(-w_t * dt2 - pen_a)
                if val > best_val:
                    best_val = val
                    best_raw = raw
                    best[0] = center[0] + ix * lin_step
                    best[1] = center[1] + iy * lin_step
                    best[2] = _wrap(th)
    return best, best_raw


# ---- branch and bound (loop closure) ---------------------------------------------------------------------------------

@njit(cache=True)
def _build_pyramid(base_u8, depth):
    """levels[h, P + i, P + j] = max of base over rows [i, i + 2^h) × cols [j, j + 2^h) (0 outside); P = 2^(depth−1)."""
    h, w = base_u8.shape
    p = 1 << (depth - 1)
    out = np.zeros((depth, h + p, w + p), np.uint8)
    out[0, p:, p:] = base_u8
    for lvl in range(1, depth):
        s = 1 << (lvl - 1)
        hp = h + p
        wp = w + p
        for i in range(hp):
            for j in range(wp):
                m = out[lvl - 1, i, j]
                if i + s < hp:
                    v = out[lvl - 1, i + s, j]
                    if v > m:
                        m = v
                if j + s < wp:
                    v = out[lvl - 1, i, j + s]
                    if v > m:
                        m = v
                    if i + s < hp:
                        v = out[lvl - 1, i + s, j + s]
                        if v > m:
                            m = v
                out[lvl, i, j] = m
    return out


@njit(cache=True)
def _level_score(pyr, lvl, p, cells, r, ox, oy):
    n = cells.shape[1]
    hp = pyr.shape[1]
    wp = pyr.shape[2]
    acc = 0
    for k in range(n):
        i = cells[r, k, 1] + oy + p
        j = cells[r, k, 0] + ox + p
        if i >= 0 and j >= 0 and i < hp and j < wp:
            acc += pyr[lvl, i, j]
    return acc / (255.0 * max(n, 1))


@njit(cache=True)
def branch_and_bound(pyr, cells, wx, wy, min_score):
    """Exact best (rotation index, dx, dy) in cells over offsets [−wx, wx] × [−wy, wy] with score > min_score.

    `cells[r, k] = (col, row)` of point k under rotation r with no offset. Depth-first branch and bound on
    the max pyramid (Hess et al. 2016, Alg. 3): a block's score at level h bounds every offset inside it.
    Returns (r, dx, dy, score); r = −1 when nothing beats min_score.
    """
    return branch_and_bound_excluding(pyr, cells, wx, wy, min_score, -1, 0, 0, 0, 0)


@njit(cache=True)
def branch_and_bound_excluding(pyr, cells, wx, wy, min_score, er, ex, ey, rad_xy, rad_r):
    """branch_and_bound where leaves within `rad_xy` cells (Chebyshev, in x and y) of (ex, ey) and `rad_r`
    rotation steps of `er` do not count: the exact best score outside that neighbourhood (backend/ambiguity.py's
    rival peak). A block's bound still covers the leaves it holds outside it, so the search stays exact.
    `er` < 0 excludes nothing."""
    depth = pyr.shape[0]
    p = 1 << (depth - 1)
    top = depth - 1
    step = 1 << top
    nr = cells.shape[0]
    nx = (2 * wx) // step + 1
    ny = (2 * wy) // step + 1
    ntop = nr * nx * ny
    cap = ntop + 8 * depth + 8
    st_l = np.empty(cap, np.int64)
    st_r = np.empty(cap, np.int64)
    st_x = np.empty(cap, np.int64)
    st_y = np.empty(cap, np.int64)
    st_s = np.empty(cap, np.float64)
    # top level, pushed in ascending score so the best is popped first
    tr = np.empty(ntop, np.int64)
    tx = np.empty(ntop, np.int64)
    ty = np.empty(ntop, np.int64)
    ts = np.empty(ntop, np.float64)
    q = 0
    for r in range(nr):
        for a in range(nx):
            for b in range(ny):
                ox = -wx + a * step
                oy = -wy + b * step
                tr[q] = r
                tx[q] = ox
                ty[q] = oy
                ts[q] = _level_score(pyr, top, p, cells, r, ox, oy)
                q += 1
    order = np.argsort(ts)
    sp = 0
    for t in range(ntop):
        i = order[t]
        if ts[i] > min_score:
            st_l[sp] = top
            st_r[sp] = tr[i]
            st_x[sp] = tx[i]
            st_y[sp] = ty[i]
            st_s[sp] = ts[i]
            sp += 1
    best = min_score
    br = -1
    bx = 0
    by = 0
    cs = np.empty(4, np.float64)
    cx = np.empty(4, np.int64)
    cy = np.empty(4, np.int64)
    while sp > 0:
        sp -= 1
        lvl = st_l[sp]
        sc = st_s[sp]
        if sc <= best:
            continue
        r = st_r[sp]
        ox = st_x[sp]
        oy = st_y[sp]
        if lvl == 0:
            if er >= 0 and abs(ox - ex) <= rad_xy and abs(oy - ey) <= rad_xy and abs(r - er) <= rad_r:
                continue
            best = sc
            br = r
            bx = ox
            by = oy
            continue
        half = 1 << (lvl - 1)
        m = 0
        for a in range(2):
            for b in range(2):
                x2 = ox + a * half
                y2 = oy + b * half
                if x2 > wx or y2 > wy:
                    continue
                cx[m] = x2
                cy[m] = y2
                cs[m] = _level_score(pyr, lvl - 1, p, cells, r, x2, y2)
                m += 1
        # push in ascending order of score
        for _ in range(m):
            lo = -1
            for u in range(m):
                if cs[u] >= 0.0 and (lo < 0 or cs[u] < cs[lo]):
                    lo = u
            if cs[lo] > best:
                st_l[sp] = lvl - 1
                st_r[sp] = r
                st_x[sp] = cx[lo]
                st_y[sp] = cy[lo]
                st_s[sp] = cs[lo]
                sp += 1
            cs[lo] = -1.0
    return br, bx, by, best


@njit(cache=True)
def rotated_cells(pts, cx, cy, angles, ox, oy, res):
    """cells[r, k] = (col, row) of point k rotated by angles[r] and translated by (cx, cy)."""
    nr = angles.shape[0]
    n = pts.shape[0]
    out = np.empty((nr, n, 2), np.int64)
    for r in range(nr):
        c = math.cos(angles[r])
        s = math.sin(angles[r])
        for k in range(n):
            out[r, k, 0] = int(math.floor((cx + c * pts[k, 0] - s * pts[k, 1] - ox) / res))
            out[r, k, 1] = int(math.floor((cy + s * pts[k, 0] + c * pts[k, 1] - oy) / res))
    return out


class SearchGrids:
    """The max pyramid of a likelihood field for `branch_and_bound` (uint8, built once per submap)."""

    def __init__(self, field: LikelihoodField, depth: int = 6) -> None:
        self.field = field
        self.depth = int(depth)
        base = np.clip(np.round(field.values * 255.0), 0, 255).astype(np.uint8)
        self.pyramid = _build_pyramid(base, self.depth)

    @property
    def nbytes(self) -> int:
        return int(self.pyramid.nbytes)

    def search(self, points: np.ndarray, center, lin_window: float, ang_window: float, min_score: float,
               ang_step: float | None = None, max_range: float = 10.0) -> tuple[np.ndarray | None, float]:
        """Best pose within ±lin_window (m) and ±ang_window (rad) of `center` whose score exceeds min_score.

        The angular step makes a point at the farthest range (at most `max_range`) move about one cell
        (Hess et al. 2016, eq. 7); farther points move more per step, which the refinement absorbs.
        Returns (pose or None, score).
        """
        f = self.field
        res = f.resolution
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if len(pts) == 0:
            return None, 0.0
        if ang_step is None:
            dmax = min(float(np.sqrt((pts ** 2).sum(axis=1)).max()), max_range)
            ang_step = math.acos(max(-1.0, 1.0 - res * res / (2.0 * max(dmax, res) ** 2)))
        na = int(math.ceil(ang_window / ang_step))
        angles = center[2] + np.arange(-na, na + 1) * ang_step
        cells = rotated_cells(pts, float(center[0]), float(center[1]), angles, f.origin[0], f.origin[1], res)
        wcells = int(math.ceil(lin_window / res))
        r, dx, dy, score = branch_and_bound(self.pyramid, cells, wcells, wcells, float(min_score))
        if r < 0:
            return None, float(score)
        pose = np.array([center[0] + dx * res, center[1] + dy * res, angles[r]])
        pose[2] = (pose[2] + np.pi) % (2 * np.pi) - np.pi
        return pose, float(score)


@njit(cache=True)
def inlier_fraction(field, ox, oy, res, pts, pose, threshold):
    """Share of points whose bilinear field value at pose exceeds threshold (exp(−½) = within 1σ of the map)."""
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    good = 0
    n = pts.shape[0]
    for k in range(n):
        qx = pose[0] + c * pts[k, 0] - s * pts[k, 1]
        qy = pose[1] + s * pts[k, 0] + c * pts[k, 1]
        v, _, _ = sample(field, (qx - ox) / res - 0.5, (qy - oy) / res - 0.5)
        if v > threshold:
            good += 1
    return good / max(n, 1)


def translation_information(h: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Eigenvalues (smallest, largest) of the translational information with yaw marginalised out (the Schur
    complement H_tt − H_tθ H_θθ⁻¹ H_θt of a match's 3×3 Gauss–Newton information), and the weakest direction."""
    h = np.asarray(h, dtype=float)
    htt = h[:2, :2]
    if h[2, 2] > 1e-12:
        htt = htt - np.outer(h[:2, 2], h[2, :2]) / h[2, 2]
    w, v = np.linalg.eigh(0.5 * (htt + htt.T))
    return float(max(w[0], 0.0)), float(max(w[1], 0.0)), v[:, 0]
