"""The Kinect Obstacle Scan (thesis Alg. 7): plane points binned by bearing into laser scans at several heights."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param


@dataclass
class KosConfig(StageConfig):
    """[kos]: levels are heights above the floor in base_link; band ±0.1 m as in the thesis."""

    section = "kos"
    levels: list = param([0.3, 0.75, 1.5], doc="scan heights above the floor", unit="m")
    band: float = param(0.1, lo=0.0, lo_open=True, doc="half height of each level's band", unit="m")
    obstacle_min: float = param(0.05, doc="obstacle scan: lowest point height", unit="m")
    obstacle_max: float = param(1.9, doc="obstacle scan: highest point height", unit="m")
    angle_increment_deg: float = param(0.0, lo=0.0, doc="bearing bin width; 0 = one bin per image column", unit="deg")
    source: str = param("planes", choices=("planes", "depth"), doc="plane points (thesis) or all valid depth points")
