"""Occupancy grids: the shared grid type, and log-odds grids built from poses and scans."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from frontend.params import StageConfig, param


@dataclass
class GridConfig(StageConfig):
    """[grid]: resolution and the inverse sensor model."""

    section = "grid"
    resolution: float = param(0.05, lo=0.0, lo_open=True, doc="cell size", unit="m")
    p_hit: float = param(0.7, lo=0.5, hi=1.0, lo_open=True, doc="occupancy probability of a beam's end cell")
    p_miss: float = param(0.4, lo=0.0, hi=0.5, doc="occupancy probability of a cell a beam passes")
    no_return_clear: float = param(4.0, lo=0.0, doc="beams without return clear free space this far", unit="m")


@dataclass
class OccupancyGrid:
    """nav_msgs/OccupancyGrid semantics: data[row, col] in −1 (unknown) or 0..100; row 0 is the map's bottom.

    `origin` is (x, y, yaw) of the lower-left corner of cell (0, 0) in the map frame, as in map_server.
    """

    data: np.ndarray  # H×W int8
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame_id: str = "map"

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """(col, row) integer cells of N×2 map points (origin yaw must be 0)."""
        return np.floor((np.asarray(xy) - np.asarray(self.origin[:2])) / self.resolution).astype(np.int64)

    def center_of(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Map coordinates (N×2) of cell centres (origin yaw must be 0)."""
        return np.column_stack((self.origin[0] + (np.asarray(cols) + 0.5) * self.resolution,
                                self.origin[1] + (np.asarray(rows) + 0.5) * self.resolution))
