"""Maps of many runs of one building: aligned into one frame, merged, and what changed between them.

1. Alignment: every run's map onto the first run's with the robust alignment of `kosmap compare` (mapping/
   compare.py: a global rotation sweep with FFT correlation, then ICP); with a blueprint, the runs' merged map
   onto the blueprint, and every run with it.
2. One canvas (the reference frame, the finest resolution, the union of the runs' extents) onto which every run
   is resampled by nearest cell (compare.Canvas).
3. Merge: the runs are independent measurements of one static world, so their log-odds add (the occupancy-grid
   update of Thrun, Burgard & Fox, Probabilistic Robotics, eq. 9.7, applied to whole maps): each cell's
   probability, clamped to the grid's [p_min, p_max], becomes log-odds; unknown cells add nothing.
4. Change: a cell occupied in some run and clearly free in another. Clearly free: passed by at least two beams'
   worth of free evidence (probability ≤ the inverse sensor model's p_miss applied twice: a single beam may be a
   dropout, which the grid clears for `no_return_clear` metres, through a wall it did not see), with no occupied
   cell of that same run within `tol` (the alignments' error, at least two cells), so a wall seen one cell aside
   in another run, or a face seen at a grazing angle, is no change. Changed cells are grouped into regions
   (connected after closing gaps of `tol`). A region no longer than 2·`tol` across, or of fewer cells than a
   `tol`-wide square, is dropped: a wall's end seen from two sides, or a face seen one cell off, makes changes of
   that size without anything having moved (so the smallest change reported is 2·`tol` + one cell across:
   0.25 m with 5 cm cells and alignments within 5 cm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kosmap.mapping.compare import Alignment, Canvas, CompareConfig, CompareError, align
from kosmap.mapping.grid import GridConfig, OccupancyGrid


@dataclass
class RunFrame:
    """One run's map placed in the reference frame (its alignment), or why it could not be."""

    name: str
    alignment: Alignment | None
    error: str | None = None
    reference: bool = False  # the run whose map the others are aligned onto


@dataclass
class ChangeRegion:
    """A connected group of changed cells, in the reference frame."""

    x: float  # centroid (m)
    y: float
    area_m2: float
    box: tuple[float, float, float, float]  # axis-aligned extent: x min, y min, x max, y max (m)
    occupied_in: list[str] = field(default_factory=list)  # runs that saw it occupied
    free_in: list[str] = field(default_factory=list)  # runs that saw it clearly free


@dataclass
class Fleet:
    """The merged map and the change map of a set of runs, on one canvas."""

    frames: list[RunFrame]
    canvas: Canvas
    merged: OccupancyGrid
    changes: OccupancyGrid  # 100 changed (in a kept region), 0 seen by some run, −1 never seen
    regions: list[ChangeRegion]
    tolerance_m: float


def align_runs(names: list[str], grids: list[OccupancyGrid], cfg: CompareConfig) -> list[RunFrame]:
    """Each run's alignment onto the first run's map (which keeps its own frame). Runs of one building share its
    furniture, which a blueprint lacks: a short run aligns onto another run where it could fit several corners of
    a bare plan. A run that does not align gets its error and stays out of the merge."""
    frames = [RunFrame(names[0], Alignment(inliers=1.0, rms=0.0, aligned=True), reference=True)]
    for name, g in zip(names[1:], grids[1:]):
        try:
            frames.append(RunFrame(name, align(g, grids[0], cfg)))
        except CompareError as e:
            frames.append(RunFrame(name, None, str(e)))
    return frames


def _merge_on(grids: list[OccupancyGrid], Ts: list[np.ndarray], cfg: CompareConfig,
              gcfg: GridConfig) -> tuple[Canvas, np.ndarray, OccupancyGrid]:
    """The runs on one canvas in the frame the transforms `Ts` lead to: (canvas, stack, merged map)."""
    canvas = union_canvas(grids, Ts, cfg.max_canvas_cells)
    stack = resample(grids, Ts, canvas)
    merged = OccupancyGrid(merge_logodds(stack, gcfg.p_min, gcfg.p_max), canvas.resolution, (*canvas.origin, 0.0))
    return canvas, stack, merged


