"""The build's two SLAMs: one on the chosen KOS scan (the KOS profile, backend/kosprofile.py), one on the laser
when the log has one; each fed by a SlamFeed (mapping/slamfeed.py), in a process of its own beside the reading
when the build runs in parallel (mapping/runtime/slamproc.py), solved once the log is read."""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path

from kosmap.backend.graph import GraphConfig
from kosmap.backend.kosprofile import kos_graph_config, kos_odometry_config
from kosmap.backend.slam import Slam, SlamResult
from kosmap.frontend.errors import KosmapError
from kosmap.frontend.odometry import OdometryConfig
from kosmap.mapping.build.readpass import LogSources
from kosmap.mapping.config import Config
from kosmap.mapping.runtime.slamproc import RemoteFeed, SlamProcessError
from kosmap.mapping.slam import nothing_reached_slam
from kosmap.mapping.slamfeed import SlamFeed, no_odom_warning


def kos_slam_configs(cfg: Config) -> tuple[OdometryConfig, GraphConfig]:
    """The KOS SLAM's front end and graph: the same as `kosmap slam --source kos` (the KOS profile, then [build]
    kos_odometry and kos_graph); a ConfigError for an unknown key."""
    return kos_odometry_config(cfg), kos_graph_config(cfg)


def start_slams(feeds: dict, src: LogSources, cfg: Config, kos_cfgs: tuple[OdometryConfig, GraphConfig],
                workers: int) -> None:
    """Into `feeds`: a feed per SLAM the log has sources for (kos, laser). With workers, each SLAM in a process of its
    own (forked before any thread starts; the same inputs in the same order, so the same maps as serial)."""
    det = src.det
    use_odom = bool(det.odom) and cfg.odometry.use_wheel_odometry
    if src.has_depth:
        feeds["kos"] = SlamFeed(Slam(*kos_cfgs, map_cell=cfg.grid.resolution), use_odom, bool(det.imu))
    if src.has_laser:
        feeds["laser"] = SlamFeed(Slam(cfg.odometry, cfg.graph, map_cell=cfg.grid.resolution), use_odom, bool(det.imu))
    if workers > 0 and "fork" in mp.get_all_start_methods():
        for name in list(feeds):  # one at a time: a failed fork leaves the ones made in `feeds` to be closed
            feeds[name] = RemoteFeed(feeds[name], name)


def solve_slams(feeds: dict, log: Path, warnings: list[str]) -> dict[str, SlamResult]:
    """Each SLAM's final solve; a SLAM that failed is a warning, none left is the build's failure."""
    results = {}
    for name, feed in feeds.items():
        try:
            res = feed.result()
        except SlamProcessError:
            raise  # a lost process is the build's failure, not one map's
        except KosmapError as e:
            warnings.append(f"{name} SLAM produced no trajectory: {e}")
            continue
        w = no_odom_warning(feed.no_odom, res.stretches if res is not None else {}, "KOS" if name == "kos" else name)
        warnings.extend([w] if w else [])
        if res is None:
            continue
        results[name] = res
        warnings.extend(f"{name} SLAM: {w}" for w in res.warnings)  # the gyro's, the heading priors'
    if not results:  # why: a SLAM's own failure, else what the reading skipped
        failed = [w.replace(" produced no trajectory", "") for w in warnings if "SLAM produced no trajectory" in w]
        raise KosmapError(f"{log.name}: {failed[0]}" if failed else nothing_reached_slam(log, "scan", warnings))
    return results
