"""Does the map agree with itself? A self-consistency figure of a SLAM run, without ground truth.

Where the robot comes back to a place (a keyframe more than REVISIT_S after an earlier one that saw the same
walls, from the same side), its scan, placed at its solved pose, should lie on the earlier scans' walls. A bent map
puts them beside each other. Per revisiting keyframe the figure is how far its points must move, as one rigid body,
onto the earlier scans' segments they project onto (two consecutive points of one earlier scan; one damped
point-to-line ICP step, Censi 2008), for the points within REVISIT_RADIUS of such a segment (where the views
overlap); over the run the median and 90th percentile, and the worst keyframe's time. Beside it: the loop factors'
residuals after the solve (loops the solution disagrees with).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import binom

from kosmap.frontend import se2

REVISIT_S = 30.0  # a scan is compared with the scans taken at least this long before it
REVISIT_RADIUS = 0.5  # m: a point with no earlier point this near sees something new (not compared)
MIN_POINTS = 20  # a keyframe is a revisit when at least this many of its points have an earlier neighbour
# A map is called bent when the walls it saw twice are doubled by more than its grid can hide, beyond what the scans'
# own noise lets one rigid step resolve. Per revisiting keyframe the misfit (how much of its misalignment to the earlier
# walls one point-to-line ICP step explains; only the directions its walls fix count) is set against its tolerance: a
# grid cell (the run's [grid] resolution, `cell`; CELL_M, its default, when none is given) plus the misfit the rigid
# step finds in the points' noise alone, at 99 % (χ² with 3 degrees of freedom, NOISE_CHI2): σ·√(NOISE_CHI2 / n) for n
# compared points whose scatter about their lines is σ (the new scan's and the earlier ones', each measured on the scan
# itself, `scan_noise`: a narrow depth scan's noise grows with range², a laser's is ~1 cm). The map is bent when the
# revisits refute a consistent map's: at least half within their tolerance and nine in ten within BENT_P90_CELLS
# tolerances (a stretch of the run placed wrong), by a sign test on their count (revisit_verdict); too few revisits to
# refute the median are "too few to tell", not a verdict. Measured: good maps of the simulated office (KOS and laser,
# ATE 0.02–0.09 m) median 0.004–0.04 m, 90 % 0.01–0.08 m, but for one (ATE 0.077 m) whose revisits the truth shows
# 0.09 m apart, called bent; bent by odometry alone (loop closure, gyro and wall headings off; ATE 0.12–0.54 m)
# median 0.14–0.31 m, 90 % 0.27–0.37 m (docs/consistency.md).
CELL_M = 0.05  # m: the default [grid] resolution, when the run's is not given
NOISE_CHI2 = 11.34  # χ²₃ at 99 %: the rigid step's three parameters fitted to noise
BENT_P90_CELLS = 3.0  # the worst tenth: three tolerances (a wall doubled by three grid cells over a stretch)
# Or when the solution disagrees with more of its own loops than chance allows: each loop is missed when the
# solution is off it by more than its own covariance allows (the loop factor's, as the graph holds it: loose along a
# corridor's axis where the match did not fix it) at 99 % (χ² with 2 degrees of freedom on the translation,
# LOOP_CHI2), so a consistent map misses 1 % of its true loops; bent when at least 3 are missed and that many misses
# have a chance below LOOP_P (binomial tail) under that 1 %. A consistent synthetic ring: none of 102; a wrong loop
# under a plain Gaussian kernel: 8 of 102 (p ≈ 1e-4).
LOOP_P = 0.01
# Or when the front end could not follow the scans: a match scoring below 0.6 × its running mean is re-searched over a
# wide window (frontend/odometry.py, the recovery); a consistent run needs that at a slip or a stall of the odometry,
# on at most 0.5 % of its matches (Intel 0.45 %, FR079 0.06 %, CSAIL 0.5 %, five of the six unscored real logs
# 0–0.16 %), while consecutive scans that overlap too little to be matched (Örebro's CARMEN log: scans 1–3 m apart)
# need it on 24 %, and its map is then wrong where no revisit can show it. Ten times the worst of the consistent runs:
RECOVERY_SHARE = 0.05
LOOP_CHI2 = 9.21  # χ²₂ at 99 %
# The revisits' verdict needs evidence: a sign test of their count beyond the tolerance (revisit_verdict) at this level,
# the loops' level: a narrow scan's few revisits (3-7 on a two-minute run) decide nothing by their median alone.
REVISIT_P = 0.01
SEGMENT_K = 4  # a point is compared with the earlier scans' segments at its this many nearest earlier points (_segment)
KEEP_POINTS = 96  # points kept per keyframe for the check (every k-th of the scan)


@dataclass
class Consistency:
    revisit_keyframes: int  # keyframes that saw walls seen REVISIT_S or more before
    keyframes: int
    median_m: float  # median over revisit keyframes of their misalignment (nan: no revisit)
    p90_m: float
    worst_m: float  # the worst keyframe's
    worst_t_s: float  # its time (s from the first scan)
    loops: int
    loop_residual_median_m: float
    loop_residual_max_m: float
    loops_disagreeing: int  # loops the solution misses by more than their covariance allows (99 %), the scans agreeing
    bent: bool
    tolerance_m: float = float("nan")  # the median revisit's tolerance: a grid cell + what the scans' noise hides
    scan_noise_m: float = float("nan")  # the median keyframe's scatter about its own lines (scan_noise)
    loops_refuted: int = 0  # loops missed where the later keyframe's scan fits the earlier ones: false loops left out
    recovery_share: float = 0.0  # share of the front end's matches it re-searched over a wide window (frontend_unsure)
    too_few: bool = False  # revisits seen, but too few for a verdict (revisit_verdict): "too few revisits to tell"

    def frontend_unsure(self, recoveries: int, matches: int) -> None:
        """Record the front end's wide re-searches; above RECOVERY_SHARE of its matches the map is likely wrong."""
        self.recovery_share = recoveries / matches if matches > 0 else 0.0
        self.bent = self.bent or self.recovery_share > RECOVERY_SHARE

    def as_dict(self) -> dict:
        return asdict(self)


