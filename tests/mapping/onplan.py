"""How much of a localizer input's scans lies on a simulated world's plan: the scans' end points posed at the log's
ground truth, against the walls and furniture of `World.blueprint`."""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def share_on_plan(inp, world, tol: float = 0.15, every: int = 1) -> float:
    """The share of end points (of every `every`-th scan of a LocalizationInput) within `tol` metres of a wall or
    furniture cell; points off the plan's grid count as off it. The plan's walls are drawn along their centre
    lines, so `tol` includes half a wall's thickness."""
    grid = world.blueprint(0.05, furniture=True)
    near = ndimage.distance_transform_edt(grid.data < 50) * grid.resolution <= tol
    gt_t, gt_p = inp.ground_truth
    hits = []
    for t, pts in zip(inp.stamps[::every], inp.points[::every]):
        x, y, yaw = gt_p[np.argmin(np.abs(gt_t - t))]
        c, s = np.cos(yaw), np.sin(yaw)
        w = np.column_stack((x + c * pts[:, 0] - s * pts[:, 1], y + s * pts[:, 0] + c * pts[:, 1]))
        cells = np.floor((w - np.asarray(grid.origin[:2])) / grid.resolution).astype(int)
        ok = (cells[:, 0] >= 0) & (cells[:, 1] >= 0) & (cells[:, 0] < grid.width) & (cells[:, 1] < grid.height)
        hit = np.zeros(len(cells), bool)
        hit[ok] = near[cells[ok, 1], cells[ok, 0]]
        hits.append(hit)
    return float(np.mean(np.concatenate(hits)))
