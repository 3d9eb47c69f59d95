"""[build]: what `kosmap build` (mapping/pipeline.py) feeds to SLAM and the maps, and what it writes.

Kept apart from pipeline.py because mapping/config.py imports it while the pipeline imports the config.
"""

from __future__ import annotations

from dataclasses import dataclass

from kosmap.frontend.params import StageConfig, param

# A narrow depth scan (70°, ≤ 4.5 m) gives the matcher no fix along a corridor: a strong odometry prior along
# the direction of travel and no unconstrained correlative search (docs/dependencies.md, "The narrow depth camera in a
# corridor loop": 17.5 m → 1.4 m ATE), and no wide recovery search (±1 m, ±90°), which locks a narrow scan onto
# the wrong wall: on the simulated office (10835 KOS steps) ATE 7.5 m with it, 0.46 m without (wheel odometry
# alone: 0.26 m). Values of [odometry] that differ for the KOS scans, applied over mapping.slam.KOS_FRONTEND
# (kos_odometry_config), whose owner tunes KOS accuracy; `kosmap build` and `kosmap slam --source kos` share both.
KOS_ODOMETRY = {"prior_weight_along": 1000.0, "search_linear": 0.0, "recovery_ratio": 0.0}


@dataclass
class BuildConfig(StageConfig):
    """[build]: rates, the KOS scan SLAM runs on, its SLAM settings, the extra maps and the MCAP's contents."""

    section = "build"
    depth_rate: float = param(10.0, lo=0.0, doc="process at most this many depth frames per second and camera (0 = every frame): SLAM needs ~10 Hz, the maps take 5 Hz, and every frame of a 30 Hz camera costs 3× the CPU for no better map (docs/bench/pipeline.md)", unit="Hz")
    laser_rate: float = param(10.0, lo=0.0, doc="laser scans used for SLAM, at most this many per second (0 = every scan; a laser averaging no more than 1.2× this keeps every scan); the laser map takes laser_map_rate of them", unit="Hz")
    kos_map_rate: float = param(5.0, lo=0.0, doc="KOS steps integrated into the grids, at most this many per second (0 = every step): at 30 Hz the misses of grazing beams wear thin walls away", unit="Hz")
    laser_map_rate: float = param(5.0, lo=0.0, doc="laser (and fused) scans integrated into the grids, at most this many per second (0 = every scan SLAM used): each de-skewed with the twist from the scan before it, as at the full rate", unit="Hz")
    slam_scan: str = param("obstacle", doc="the KOS scan SLAM runs on: obstacle, or a level's name such as h0_75")
    kos_odometry: dict = param(dict(KOS_ODOMETRY), doc="[odometry] values that differ for the KOS scans (a narrow depth scan); a table given replaces this one whole")
    kos_graph: dict = param({}, doc="[graph] values that differ for the KOS scans")
    kos_on_laser_poses: bool = param(True, doc="also map the KOS obstacle scan at the laser SLAM's poses (KOS without KOS SLAM's error)")
    fused_map: bool = param(True, doc="also map the obstacle scan fused with the laser, at the laser SLAM's poses")
    compare_levels: bool = param(False, doc="compare every KOS level with the blueprint (else the SLAM scan's map only)")
    mcap_planes_period: float = param(1.0, lo=0.0, doc="MCAP: the plane points of one frame every this many seconds (0 = none)", unit="s")
    mcap_plane_points: int = param(4000, lo=1, doc="MCAP: at most this many plane points per cloud (a seeded subsample)")
    in_flight: int = param(0, lo=0, doc="depth frames in flight to the worker processes (0 = 3 per worker)")