def keep_points(points: np.ndarray, n: int = KEEP_POINTS) -> np.ndarray:
    """At most `n` of a scan's points, evenly through the scan (float32): what the check keeps per keyframe."""
    p = np.asarray(points, np.float32)
    return p[:: max(1, math.ceil(len(p) / n))].copy()


@dataclass
class LoopCheck:
    """One loop factor after the solve: how far the solution is from it (x, y, yaw; pose of the solution's b in the
    loop's measured b), the factor's covariance (3×3, in b's frame) and its later keyframe (-1: unknown)."""

    error: np.ndarray
    cov: np.ndarray
    keyframe: int = -1

    def missed(self) -> bool:
        """The solution misses the loop by more than its own covariance allows (translation, χ²₂ at 99 %)."""
        e = np.asarray(self.error, float)[:2]
        return float(e @ np.linalg.solve(np.asarray(self.cov, float)[:2, :2], e)) > LOOP_CHI2


def loop_checks(graph) -> list[LoopCheck]:
    """The loop factors of a solved backend.graph.PoseGraph, each with its own covariance (the full one the loop
    closer gave, else its σ)."""
    out = []
    for e in graph.edges:
        if e.kind == "loop":
            err = se2.between(e.measurement, se2.between(graph.est[e.a], graph.est[e.b]))
            cov = np.asarray(e.cov, float) if e.cov is not None else np.diag(np.asarray(e.sigmas, float) ** 2)
            out.append(LoopCheck(np.asarray(err, float), cov, max(int(e.a), int(e.b))))
    return out


