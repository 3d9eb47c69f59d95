"""Map comparison: robust rigid alignment of two occupancy grids, then precision, recall, F1 and distances.

A (the map under test) is aligned to B (the reference: another map or a blueprint) in two steps:
  1. a global search over every rotation (a sweep in `sweep_step_deg` steps): for each angle, the best
     translation by FFT cross-correlation of A's rotated occupied cells with a likelihood field
     exp(−d²/2σ²) of B's distance transform (the correlative matching of Olson, "Real-time correlative
     scan matching", ICRA 2009, done over the whole map), on a coarse lattice;
  2. trimmed point-to-point ICP (Besl & McKay 1992; closed-form 2D Kabsch step) from the best few
     candidates, with a shrinking correspondence distance, on the occupied cell centres at full resolution.
Metrics are then computed on one canvas (B's frame, the finer of the two resolutions) onto which both
maps are resampled, so maps of different resolutions and sizes compare cell area for cell area:
  - wall cells: occupancy ≥ occupied_thresh and (walls = "surface") free space among the 8 neighbours;
  - precision(tol): fraction of A's wall cells with a B wall cell within tol (centre to centre); recall(tol):
    the same from B to A; F1 their harmonic mean;
  - coverage(tol): fraction of B's wall faces that A saw: within tol of space both maps call free (a run that
    drove past a room's closed side never saw it, and a 15 cm wall's far face is not seen from the corridor);
    recall_observed(tol) and f1_observed(tol): recall and F1 over those faces only (what A got right of what it
    saw), the fair score of a partial exploration; F1 itself scores A against the whole of B;
  - distances A→B and B→A: mean and median distance from each wall cell to the other map's nearest one;
  - free space, over the cells both maps decide (free: occupancy < free_thresh, or a wall): agreement of
    the labels, IoU of the free cells, and the fraction of A's free cells that lie on B's walls.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import fft as sfft
from scipy.spatial import cKDTree

from kosmap.frontend.errors import KosmapError
from kosmap.frontend.params import StageConfig, param
from kosmap.mapping.grid import OccupancyGrid


@dataclass
class CompareConfig(StageConfig):
    """[compare]: tolerances of the occupied-cell match, cell labels, and the alignment search."""

    section = "compare"
    tolerances: list = param([0.05, 0.10, 0.20], lo=0.0, lo_open=True, doc="match tolerances", unit="m")
    align: bool = param(True, doc="align A to B before scoring")
    occupied_thresh: float = param(0.65, lo=0.0, hi=1.0, doc="a cell with occupancy ≥ this is a wall (map_server's occupied_thresh)")
    free_thresh: float = param(0.5, lo=0.0, hi=1.0, doc="a known cell with occupancy < this is free space")
    walls: str = param("surface", choices=("surface", "all"), doc="wall cells scored: those next to free space (what a range sensor sees of a thick wall) or all occupied cells")
    blueprint_dark: float = param(0.5, lo=0.0, hi=1.0, lo_open=True, doc="blueprint pixels darker than this fraction of white are walls")
    sweep_step_deg: float = param(2.0, lo=0.1, hi=15.0, doc="rotation step of the global alignment search", unit="deg")
    coarse_resolution: float = param(0.0, lo=0.0, doc="lattice of the global search (0 = automatic: ≥ 0.15 m, ≤ 150 cells across)", unit="m")
    candidates: int = param(4, lo=1, hi=20, doc="best rotations of the global search refined by ICP")
    max_points: int = param(20000, lo=100, doc="occupied cells of A used by ICP (a seeded random subset beyond this)")
    seed: int = param(0, lo=0, doc="seed of the ICP subset")
    max_canvas_cells: int = param(16_000_000, lo=10_000, doc="the scoring canvas coarsens (×1.5 steps) beyond this many cells (~100 B each)")


class CompareError(KosmapError):
    """Maps that cannot be compared (e.g. one has no walls)."""


# ---- geometry ---------------------------------------------------------------------------------------------------

def se2(x: float, y: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def apply(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ T[:2, :2].T + T[:2, 2]


def occupied(grid: OccupancyGrid, cfg: CompareConfig) -> np.ndarray:
    """Mask of wall cells: occupancy ≥ occupied_thresh."""
    return grid.data.astype(np.int16) >= round(100 * cfg.occupied_thresh)


def free(grid: OccupancyGrid, cfg: CompareConfig) -> np.ndarray:
    """Mask of free cells: known and occupancy < free_thresh."""
    d = grid.data.astype(np.int16)
    return (d >= 0) & (d < 100 * cfg.free_thresh)


def wall_mask(data: np.ndarray, cfg: CompareConfig) -> np.ndarray:
    """The wall cells that are scored and aligned: every occupied cell (walls = "all"), or those with free
    space among their 8 neighbours (walls = "surface": a range sensor sees only a wall's faces, so a
    blueprint's 15 cm wall counts by its faces, not its inside, nor its face towards the unknown outside).
    A map without any free space keeps all its occupied cells."""
    import cv2

    d = data.astype(np.int16)
    occ = d >= round(100 * cfg.occupied_thresh)
    if cfg.walls == "all":
        return occ
    fr = (d >= 0) & (d < 100 * cfg.free_thresh)
    if not fr.any():
        return occ
    return occ & (cv2.dilate(fr.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)


def occupied_points(grid: OccupancyGrid, cfg: CompareConfig) -> np.ndarray:
    """Map coordinates (N×2) of the centres of the wall cells (see wall_mask)."""
    rows, cols = np.nonzero(wall_mask(grid.data, cfg))
    return grid.world_of(cols, rows)


@dataclass
class Alignment:
    """The rigid transform taking A's map frame into B's: p_B = R(yaw)·p_A + (x, y)."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    inliers: float = float("nan")  # fraction of A's wall cells within 2 cells of B's after alignment
    rms: float = float("nan")  # RMS distance of those inliers (m)
    coarse_score: float = float("nan")
    ms: float = 0.0
    aligned: bool = False

    @property
    def matrix(self) -> np.ndarray:
        return se2(self.x, self.y, self.yaw)

    def as_dict(self) -> dict:
        def num(v: float) -> float | None:  # JSON has no NaN
            return float(v) if np.isfinite(v) else None

        return {"aligned": self.aligned, "x": self.x, "y": self.y, "yaw_deg": float(np.degrees(self.yaw)),
                "inliers": num(self.inliers), "rms": num(self.rms), "coarse_score": num(self.coarse_score), "ms": self.ms}


def _kabsch(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Least-squares rigid 2D transform taking p onto q (closed form)."""
    pm, qm = p.mean(axis=0), q.mean(axis=0)
    h = (p - pm).T @ (q - qm)
    th = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = np.cos(th), np.sin(th)
    r = np.array([[c, -s], [s, c]])
    return se2(*(qm - r @ pm), th)


def line_normals(pts: np.ndarray, tree: cKDTree, radius: float) -> np.ndarray:
    """Unit normals of the local wall line at each point (PCA of its neighbours within `radius`)."""
    nb = tree.query_ball_point(pts, radius)
    cnt = np.array([len(n) for n in nb])
    idx = np.concatenate(nb).astype(np.int64)
    owner = np.repeat(np.arange(len(pts)), cnt)
    q = tree.data[idx] - pts[owner]
    sxx = np.bincount(owner, q[:, 0] * q[:, 0], len(pts))
    sxy = np.bincount(owner, q[:, 0] * q[:, 1], len(pts))
    syy = np.bincount(owner, q[:, 1] * q[:, 1], len(pts))
    th = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # direction of the largest spread = the wall's direction
    return np.column_stack((-np.sin(th), np.cos(th)))


def icp(a: np.ndarray, tree: cKDTree, T: np.ndarray, schedule: list[float], normals: np.ndarray | None = None,
        iters: int = 30) -> np.ndarray:
    """Trimmed ICP (correspondences beyond the stage's distance are dropped): point-to-point, or
    point-to-line (Chen & Medioni 1992; linearised in the angle) when B's wall normals are given."""
    for dmax in schedule:
        for _ in range(iters):
            pa = apply(T, a)
            d, j = tree.query(pa, distance_upper_bound=dmax)
            ok = np.isfinite(d)
            if ok.sum() < 3:
                break
            p, q = pa[ok], tree.data[j[ok]]
            if normals is None:
                dT = _kabsch(p, q)
            else:
                n = normals[j[ok]]
                c = p.mean(axis=0)  # rotate about the centroid: better conditioned
                pc = p - c
                J = np.column_stack((n[:, 0], n[:, 1], n[:, 1] * pc[:, 0] - n[:, 0] * pc[:, 1]))
                r = np.einsum("ij,ij->i", n, q - p)
                x = np.linalg.lstsq(J.T @ J + 1e-9 * np.eye(3), J.T @ r, rcond=None)[0]
                R = se2(0.0, 0.0, x[2])
                dT = se2(*(c + x[:2] - R[:2, :2] @ c), x[2])
            T = dT @ T
            if np.hypot(*dT[:2, 2]) < 1e-5 and abs(np.arctan2(dT[1, 0], dT[0, 0])) < 1e-6:
                break
    return T


def _coarse_lattice(pts: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """Unique coarse cells (N×2 int) of points and the lattice's lower-left corner."""
    lo = np.floor(pts.min(axis=0) / res) * res
    return np.unique(np.floor((pts - lo) / res).astype(np.int64), axis=0), lo


def global_search(a: np.ndarray, b: np.ndarray, res: float, step_deg: float, keep: int) -> list[tuple[float, np.ndarray]]:
    """Every rotation in `step_deg` steps, each with its best translation by FFT correlation with B's
    likelihood field: the `keep` best (score, A→B transform) with distinct rotations."""
    import cv2

    bc, blo = _coarse_lattice(b, res)
    hb, wb = bc[:, 1].max() + 1, bc[:, 0].max() + 1
    ac = (np.unique(np.floor(a / res).astype(np.int64), axis=0) + 0.5) * res  # A's walls, one point per coarse cell
    ca = ac.mean(axis=0)
    rad = np.hypot(*(ac - ca).T).max()
    m = int(np.ceil(rad / res)) + 2
    H, W = sfft.next_fast_len(int(hb + 4 * m)), sfft.next_fast_len(int(wb + 4 * m))
    occ = np.ones((H, W), np.uint8)
    occ[bc[:, 1] + 2 * m, bc[:, 0] + 2 * m] = 0
    d = cv2.distanceTransform(occ, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    sigma = 1.5  # cells of the coarse lattice
    field_ = np.exp(-(d ** 2) / np.float32(2 * sigma * sigma)).astype(np.float32)
    # one thread per transform: these ~300 × 230 FFTs gained no wall time from threads on 2 cores and cost ~40 % more
    # CPU (a 10-minute office map: 0.42 vs 0.62-0.71 CPU s a search), which the build's other processes need
    Fb = np.conj(sfft.rfft2(field_, workers=1))
    results = []
    angles = np.radians(np.arange(0.0, 360.0, step_deg))
    for th in angles:
        c, s = np.cos(th), np.sin(th)
        q = (ac - ca) @ np.array([[c, s], [-s, c]])
        u = np.floor(q / res).astype(np.int64) + m
        img = np.bincount(u[:, 1] * W + u[:, 0], minlength=H * W).reshape(H, W).astype(np.float32)
        corr = sfft.irfft2(np.conj(Fb * sfft.rfft2(img, workers=1)), s=(H, W), workers=1)
        valid = corr[:hb + 2 * m + 1, :wb + 2 * m + 1]
        k = int(np.argmax(valid))
        sr, sc = divmod(k, valid.shape[1])
        # A's point p lands at canvas pixel floor(R(p−cA)/res)+m+s, i.e. B's lattice cell that −2m: world below.
        t = blo + (np.array([sc, sr]) - m) * res + np.array([0.0, 0.0])
        T = se2(*(t - np.array([[c, -s], [s, c]]) @ ca), th)
        results.append((float(valid.flat[k]) / len(ac), float(th), T))
    results.sort(key=lambda r: -r[0])
    picked: list[tuple[float, np.ndarray]] = []
    picked_th: list[float] = []
    min_sep = max(np.radians(3 * step_deg), np.radians(6))
    for score, th, T in results:
        if all(abs((th - p + np.pi) % (2 * np.pi) - np.pi) >= min_sep for p in picked_th):
            picked.append((score, T))
            picked_th.append(th)
        if len(picked) == keep:
            break
    return picked


def align(a: OccupancyGrid, b: OccupancyGrid, cfg: CompareConfig | None = None) -> Alignment:
    """Robust rigid alignment of A's walls onto B's from any initial rotation (global search, then ICP)."""
    cfg = cfg or CompareConfig()
    t0 = time.perf_counter()
    pa, pb = occupied_points(a, cfg), occupied_points(b, cfg)
    if len(pa) < 3 or len(pb) < 3:
        raise CompareError(f"map {'A' if len(pa) < 3 else 'B'} has fewer than 3 wall cells: nothing to align")
    if len(pb) > 200_000:  # a fine blueprint: thin B's walls to half the coarser cell, plenty for ICP
        q = max(a.resolution, b.resolution) / 2
        pb = pb[np.unique(np.floor(pb / q).astype(np.int64), axis=0, return_index=True)[1]]
    ext = max(np.ptp(pb, axis=0).max(), np.ptp(pa, axis=0).max())
    res_c = cfg.coarse_resolution or max(0.15, 2 * max(a.resolution, b.resolution), ext / 150.0)
    tree = cKDTree(pb)
    rng = np.random.default_rng(cfg.seed)
    sub = pa if len(pa) <= cfg.max_points else pa[rng.choice(len(pa), cfg.max_points, replace=False)]
    fine = 1.5 * max(a.resolution, b.resolution)
    schedule = [d for d in (4 * res_c, 2 * res_c, res_c, 0.5 * res_c) if d > fine] + [fine]
    normals = line_normals(pb, tree, 2.5 * max(a.resolution, b.resolution))
    best = None
    for score, T0 in global_search(pa, pb, res_c, cfg.sweep_step_deg, cfg.candidates):
        T = icp(sub, tree, T0, schedule[:2])  # point-to-point while far: robust
        T = icp(sub, tree, T, schedule[2:] or schedule[-1:], normals)  # point-to-line near: accurate on walls
        d, _ = tree.query(apply(T, sub), distance_upper_bound=2 * fine)
        ok = np.isfinite(d)
        inl = float(ok.mean())
        rms = float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else float("inf")
        key = (round(inl, 3), -rms)
        if best is None or key > best[0]:
            best = (key, T, score, inl, rms)
    _, T, score, inl, rms = best
    return Alignment(float(T[0, 2]), float(T[1, 2]), float(np.arctan2(T[1, 0], T[0, 0])), inl, rms, score,
                     (time.perf_counter() - t0) * 1e3, True)


# ---- scoring ----------------------------------------------------------------------------------------------------

@dataclass
class Canvas:
    """A lattice in B's frame (axis-aligned) onto which both maps are resampled for scoring."""

    resolution: float
    origin: tuple[float, float]
    width: int
    height: int

    def sample(self, grid: OccupancyGrid, T: np.ndarray, values: np.ndarray | None = None, fill=-1) -> np.ndarray:
        """grid (whose frame maps into B's by T) resampled to the canvas by nearest cell (or `values`, an
        array of the grid's shape); `fill` outside it."""
        values = grid.data if values is None else values
        out = np.full((self.height, self.width), fill, values.dtype)
        M = np.linalg.inv(grid.pixel_to_world()) @ np.linalg.inv(T)  # canvas world → grid (col, row) continuous
        cols = self.origin[0] + (np.arange(self.width) + 0.5) * self.resolution
        for r0 in range(0, self.height, 256):
            rows = self.origin[1] + (np.arange(r0, min(r0 + 256, self.height)) + 0.5) * self.resolution
            X, Y = np.meshgrid(cols, rows)
            u = np.floor(M[0, 0] * X + M[0, 1] * Y + M[0, 2]).astype(np.int64)
            v = np.floor(M[1, 0] * X + M[1, 1] * Y + M[1, 2]).astype(np.int64)
            ok = (u >= 0) & (u < grid.width) & (v >= 0) & (v < grid.height)
            blk = out[r0:r0 + len(rows)]
            blk[ok] = values[v[ok], u[ok]]
        return out


def _corners(grid: OccupancyGrid, T: np.ndarray) -> np.ndarray:
    c = np.array([[0, 0, 1], [grid.width, 0, 1], [0, grid.height, 1], [grid.width, grid.height, 1]], float)
    return (T @ grid.pixel_to_world() @ c.T).T[:, :2]


def make_canvas(a: OccupancyGrid, b: OccupancyGrid, T: np.ndarray, max_cells: int) -> Canvas:
    """The finer resolution over the union of both maps' extents (coarsened if that exceeds max_cells)."""
    pts = np.vstack((_corners(a, T), _corners(b, np.eye(3))))
    res = min(a.resolution, b.resolution)
    if not (np.isfinite(pts).all() and res > 0):  # (NaN extents would coarsen the canvas for ever)
        raise CompareError("a map's origin, resolution or alignment is not a finite number; check the maps' YAML")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    while True:
        w, h = (np.ceil((hi - lo) / res - 1e-9)).astype(int)
        if w * h <= max_cells:
            break
        res *= 1.5
    return Canvas(res, (float(lo[0]), float(lo[1])), int(max(w, 1)), int(max(h, 1)))


@dataclass
class Comparison:
    """Everything `compare` measured, plus the canvas rasters the overlay picture is drawn from."""

    metrics: dict
    canvas: Canvas
    a: np.ndarray = field(repr=False)  # A resampled on the canvas (int8, −1 / 0..100)
    b: np.ndarray = field(repr=False)
    wall_a: np.ndarray = field(repr=False)  # scored wall cells of A on the canvas
    wall_b: np.ndarray = field(repr=False)
    d_to_a: np.ndarray = field(repr=False)  # metres from each canvas cell to A's nearest wall
    d_to_b: np.ndarray = field(repr=False)
    cfg: CompareConfig = field(repr=False)


def _edt(mask: np.ndarray) -> np.ndarray:
    """Euclidean distance (cells) from every cell to the nearest True cell (inf when there is none)."""
    import cv2

    if not mask.any():
        return np.full(mask.shape, np.inf, np.float32)
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _stats(x: np.ndarray) -> dict:
    return {"mean": float(np.mean(x)) if x.size else None, "median": float(np.median(x)) if x.size else None}


def compare(a: OccupancyGrid, b: OccupancyGrid, cfg: CompareConfig | None = None,
            alignment: Alignment | None = None) -> Comparison:
    """Align A to B (unless cfg.align is false or an alignment is given), then score A against B."""
    cfg = cfg or CompareConfig()
    if alignment is None:
        alignment = align(a, b, cfg) if cfg.align else Alignment()
    T = alignment.matrix
    cv = make_canvas(a, b, T, cfg.max_canvas_cells)
    A, B = cv.sample(a, T), cv.sample(b, np.eye(3))
    wallA = cv.sample(a, T, wall_mask(a.data, cfg), False)
    wallB = cv.sample(b, np.eye(3), wall_mask(b.data, cfg), False)
    occ_t, free_t = round(100 * cfg.occupied_thresh), 100 * cfg.free_thresh
    occA, occB = A >= occ_t, B >= occ_t
    freeA, freeB = (A >= 0) & (A < free_t), (B >= 0) & (B < free_t)
    if not wallA.any() or not wallB.any():
        raise CompareError(f"map {'A' if not wallA.any() else 'B'} has no wall cells "
                           f"(occupancy ≥ {cfg.occupied_thresh}) where the maps overlap: nothing to compare")
    r = cv.resolution
    dA, dB = _edt(wallA) * r, _edt(wallB) * r
    dSeen = _edt(freeA & freeB) * r  # metres to space both call free: B's faces that A could have seen
    a2b, b2a = dB[wallA], dA[wallB]
    eps = 1e-6
    per_tol = {}
    for tol in cfg.tolerances:
        p = float(np.mean(a2b <= tol + eps))
        rc = float(np.mean(b2a <= tol + eps))
        seen = dSeen[wallB] <= max(tol, 1.5 * r) + eps
        ro = float(np.mean(b2a[seen] <= tol + eps)) if seen.any() else None
        per_tol[f"{tol:.2f}"] = {"tolerance": tol, "precision": p, "recall": rc,
                                 "f1": 2 * p * rc / (p + rc) if p + rc > 0 else 0.0,
                                 "coverage": float(np.mean(seen)), "recall_observed": ro,
                                 "f1_observed": None if ro is None else (2 * p * ro / (p + ro) if p + ro > 0 else 0.0)}
    definite = (occA | freeA) & (occB | freeB)
    both_free = freeA & freeB & definite
    any_free = (freeA | freeB) & definite
    metrics = {
        "alignment": alignment.as_dict(),
        "canvas": {"resolution": r, "width": cv.width, "height": cv.height, "origin": list(cv.origin)},
        "maps": {"a": {"resolution": a.resolution, "width": a.width, "height": a.height, "origin": list(a.origin),
                       "wall_cells": int(wall_mask(a.data, cfg).sum())},
                 "b": {"resolution": b.resolution, "width": b.width, "height": b.height, "origin": list(b.origin),
                       "wall_cells": int(wall_mask(b.data, cfg).sum())}},
        "tolerances": per_tol,
        "distance_a_to_b": _stats(a2b),
        "distance_b_to_a": _stats(b2a),
        "free": {"agreement": float(np.mean(freeA[definite] == freeB[definite])) if definite.any() else None,
                 "iou": float(both_free.sum() / any_free.sum()) if any_free.any() else None,
                 "a_free_on_b_walls": float(np.mean(occB[freeA])) if freeA.any() else None,
                 "cells_compared": int(definite.sum())},
    }
    return Comparison(metrics, cv, A, B, wallA, wallB, dA, dB, cfg)


# ---- outputs ----------------------------------------------------------------------------------------------------

def overlay_picture(c: Comparison) -> np.ndarray:
    """BGR overlay like the thesis's figures: A's walls red, B's green, agreement (within the smallest
    tolerance) black; occupied cells that are not scored (inside thick walls) pale; free space white,
    unknown grey. Row 0 = top."""
    tol = min(c.cfg.tolerances) + 1e-6
    occ_t, free_t = round(100 * c.cfg.occupied_thresh), 100 * c.cfg.free_thresh
    occA, occB = c.a >= occ_t, c.b >= occ_t
    img = np.full(c.a.shape + (3,), 205, np.uint8)
    free_any = ((c.a >= 0) & (c.a < free_t)) | ((c.b >= 0) & (c.b < free_t))
    img[free_any] = 255
    img[occB] = (170, 225, 170)
    img[occA & ~c.wall_b] = (170, 170, 240)
    img[c.wall_b] = (0, 170, 0)
    img[c.wall_a] = (0, 0, 230)
    img[(c.wall_a & (c.d_to_b <= tol)) | (c.wall_b & (c.d_to_a <= tol))] = 0
    return np.ascontiguousarray(img[::-1])


def metrics_markdown(m: dict, title: str = "Map comparison") -> str:
    """The metrics as a Markdown table (also what the CLI prints)."""
    al = m["alignment"]
    lines = [f"## {title}", ""]
    if al["aligned"]:
        lines.append(f"Alignment A→B: x {al['x']:+.3f} m, y {al['y']:+.3f} m, yaw {al['yaw_deg']:+.2f}°, "
                     f"inliers {al['inliers']:.1%}, RMS {al['rms']:.3f} m ({al['ms']:.0f} ms)")
    else:
        lines.append("Alignment: none (--no-align: the frames are taken to agree)")
    c = m["canvas"]
    lines += [f"Scored on a {c['width']}×{c['height']} canvas at {c['resolution']:.3f} m.", "",
              "| tolerance | precision | recall | F1 | walls seen | recall of seen walls | F1 of seen walls |",
              "|---|---|---|---|---|---|---|"]
    f = lambda v: "–" if v is None else f"{v:.3f}"  # noqa: E731
    for t in m["tolerances"].values():
        lines.append(f"| {t['tolerance']:.2f} m | {t['precision']:.3f} | {t['recall']:.3f} | {t['f1']:.3f} | "
                     f"{t['coverage']:.3f} | {f(t['recall_observed'])} | {f(t.get('f1_observed'))} |")
    ab, ba, fr = m["distance_a_to_b"], m["distance_b_to_a"], m["free"]
    lines += ["", "| distance | mean | median |", "|---|---|---|",
              f"| A walls → nearest B wall | {f(ab['mean'])} m | {f(ab['median'])} m |",
              f"| B walls → nearest A wall | {f(ba['mean'])} m | {f(ba['median'])} m |", "",
              f"Free space: agreement {f(fr['agreement'])}, IoU {f(fr['iou'])}, "
              f"A's free cells on B's walls {f(fr['a_free_on_b_walls'])} ({fr['cells_compared']} cells known in both).", ""]
    return "\n".join(lines)
