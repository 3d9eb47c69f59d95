"""Look-alike rejection for loop closures: the best *distinct* second peak of the branch-and-bound search, and
the match's degenerate directions.

A narrow (70°) depth scan of a corridor wall with a door gap fits many places along the corridor about equally
well; an exact search then returns whichever of those look-alikes scores a hair higher. Two tests catch it:
- ratio test (Lowe 2004, §7.1, for descriptors; Olson 2009, "Recognizing places using spectrally clustered
  local matches", for place recognition): the best score outside a neighbourhood of the best pose, divided by
  the best; near 1 means another place matches as well, so the match says nothing about which;
- degeneracy (Zhang, Kaess & Singh 2016, "On degeneracy of optimization-based state estimation problems"):
  the eigenvalues of the match's Gauss–Newton information on translation (θ marginalised out); a wall alone
  gives none along itself.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from frontend.matcher import _level_score


@njit(cache=True)
def branch_and_bound_excluding(pyr, cells, wx, wy, min_score, er, ex, ey, rad_xy, rad_r):
    """Like frontend.matcher.branch_and_bound (Hess et al. 2016, Alg. 3), but leaves within `rad_xy` cells
    (Chebyshev, in x and y) of (ex, ey) and `rad_r` rotation steps of `er` do not count: the exact best score
    outside that neighbourhood. A block's bound still covers the leaves it holds outside it, so the search
    stays exact. `er` < 0 excludes nothing. Returns (r, dx, dy, score); r = −1 when nothing beats min_score."""
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


def search_two_peaks(grids, points: np.ndarray, center, lin_window: float, ang_window: float, min_score: float,
                     exclude_radius: float, rival_floor=None, max_range: float = 10.0):
    """The best pose (as frontend.matcher.SearchGrids.search) and the best score at least `exclude_radius`
    metres away from it (any rotation). The rival is searched only above `rival_floor(best)`, the score that
    would reject the match (the smaller the window of scores, the more the search prunes); None: no rival search.

    Returns (pose or None, best score, rival score or 0.0 when none beats the floor)."""
    from frontend.matcher import rotated_cells

    f = grids.field
    res = f.resolution
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if len(pts) == 0:
        return None, 0.0, 0.0
    dmax = min(float(np.sqrt((pts ** 2).sum(axis=1)).max()), max_range)
    ang_step = math.acos(max(-1.0, 1.0 - res * res / (2.0 * max(dmax, res) ** 2)))  # Hess et al. 2016, eq. 7
    na = int(math.ceil(ang_window / ang_step))
    angles = center[2] + np.arange(-na, na + 1) * ang_step
    cells = rotated_cells(pts, float(center[0]), float(center[1]), angles, f.origin[0], f.origin[1], res)
    w = int(math.ceil(lin_window / res))
    r, dx, dy, best = branch_and_bound_excluding(grids.pyramid, cells, w, w, float(min_score), -1, 0, 0, 0, 0)
    if r < 0:
        return None, float(best), 0.0
    pose = np.array([center[0] + dx * res, center[1] + dy * res, angles[r]])
    pose[2] = (pose[2] + np.pi) % (2 * np.pi) - np.pi
    floor = None if rival_floor is None else rival_floor(best)
    if floor is None or floor >= best:
        return pose, float(best), 0.0
    rad = int(math.ceil(exclude_radius / res))
    r2, _, _, second = branch_and_bound_excluding(grids.pyramid, cells, w, w, float(max(min_score, floor)),
                                                  r, dx, dy, rad, len(angles))
    return pose, float(best), float(second) if r2 >= 0 else 0.0


def translation_information(h: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Eigenvalues (smallest, largest) of the translational information with yaw marginalised out (the Schur
    complement H_tt − H_tθ H_θθ⁻¹ H_θt of a match's 3×3 Gauss–Newton information), and the weakest direction."""
    h = np.asarray(h, dtype=float)
    htt = h[:2, :2]
    if h[2, 2] > 1e-12:
        htt = htt - np.outer(h[:2, 2], h[2, :2]) / h[2, 2]
    w, v = np.linalg.eigh(0.5 * (htt + htt.T))
    return float(max(w[0], 0.0)), float(max(w[1], 0.0)), v[:, 0]