def consistency(key_t_s: np.ndarray, key_poses: np.ndarray, key_points: list[np.ndarray],
                loops: list[LoopCheck] | None = None, cell: float = CELL_M) -> Consistency:
    """The figure for keyframes at times `key_t_s` (s), solved poses `key_poses` (N×3) and their kept points
    (base_link, in beam order); `loops`: the loop factors after the solve (loop_checks); `cell`: the map's grid cell
    (m, the run's [grid] resolution): walls doubled by less are one wall in the map."""
    t = np.asarray(key_t_s, float)
    world = [se2.transform_points(p, np.asarray(q, float)) for p, q in zip(key_poses, key_points)]
    noise = np.array([scan_noise(q) for q in key_points])
    nz = np.nan_to_num(noise)  # a scan too short to measure: no noise allowance
    per_kf = np.full(len(t), np.nan)
    tol = np.full(len(t), np.nan)
    order = np.argsort(t)
    tree, tree_until = None, -1
    for i in order:
        if len(world[i]) == 0:
            continue
        n_old = int(np.searchsorted(t[order], t[i] - REVISIT_S, side="right"))  # keyframes at least REVISIT_S older
        if n_old < 2:
            continue
        if tree is None or n_old - tree_until >= max(25, tree_until // 10):
            # rebuilt as the earlier part grows (by 25 keyframes ≈ 5 m, or 10 % on a long log: ~70 builds for 5000
            # keyframes instead of 200; the latest 10 % of the earlier keyframes wait for the next build)
            olds = [j for j in order[:n_old] if len(world[j])]
            pts = np.vstack([world[j] for j in olds]) if olds else np.zeros((0, 2))
            seen_from = (np.vstack([np.repeat(np.asarray(key_poses[j][:2], float)[None], len(world[j]), 0) for j in olds])
                         if olds else np.zeros((0, 2)))
            old_noise = np.concatenate([np.full(len(world[j]), nz[j]) for j in olds]) if olds else np.zeros(0)
            nbr = _scan_neighbours([world[j] for j in olds])
            tree, tree_until = (cKDTree(pts), n_old) if len(pts) >= 2 else (None, -1)
        if tree is None:
            continue
        d, idx = tree.query(world[i], k=SEGMENT_K, distance_upper_bound=REVISIT_RADIUS)
        near = np.isfinite(d[:, 0])
        a_, b_, ia, seg = _segment(world[i][near], tree.data, idx[near], nbr)
        keep = np.flatnonzero(near)[seg]  # the points where the earlier scans saw the same stretch of surface
        a_, b_, ia = a_[seg], b_[seg], ia[seg]
        # the same face: both scans saw the wall from the same side (a wall's two faces are its thickness apart)
        same = _same_side(a_, b_, seen_from[ia], np.asarray(key_poses[i][:2], float), world[i][keep])
        if same.sum() < MIN_POINTS:
            continue
        per_kf[i] = _misalignment(world[i][keep][same], a_[same], b_[same], key_poses[i][:2])
        sigma = math.sqrt(nz[i] ** 2 + float(np.median(old_noise[ia][same])) ** 2)
        tol[i] = cell + sigma * math.sqrt(NOISE_CHI2 / int(same.sum()))
    rv = np.isfinite(per_kf)
    checks = list(loops or [])
    res = np.array([math.hypot(*c.error[:2]) for c in checks])
    if rv.any():
        med, p90 = float(np.median(per_kf[rv])), float(np.percentile(per_kf[rv], 90))
        ratio = per_kf[rv] / tol[rv]
        w = int(np.nanargmax(per_kf))
        worst, worst_t = float(per_kf[w]), float(t[w] - t.min())
        med_tol = float(np.median(tol[rv]))
    else:
        med = p90 = worst = worst_t = med_tol = float("nan")
        ratio = np.zeros(0)
    # A missed loop counts against the map unless the map's own scans refute it: the solution is off the loop by less
    # than REVISIT_RADIUS (so were the loop right, the later keyframe's scan would lie that far off the earlier walls,
    # within the check's reach) and that keyframe fits the earlier walls within its tolerance: a false loop the robust
    # kernel rightly left out (on the simulated office, 3 of 15 KOS loops 0.15–0.3 m off a map of ATE 0.03 m whose
    # revisits fit within 3 cm). A miss beyond REVISIT_RADIUS is not refuted: the scan may fit another, similar wall.
    missed = [c for c in checks if c.missed()]
    refuted = sum(1 for c in missed if 0 <= c.keyframe < len(t) and math.hypot(*c.error[:2]) <= REVISIT_RADIUS
                  and per_kf[c.keyframe] <= tol[c.keyframe])
    off = len(missed) - refuted
    chance = float(binom.sf(off - 1, len(checks), 0.01)) if off else 1.0  # this many misses of a consistent map's 1 %
    revisits_bent, decidable = revisit_verdict(ratio)
    bent = bool(revisits_bent or (off >= 3 and chance < LOOP_P))
    return Consistency(int(rv.sum()), int(len(t)), med, p90, worst, worst_t, len(checks),
                       float(np.median(res)) if len(res) else float("nan"), float(res.max()) if len(res) else float("nan"),
                       int(off), bent, med_tol, float(np.nanmedian(noise)) if np.isfinite(noise).any() else float("nan"),
                       int(refuted), too_few=bool(len(ratio) and not decidable and not bent))


def revisit_verdict(ratio: np.ndarray) -> tuple[bool, bool]:
    """Whether the revisits' misfits (each over its tolerance, `ratio`) show a bent map, and whether their count could
    refute the median (fewer: only a gross bend, the worst-tenth test, can show). A consistent map's revisit is within
    its tolerance at least half the time and within BENT_P90_CELLS tolerances nine times in ten; the map is bent when the revisits refute either at REVISIT_P (a sign test: the
    binomial chance of that many revisits beyond it). The median test needs ⌈log₂(1/REVISIT_P)⌉ = 7 revisits, all off;
    the worst-tenth one 3 revisits, all off by more than BENT_P90_CELLS tolerances. Fewer: too few revisits to tell."""
    n = len(ratio)
    if n == 0:
        return False, False
    over = int(np.sum(ratio > 1.0))
    far = int(np.sum(ratio > BENT_P90_CELLS))
    p_med = float(binom.sf(over - 1, n, 0.5)) if over else 1.0
    p_far = float(binom.sf(far - 1, n, 0.1)) if far else 1.0
    decidable = 0.5 ** n < REVISIT_P  # the median test could refute a consistent map: 7 revisits or more
    return bool(p_med < REVISIT_P or p_far < REVISIT_P), decidable


def scan_noise(points: np.ndarray, max_gap: float = REVISIT_RADIUS) -> float:
    """A scan's scatter (m, σ) about its own lines, measured on the scan itself: the second difference of three
    consecutive points (in beam order) across the chord of the outer two is 0 on a straight wall and has variance 6σ²
    from the middle point's and its neighbours' noise; the median absolute value over the scan (corners and edges are
    its outliers), as σ. Triples across a gap over `max_gap` are skipped; nan below 5 triples."""
    p = np.asarray(points, float)
    if len(p) < 7:
        return float("nan")
    chord = p[2:] - p[:-2]
    L = np.linalg.norm(chord, axis=1)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    ok = (np.maximum(step[:-1], step[1:]) <= max_gap) & (L > 1e-6)
    if ok.sum() < 5:
        return float("nan")
    n = np.column_stack((-chord[ok, 1], chord[ok, 0])) / L[ok, None]
    dev = np.einsum("ij,ij->i", p[:-2][ok] - 2 * p[1:-1][ok] + p[2:][ok], n)
    return float(1.4826 * np.median(np.abs(dev)) / math.sqrt(6.0))


def _scan_neighbours(scans: list[np.ndarray]) -> np.ndarray:
    """For the points of `scans` stacked in order: the stacked index of each point's predecessor and successor in its
    own scan (beam order), -1 at a scan's ends and across a gap over REVISIT_RADIUS (another surface)."""
    out = []
    base = 0
    for q in scans:
        n = len(q)
        prev, nxt = np.arange(n) - 1 + base, np.arange(n) + 1 + base
        gap = np.linalg.norm(np.diff(q, axis=0), axis=1) > REVISIT_RADIUS if n > 1 else np.zeros(0, bool)
        prev[0], nxt[-1] = -1, -1
        prev[1:][gap], nxt[:-1][gap] = -1, -1
        out.append(np.column_stack((prev, nxt)))
        base += n
    return np.vstack(out) if out else np.zeros((0, 2), np.int64)


def _segment(p: np.ndarray, pts: np.ndarray, idx: np.ndarray, nbr: np.ndarray):
    """The earlier surface each point p is compared with: a segment of an earlier scan between consecutive points (in
    its beam order) that p projects onto, the nearest such among the segments at p's SEGMENT_K nearest earlier points
    (`idx`, n×k, missing ones = len(pts)): point-to-line ICP's two closest points are consecutive points of the
    reference scan (Censi 2008). A point that projects onto none lies beyond the stretch of surface the earlier scans
    saw (past their end, or round a corner): it is not compared (the views do not overlap there, and its distance to
    the nearest earlier point runs along the surface, not across it). Returns a, b, a's index and which points are
    compared."""
    n = len(p)
    best = np.full(n, np.inf)
    a, b, ia = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n, np.int64)
    for k in range(idx.shape[1]):
        i0 = idx[:, k]
        real = i0 < len(pts)
        i0 = np.where(real, i0, 0)
        a0 = pts[i0]
        for side in (0, 1):
            j = nbr[i0, side]
            has = real & (j >= 0)
            q = pts[np.maximum(j, 0)]
            ab = q - a0
            L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
            u = np.einsum("ij,ij->i", p - a0, ab) / L2
            dist = np.abs(ab[:, 0] * (p[:, 1] - a0[:, 1]) - ab[:, 1] * (p[:, 0] - a0[:, 0])) / np.sqrt(L2)
            take = has & (L2 > 1e-8) & (u >= 0.0) & (u <= 1.0) & (dist < best)
            best[take], a[take], b[take], ia[take] = dist[take], a0[take], q[take], i0[take]
    return a, b, ia, np.isfinite(best)


