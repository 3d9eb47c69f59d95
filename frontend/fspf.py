"""FSPF (Biswas & Veloso) and FSPF+ (thesis Alg. 1, 3–6): sampled plane filtering of depth images."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param

PLANE_CLASSES = ("ground", "ceiling", "left", "right", "front", "slanted")


@dataclass
class FspfConfig(StageConfig):
    """[fspf]: defaults from the thesis's Table 5.4 (real-time configuration)."""

    section = "fspf"
    method: str = param("fspf+", choices=("fspf+", "fspf"), doc="FSPF+ (thesis) or FSPF (Biswas, baseline)")
    n_min: int = param(40, lo=3, doc="planes with this many inliers or fewer are dropped (nMin)")
    omega_px: int = param(60, lo=2, doc="p1, p2 are drawn within this many pixels of p0 (Ω)", unit="px")
    delta_m: float = param(0.5, lo=0.0, lo_open=True, doc="world size of the search window (Δ)", unit="m")
    epsilon_m: float = param(0.02, lo=0.0, lo_open=True, doc="RANSAC inlier distance (ε)", unit="m")
    beta: float = param(3.0, lo=1.0, doc="RANSAC stopping factor (β)")
    analysed_fraction: float = param(0.90, lo=0.0, hi=1.0, lo_open=True,
                                     doc="stop when this fraction of eligible pixels is consumed (nRequired)")
    drop_classes: list = param(["ground", "ceiling"], choices=PLANE_CLASSES, doc="plane classes filtered out")
    seed: int = param(0, lo=0, doc="random seed (per frame, the frame index is added)")