def union_canvas(grids: list[OccupancyGrid], transforms: list[np.ndarray], max_cells: int) -> Canvas:
    """The finest resolution over the union of the maps' extents in the reference frame (coarsened ×1.5 while it
    holds more than `max_cells`)."""
    corners = []
    for g, T in zip(grids, transforms):
        c = np.array([[0, 0, 1], [g.width, 0, 1], [0, g.height, 1], [g.width, g.height, 1]], float)
        corners.append((T @ g.pixel_to_world() @ c.T).T[:, :2])
    pts = np.vstack(corners)
    res = min(g.resolution for g in grids)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    while True:
        w, h = np.ceil((hi - lo) / res - 1e-9).astype(int)
        if w * h <= max_cells:
            break
        res *= 1.5
    return Canvas(res, (float(lo[0]), float(lo[1])), int(max(w, 1)), int(max(h, 1)))


def resample(grids: list[OccupancyGrid], transforms: list[np.ndarray], canvas: Canvas) -> np.ndarray:
    """R×H×W int8: each map on the canvas (−1 outside it)."""
    return np.stack([canvas.sample(g, T) for g, T in zip(grids, transforms)])


def merge_logodds(stack: np.ndarray, p_min: float, p_max: float) -> np.ndarray:
    """H×W int8 occupancy (−1 where no run saw the cell): the runs' log-odds summed (module doc, step 3)."""
    known = stack >= 0
    p = np.clip(stack.astype(np.float64) / 100.0, p_min, p_max)
    lo = np.where(known, np.log(p / (1.0 - p)), 0.0).sum(axis=0)
    out = np.rint(100.0 / (1.0 + np.exp(-lo))).astype(np.int8)
    out[~known.any(axis=0)] = -1
    return out


def twice_free(p_miss: float) -> float:
    """Occupancy (0..100) of a cell that two beams passed and none ended in (log-odds of p_miss added twice)."""
    lo = 2.0 * np.log(p_miss / (1.0 - p_miss))
    return float(100.0 / (1.0 + np.exp(-lo)))