def _same_side(a: np.ndarray, b: np.ndarray, c_old: np.ndarray, c_new: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Whether the new point p and its earlier neighbours a, b lie on the same face of a surface: the sensor positions
    c_old (each pair's) and c_new on the same side of the line through a and b; where a and b nearly coincide (a wall
    seen by many earlier keyframes, or a narrow scan's dense points) the line has no direction, and the faces are told
    apart by the rays instead: two faces of one wall, each sensor sees its own point in front of the other's. (Taking
    such pairs as the same face compared a wall's two faces: on the simulated office, KOS keyframes a wall thickness,
    0.2 m, off the earlier scans at poses within 2 cm of the truth.)"""
    ab = b - a
    s_old = ab[:, 0] * (c_old[:, 1] - a[:, 1]) - ab[:, 1] * (c_old[:, 0] - a[:, 0])
    s_new = ab[:, 0] * (c_new[1] - a[:, 1]) - ab[:, 1] * (c_new[0] - a[:, 0])
    ap = p - a
    opposite = (np.einsum("ij,ij->i", -ap, p - c_new) > 0) & (np.einsum("ij,ij->i", ap, a - c_old) > 0)
    return np.where(np.linalg.norm(ab, axis=1) <= 0.02, ~opposite, s_old * s_new > 0)


def _misalignment(p: np.ndarray, a: np.ndarray, b: np.ndarray, centre: np.ndarray) -> float:
    """How far (m) the points p must move, as one rigid body about `centre`, to lie on the lines through their earlier
    neighbours a and b: one damped Gauss–Newton step of point-to-line ICP (Censi 2008). The points' own noise and
    spacing average out; a direction the walls do not fix (a corridor's axis) is held at 0 by the damping."""
    ab = b - a
    L = np.linalg.norm(ab, axis=1)
    n = np.column_stack((-ab[:, 1], ab[:, 0])) / np.maximum(L, 1e-9)[:, None]
    ap = p - a
    far = np.linalg.norm(ap, axis=1)
    short = L <= 0.02  # a and b nearly coincide: the normal points from a to p
    n[short] = ap[short] / np.maximum(far[short], 1e-9)[:, None]
    r = np.einsum("ij,ij->i", n, ap)
    lever = p - centre
    J = np.column_stack((n, n[:, 1] * lever[:, 0] - n[:, 0] * lever[:, 1]))
    H = J.T @ J
    H += np.eye(3) * 1e-2 * np.trace(H) / 3
    d = np.linalg.solve(H, -J.T @ r)
    # the size of the residual the rigid move explains (not |δ|: along a corridor's axis a large δ is the points'
    # noise, amplified by the weak information there, and explains next to nothing)
    return float(math.sqrt(max(float(np.mean(r ** 2) - np.mean((r + J @ d) ** 2)), 0.0)))


def warning(c: Consistency) -> str | None:
    """The console/report line when the map is likely bent (or wrong: the front end could not follow), else None."""
    if not c.bent:
        return None
    if c.recovery_share > RECOVERY_SHARE:
        return (f"the map is likely wrong: the scan matcher had to search a wide window on {100 * c.recovery_share:.0f} % of "
                f"its matches (a consistent run: at most {100 * RECOVERY_SHARE / 10:g} %): consecutive scans overlap too little "
                f"to be matched (scans far apart, or odometry that jumps), which a revisit may not show")
    loops = (f"; the solution misses {c.loops_disagreeing} of its {c.loops} loops by more than their covariance allows"
             if c.loops_disagreeing else "")
    return (f"the map is likely bent: where the robot came back, its scans lie a median {c.median_m:.3f} m "
            f"(90 % within {c.p90_m:.2f} m) off the earlier ones, the worst {c.worst_m:.2f} m at t = {c.worst_t_s:.0f} s "
            f"(the tolerance: {c.tolerance_m:.3f} m, a grid cell and what the scans' noise hides){loops}")
