"""Log-odds occupancy grids from poses and scans."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param


@dataclass
class GridConfig(StageConfig):
    """[grid]: resolution and the inverse sensor model."""

    section = "grid"
    resolution: float = param(0.05, lo=0.0, lo_open=True, doc="cell size", unit="m")
    p_hit: float = param(0.7, lo=0.5, hi=1.0, lo_open=True, doc="occupancy probability of a beam's end cell")
    p_miss: float = param(0.4, lo=0.0, hi=0.5, doc="occupancy probability of a cell a beam passes")
    no_return_clear: float = param(4.0, lo=0.0, doc="beams without return clear free space this far", unit="m")
