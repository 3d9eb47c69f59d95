"""The map as a particle filter and a scan matcher see it: a likelihood field over an occupancy grid.

Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), §6.4 (Table 6.3, likelihood_field_range_finder_model): a
beam's end point at distance d from the nearest occupied cell has likelihood z_hit·N(d; 0, σ_hit²) + z_rand/z_max;
no-returns are skipped and nothing is charged for a beam that ends short of the wall it points at, so furniture,
people and anything the map (a bare blueprint) lacks cost only the z_rand floor. AMCL's likelihood_field model
looks the value up at the nearest cell, as `log_table` is used here.

The distance is taken to the surface of the walls (the nearest cell across it less half a cell, on both sides): a wall
in a blueprint is a band of cells, and a sensor sees its surface, not the centre of its outermost cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

OCCUPIED_MIN = 65  # map_server's occupied_thresh (0.65) in OccupancyGrid units
FREE_MAX = 19  # below map_server's free_thresh (0.196): a cell a robot may stand in


@dataclass
class MapField:
    """Look-up tables over the map's cells (row 0 = the map's bottom, origin = lower-left corner of cell (0, 0))."""

    log_table: np.ndarray  # H×W float32: log(z_hit·exp(−d²/2σ_hit²) + z_rand/z_max)
    match: np.ndarray  # H×W float32: exp(−d²/2σ_match²), the scan matcher's field (frontend/matcher.py)
    match_coarse: np.ndarray  # H×W float32: the same with 2σ_match, the coarser of the refinement's two levels
    free: np.ndarray  # H×W bool: cells a pose may lie in
    distance: np.ndarray  # H×W float32: metres to the nearest occupied cell's edge
    origin: tuple[float, float]
    resolution: float
    floor: float  # log(z_rand/z_max): an end point off the map, or far from any wall
    match_sigma: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.free.shape  # type: ignore[return-value]

    @property
    def free_area(self) -> float:
        return float(self.free.sum()) * self.resolution ** 2

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(col, row, inside) of N×2 map points."""
        c = np.floor((np.asarray(xy)[:, 0] - self.origin[0]) / self.resolution).astype(np.int64)
        r = np.floor((np.asarray(xy)[:, 1] - self.origin[1]) / self.resolution).astype(np.int64)
        h, w = self.shape
        inside = (c >= 0) & (r >= 0) & (c < w) & (r < h)
        return c, r, inside

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        c, r, inside = self.cells(xy)
        out = np.zeros(len(c), bool)
        out[inside] = self.free[r[inside], c[inside]]
        return out

    def is_occupied(self, xy: np.ndarray) -> np.ndarray:
        """Points within one cell of a wall (the map's occupied cells)."""
        c, r, inside = self.cells(xy)
        out = np.zeros(len(c), bool)
        out[inside] = self.distance[r[inside], c[inside]] <= 0.5 * self.resolution
        return out

    def sample_free(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n poses uniform over the free cells (uniform inside each cell) and over headings."""
        rows, cols = np.nonzero(self.free)
        k = rng.integers(0, len(rows), n)
        x = self.origin[0] + (cols[k] + rng.random(n)) * self.resolution
        y = self.origin[1] + (rows[k] + rng.random(n)) * self.resolution
        return np.column_stack((x, y, rng.uniform(-math.pi, math.pi, n)))


def map_field(data: np.ndarray, resolution: float, origin, sigma_hit: float, z_hit: float, z_rand: float,
              z_max: float, match_sigma: float) -> MapField:
    """The likelihood fields of an occupancy grid (nav_msgs semantics: −1 unknown, 0..100; row 0 the bottom; origin
    the lower-left corner, no yaw): its occupied cells are the walls, its free cells where a robot may be."""
    data = np.asarray(data)
    occ = data >= OCCUPIED_MIN
    res = float(resolution)
    if occ.any():
        d = ndimage.distance_transform_edt(~occ) * res
        d = np.maximum(d - 0.5 * res, 0.0)
        # inside a wall: the distance to its surface too, so that the fields peak at the surface a sensor sees
        # and not across the whole band of wall cells (the matcher would pull end points into the wall)
        surface = np.where(occ, np.maximum(ndimage.distance_transform_edt(occ) * res - 0.5 * res, 0.0), d)
    else:
        d = surface = np.full(data.shape, np.inf)
    floor = math.log(z_rand / z_max)
    table = np.log(z_hit * np.exp(-0.5 * (surface / sigma_hit) ** 2) + z_rand / z_max).astype(np.float32)
    match = np.exp(-0.5 * (surface / match_sigma) ** 2).astype(np.float32)
    free = (data >= 0) & (data <= FREE_MAX)
    coarse = np.exp(-0.5 * (surface / (2.0 * match_sigma)) ** 2).astype(np.float32)
    return MapField(np.ascontiguousarray(table), np.ascontiguousarray(match), np.ascontiguousarray(coarse), free,
                    np.minimum(d, 1e6).astype(np.float32), (float(origin[0]), float(origin[1])), res,
                    floor, float(match_sigma))
