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

from kosmap.frontend.matcher import branch_and_bound, branch_and_bound_excluding, translation_information  # noqa: F401 (re-export)


def search_two_peaks(grids, points: np.ndarray, center, lin_window: float, ang_window: float, min_score: float,
                     exclude_radius: float, rival_floor=None, max_range: float = 10.0):
    """The best pose (as frontend.matcher.SearchGrids.search) and the best score at least `exclude_radius`
    metres away from it (any rotation). The rival is searched only above `rival_floor(best)`, the score that
    would reject the match (the smaller the window of scores, the more the search prunes); None: no rival search.

    Returns (pose or None, best score, rival score or 0.0 when none beats the floor)."""
    from kosmap.frontend.matcher import rotated_cells

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
    r, dx, dy, best = branch_and_bound(grids.pyramid, cells, w, w, float(min_score))
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
