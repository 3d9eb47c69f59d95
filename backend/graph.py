"""The pose graph: gtsam Pose2 nodes, odometry, scan-matching and loop factors, robust kernels, batch LM."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param


@dataclass
class GraphConfig(StageConfig):
    """[graph]: loop search and the robust kernel."""

    section = "graph"
    loop_closure: bool = param(True, doc="search for and add loop closures")
    loop_search_radius: float = param(4.0, lo=0.0, doc="candidate submaps within this distance", unit="m")
    robust_kernel: str = param("cauchy", choices=("cauchy", "gnc", "huber", "none"), doc="kernel on loop factors")
