"""Does the map agree with itself? A self-consistency figure of a SLAM run, without ground truth.

Where the robot comes back to a place (a keyframe more than REVISIT_S after an earlier one that saw the same
walls), its scan, placed at its solved pose, should lie on the earlier scans' walls. A bent map puts them beside
each other. The figure is the point-to-line distance from each revisiting scan point to the earlier points (the line
through its two nearest earlier neighbours, as in point-to-line ICP, Censi 2008), for the points with an earlier
neighbour within REVISIT_RADIUS: per keyframe the median, over the run the median and 90th percentile, and the
worst stretch. Beside it: the loop factors' residuals after the solve (a loop the solution disagrees with).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from kosmap.frontend import se2

REVISIT_S = 30.0  # a scan is compared with the scans taken at least this long before it
REVISIT_RADIUS = 0.5  # m: a point with no earlier point this near sees something new (not compared)
MIN_POINTS = 20  # a keyframe is a revisit when at least this many of its points have an earlier neighbour
# A consistent map puts a revisit a median 0.01–0.03 m off (range noise and the walls' roughness; the simulated office
# and the synthetic ring); one bent by a wrong loop or uncorrected drift puts it 0.1 m and more off.
BENT_MEDIAN_M = 0.03
BENT_P90_M = 0.10
# Or when the solution disagrees with many of its own loops: at least this share of them (and 3) off by more than
# twice the loop factor's σ (a consistent synthetic ring: none of 114; a wrong loop without a robust kernel: 19 %).
BENT_LOOP_SHARE = 0.10
KEEP_POINTS = 96  # points kept per keyframe for the check (every k-th of the scan)


@dataclass
class Consistency:
    revisit_keyframes: int  # keyframes that saw walls seen REVISIT_S or more before
    keyframes: int
    median_m: float  # median over revisit keyframes of their median point-to-line distance (nan: no revisit)
    p90_m: float
    worst_m: float  # the worst keyframe's
    worst_t_s: float  # its time (s from the first scan)
    loops: int
    loop_residual_median_m: float
    loop_residual_max_m: float
    loops_disagreeing: int  # loops the solution misses by more than twice their σ
    bent: bool

    def as_dict(self) -> dict:
        return asdict(self)


def keep_points(points: np.ndarray, n: int = KEEP_POINTS) -> np.ndarray:
    """At most `n` of a scan's points, evenly through the scan (float32): what the check keeps per keyframe."""
    p = np.asarray(points, np.float32)
    return p[:: max(1, math.ceil(len(p) / n))].copy()


def consistency(key_t_s: np.ndarray, key_poses: np.ndarray, key_points: list[np.ndarray],
                loop_residuals: list[float] | None = None, loop_sigma: float = 0.05) -> Consistency:
    """The figure for keyframes at times `key_t_s` (s), solved poses `key_poses` (N×3) and their kept points
    (base_link); `loop_residuals`: the loops' translation residuals (m) after the solve."""
    t = np.asarray(key_t_s, float)
    world = [se2.transform_points(p, np.asarray(q, float)) for p, q in zip(key_poses, key_points)]
    per_kf = np.full(len(t), np.nan)
    order = np.argsort(t)
    tree, tree_until = None, -1
    for i in order:
        if len(world[i]) == 0:
            continue
        n_old = int(np.searchsorted(t[order], t[i] - REVISIT_S, side="right"))  # keyframes at least REVISIT_S older
        if n_old < 2:
            continue
        if tree is None or n_old - tree_until >= 25:  # rebuilt as the earlier part grows (25 keyframes ≈ 5 m)
            old = [world[j] for j in order[:n_old] if len(world[j])]
            pts = np.vstack(old) if old else np.zeros((0, 2))
            tree, tree_until = (cKDTree(pts), n_old) if len(pts) >= 2 else (None, -1)
        if tree is None:
            continue
        d, idx = tree.query(world[i], k=2, distance_upper_bound=REVISIT_RADIUS)
        ok = np.isfinite(d[:, 1])
        if ok.sum() < MIN_POINTS:
            continue
        per_kf[i] = float(np.median(_to_line(world[i][ok], tree.data[idx[ok, 0]], tree.data[idx[ok, 1]])))
    rv = per_kf[np.isfinite(per_kf)]
    res = np.asarray(loop_residuals or [], float)
    if len(rv):
        med, p90 = float(np.median(rv)), float(np.percentile(rv, 90))
        w = int(np.nanargmax(per_kf))
        worst, worst_t = float(per_kf[w]), float(t[w] - t.min())
    else:
        med = p90 = worst = worst_t = float("nan")
    off = int(np.sum(res > 2 * loop_sigma))
    bent = bool((len(rv) >= 5 and (med > BENT_MEDIAN_M or p90 > BENT_P90_M))
                or (off >= 3 and off >= BENT_LOOP_SHARE * len(res)))
    return Consistency(int(len(rv)), int(len(t)), med, p90, worst, worst_t, int(len(res)),
                       float(np.median(res)) if len(res) else float("nan"), float(res.max()) if len(res) else float("nan"),
                       off, bent)


def _to_line(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from each p to the line through a and b (to a itself where a and b nearly coincide)."""
    ab = b - a
    L = np.linalg.norm(ab, axis=1)
    ap = p - a
    cross = np.abs(ab[:, 0] * ap[:, 1] - ab[:, 1] * ap[:, 0]) / np.maximum(L, 1e-9)
    return np.where(L > 0.02, cross, np.linalg.norm(ap, axis=1))


def warning(c: Consistency) -> str | None:
    """The console/report line when the map is likely bent, else None."""
    if not c.bent:
        return None
    loops = (f"; the solution misses {c.loops_disagreeing} of its {c.loops} loops by more than twice their σ"
             if c.loops_disagreeing else "")
    return (f"the map is likely bent: where the robot came back, its scans lie a median {c.median_m:.3f} m "
            f"(90 % within {c.p90_m:.2f} m) off the earlier ones, the worst {c.worst_m:.2f} m at t = {c.worst_t_s:.0f} s "
            f"(a consistent map: a few mm to cm){loops}")
