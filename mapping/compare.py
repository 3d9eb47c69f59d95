"""Map comparison: robust rigid alignment of two occupancy grids, then precision, recall, F1 and distances."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param


@dataclass
class CompareConfig(StageConfig):
    """[compare]: tolerances of the occupied-cell match."""

    section = "compare"
    tolerances: list = param([0.05, 0.10, 0.20], doc="match tolerances", unit="m")
    align: bool = param(True, doc="align A to B before scoring")