def change_cells(stack: np.ndarray, cfg: CompareConfig, tol_cells: int,
                 free_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(changed H×W, occupied R×H×W, clearly free R×H×W) on the canvas (module doc, step 4); `free_max`: the
    highest occupancy (0..100) that counts as clearly free (`twice_free`)."""
    import cv2

    occ = stack >= round(100 * cfg.occupied_thresh)
    free = (stack >= 0) & (stack <= min(free_max, 100 * cfg.free_thresh))
    r = max(1, int(tol_cells))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    clear = np.stack([f & (cv2.dilate(o.astype(np.uint8), disk) == 0) for o, f in zip(occ, free)])
    changed = occ.any(axis=0) & clear.any(axis=0)
    # a cell occupied in one run and clear in that same run cannot be (clear excludes its own walls); the "some
    # runs / others" are then always different runs
    return changed, occ, clear


def change_regions(changed: np.ndarray, occ: np.ndarray, clear: np.ndarray, names: list[str], canvas: Canvas,
                   tol_cells: int) -> tuple[list[ChangeRegion], np.ndarray]:
    """Regions of changed cells, largest first, and the mask of the cells kept (module doc, step 4)."""
    import cv2

    r = max(1, int(tol_cells))
    joined = cv2.morphologyEx(changed.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((r + 1, r + 1), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8)
    res = canvas.resolution
    kept = np.zeros_like(changed)
    regions = []
    for k in range(1, n):
        cells = (labels == k) & changed
        rows, cols = np.nonzero(cells)
        if len(rows) < r * r or max(np.ptp(rows), np.ptp(cols)) + 1 <= 2 * r:  # module doc, step 4
            continue
        kept |= cells
        x = canvas.origin[0] + (cols.mean() + 0.5) * res
        y = canvas.origin[1] + (rows.mean() + 0.5) * res
        box = (canvas.origin[0] + cols.min() * res, canvas.origin[1] + rows.min() * res,
               canvas.origin[0] + (cols.max() + 1) * res, canvas.origin[1] + (rows.max() + 1) * res)
        regions.append(ChangeRegion(
            float(x), float(y), float(len(rows) * res * res), tuple(float(v) for v in box),
            [nm for nm, o in zip(names, occ) if o[cells].any()], [nm for nm, c in zip(names, clear) if c[cells].any()]))
    regions.sort(key=lambda g: -g.area_m2)
    return regions, kept


def fleet(names: list[str], grids: list[OccupancyGrid], blueprint: OccupancyGrid | None, cfg: CompareConfig,
          gcfg: GridConfig) -> Fleet:
    """Align, merge and compare the runs (the module doc's steps): `cfg` the alignment's and the cell labels',
    `gcfg` the grids' inverse sensor model (log-odds clamp, p_miss). The runs join the first run's frame; with a
    blueprint, their merged map (which covers more than any one run, so fits the plan in fewer ways) is then
    aligned onto it and every run follows. The first run must have walls to align to."""
    frames = align_runs(names, grids, cfg)
    use = [k for k, f in enumerate(frames) if f.alignment is not None]
    gs = [grids[k] for k in use]
    Ts = [frames[k].alignment.matrix for k in use]
    canvas, stack, merged = _merge_on(gs, Ts, cfg, gcfg)
    if blueprint is not None:  # one transform for all: the runs keep their places relative to each other
        onto = align(merged, blueprint, cfg)
        Ts = [onto.matrix @ T for T in Ts]
        for k in use:
            a = frames[k].alignment
            M = onto.matrix @ a.matrix
            frames[k].alignment = Alignment(float(M[0, 2]), float(M[1, 2]), float(np.arctan2(M[1, 0], M[0, 0])),
                                            a.inliers, a.rms, a.coarse_score, a.ms, True)
        canvas, stack, merged = _merge_on(gs, Ts, cfg, gcfg)
    rms = [frames[k].alignment.rms for k in use if np.isfinite(frames[k].alignment.rms)]
    tol = max(2 * canvas.resolution, 2 * max(rms, default=0.0))
    tol_cells = int(round(tol / canvas.resolution))
    changed, occ, clear = change_cells(stack, cfg, tol_cells, twice_free(gcfg.p_miss))
    regions, kept = change_regions(changed, occ, clear, [names[k] for k in use], canvas, tol_cells)
    ch = np.where(kept, 100, np.where((stack >= 0).any(axis=0), 0, -1)).astype(np.int8)
    return Fleet(frames, canvas, merged, OccupancyGrid(ch, canvas.resolution, merged.origin), regions, tol)


def change_picture(f: Fleet) -> np.ndarray:
    """BGR picture of the change map (row 0 = top): the merged map (white free, black occupied), changed cells
    red, each region boxed and numbered as in the list."""
    import cv2

    from kosmap.mapping.mapio import grid_picture

    m = f.merged.data
    img = grid_picture(f.merged)
    img[f.changes.data[::-1] == 100] = (0, 0, 230)
    res, (ox, oy) = f.canvas.resolution, f.canvas.origin
    scale = max(1, int(np.ceil(600 / max(img.shape[:2]))))  # small maps drawn larger so the labels read
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    H = m.shape[0]
    for k, g in enumerate(f.regions, 1):
        x0, y0, x1, y1 = g.box
        c0, c1 = int((x0 - ox) / res * scale) - 3, int((x1 - ox) / res * scale) + 3
        r0, r1 = int((H - (y1 - oy) / res) * scale) - 3, int((H - (y0 - oy) / res) * scale) + 3
        cv2.rectangle(img, (c0, r0), (c1, r1), (0, 0, 200), 1)
        cv2.putText(img, str(k), (c1 + 2, max(r0 + 10, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 160), 1, cv2.LINE_AA)
    return img
