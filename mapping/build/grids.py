"""Pass 2 of `kosmap build`: every occupancy grid from the spill and the optimised poses, one job per map
(mapping/build/jobs.py) while this process writes the MCAP; each finished grid starts its comparisons. The maps
are written as PNG and map_server PGM + YAML, the trajectories as TUM."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.backend.slam import SlamResult
from kosmap.backend.trajio import write_tum
from kosmap.frontend import se2
from kosmap.frontend.kos import FUSED, OBSTACLE
from kosmap.mapping.build.compares import Compares
from kosmap.mapping.build.jobs import Jobs
from kosmap.mapping.build.readpass import ReadResult
from kosmap.mapping.build.spill import RowReader, Series, scan_of
from kosmap.mapping.config import Config
from kosmap.mapping.grid import GridBuilder, OccupancyGrid
from kosmap.mapping.mapio import grid_picture, write_map_server, write_png


@dataclass
class GridJob:
    """One map to build: what it shows (metrics.json "maps") and the spilled scans and poses its job reads."""

    name: str
    source: str  # kos or laser (or fused)
    level: str | None  # the KOS scan, None for the laser
    poses_of: str  # the SLAM whose poses it is built on
    label: str
    mount: tuple  # the sensor's (x, y, yaw) in base_link
    series: Series
    band: tuple[int, int] | None  # (k, B): band k of the B in a row, or None for the whole row
    stamps: np.ndarray
    poses: np.ndarray
    idx: np.ndarray  # the scans integrated (at the map rate)

    @property
    def cost(self) -> int:
        """Beams to trace: scans × beams per scan."""
        return len(self.idx) * (self.series.width // (self.band[1] if self.band else 1))


@dataclass
class MapOut:
    """A map written: its grid and files, and what metrics.json says of it."""

    job: GridJob
    grid: OccupancyGrid
    png: Path
    yaml: Path

    def as_metrics(self) -> dict:
        g, j = self.grid, self.job
        return {"png": self.png, "yaml": self.yaml, "source": j.source, "level": j.level, "poses": j.poses_of,
                "scans": len(j.idx), "label": j.label, "occupied_cells": int((g.data >= 65).sum()),
                "known_cells": int((g.data >= 0).sum()), "width": g.width, "height": g.height,
                "resolution": g.resolution, "origin": list(g.origin)}


def grid_job(gcfg, mount, path: str, width: int, band: tuple | None, meta: dict, stamps: np.ndarray,
             poses: np.ndarray, idx: np.ndarray) -> OccupancyGrid:
    """One log-odds grid from the spilled scans `idx` (rows of `path`; band k of B per row when `band` = (k, B))."""
    rows = RowReader(path, width)
    b = GridBuilder(gcfg, mount)
    last = -1
    try:
        for s in idx:
            s = int(s)
            if last >= 0 and s - 1 > last:  # scans skipped (a map rate below the scans'): de-skew from the one before
                b.previous(stamps[s - 1], poses[s - 1])
            last = s
            r = rows.get(s)
            if band is not None:
                n = width // band[1]
                r = r[band[0] * n:(band[0] + 1) * n]
            b.add(poses[s], scan_of(meta, stamps[s], r))
    finally:
        rows.close()
    return b.to_occupancy()


def every(stamps: np.ndarray, rate: float) -> np.ndarray:
    """Indices of the stamps kept at most `rate` per second (all when rate is 0)."""
    if rate <= 0 or not len(stamps):
        return np.arange(len(stamps))
    period, keep, last = int(1e9 / rate) - 1_000_000, [], None
    for i, t in enumerate(stamps):
        if last is None or t - last >= period:
            keep.append(i)
            last = t
    return np.asarray(keep, np.int64)


def _poses_at(res: SlamResult, stamps: np.ndarray) -> np.ndarray:
    if np.array_equal(res.stamps_ns, stamps):
        return res.poses
    return se2.interpolate(res.stamps_ns.astype(np.float64), res.poses, stamps.astype(np.float64))


def plan_grids(read: ReadResult, results: dict[str, SlamResult], cfg: Config) -> list[GridJob]:
    """The maps of the build, in their order: every KOS scan on the KOS SLAM's poses, the KOS obstacle scan on the
    laser's, the laser and the fused scan on the laser's."""
    bcfg, spill = cfg.build, read.spill
    bands = spill.bands
    kos_stamps = np.asarray(spill.kos.stamps, np.int64)
    laser_mount = tuple(read.laser_mount) if read.laser_mount is not None else (0.0, 0.0, 0.0)
    jobs: list[GridJob] = []
    kos_idx = every(kos_stamps, bcfg.kos_map_rate)
    if len(kos_stamps) and "kos" in results:
        poses = _poses_at(results["kos"], kos_stamps)
        for k, b in enumerate(bands):
            jobs.append(GridJob(f"kos_{b}", "kos", b, "kos", f"KOS {b}" + (" (SLAM scan)" if b == bcfg.slam_scan else ""),
                                (0.0, 0.0, 0.0), spill.kos, (k, len(bands)), kos_stamps, poses, kos_idx))
    if len(kos_stamps) and "laser" in results and bcfg.kos_on_laser_poses:
        jobs.append(GridJob("kos_obstacle_at_laser_poses", "kos", OBSTACLE, "laser", "KOS obstacle at the laser's poses",
                            (0.0, 0.0, 0.0), spill.kos, (bands.index(OBSTACLE), len(bands)), kos_stamps,
                            _poses_at(results["laser"], kos_stamps), kos_idx))
    for name, series, level, label in (("laser", spill.laser, None, "laser"),
                                       ("fused", spill.fused, FUSED, "KOS obstacle fused with the laser")):
        if "laser" in results and len(series):  # both on the laser's poses, at laser_map_rate
            st = np.asarray(series.stamps, np.int64)
            jobs.append(GridJob(name, name, level, "laser", label, laser_mount, series, None, st,
                                _poses_at(results["laser"], st), every(st, bcfg.laser_map_rate)))
    return jobs


class GridsInFlight:
    """The grid jobs submitted (longest first), handed to the comparisons as they finish (`poll`), then written
    (`collect`)."""

    def __init__(self, plan: list[GridJob], cfg: Config, jobs: Jobs, compares: Compares) -> None:
        self.plan, self.compares = plan, compares
        # Longest first (beams to trace), so that no long job starts last while the other worker idles (Graham's
        # LPT rule): the laser and fused maps trace ~4× a KOS map's beams.
        self.futures: list = [None] * len(plan)
        for k in sorted(range(len(plan)), key=lambda k: -plan[k].cost):
            j = plan[k]
            j.series.close()
            self.futures[k] = jobs.submit(grid_job, cfg.grid, j.mount, str(j.series.path), j.series.width, j.band,
                                          j.series.meta, j.stamps, j.poses, j.idx)
        compares.expect([j.name for j in plan])

    def poll(self) -> None:
        """Hand every finished grid to the comparisons (called between batches of MCAP messages)."""
        for j, fut in zip(self.plan, self.futures):
            if fut.done():
                self.compares.grid_ready(j.name, fut.result())

    def collect(self, out: Path, results: dict[str, SlamResult], files: dict[str, Path]) -> dict[str, MapOut]:
        """Every grid (waited for), to the comparisons and written: map_<name>.png (with its trajectory), .pgm and
        .yaml."""
        maps: dict[str, MapOut] = {}
        for j, fut in zip(self.plan, self.futures):
            grid = fut.result()
            self.compares.grid_ready(j.name, grid)
            res = results.get(j.poses_of)
            png = write_png(grid_picture(grid, None if res is None else res.poses), out / f"map_{j.name}.png")
            yml = write_map_server(grid, out / f"map_{j.name}.yaml")
            files[f"map_{j.name}"] = yml
            maps[j.name] = MapOut(j, grid, png, yml)
        return maps


def write_trajectories(out: Path, results: dict[str, SlamResult], gt: np.ndarray, files: dict[str, Path]) -> None:
    """trajectory_<slam>.tum, ground_truth.tum (when the log has one) and odometry.tum (the wheel odometry at the
    scans' stamps: the baseline SLAM should beat)."""
    for name, res in results.items():
        files[f"trajectory_{name}"] = write_tum(out / f"trajectory_{name}.tum", res.stamps_ns * 1e-9, res.poses)
    if len(gt):
        files["ground_truth"] = write_tum(out / "ground_truth.tum", gt[:, 0], gt[:, 1:4])
    res = results.get("kos") or results.get("laser")
    ok = np.isfinite(res.odom_poses).all(axis=1)
    if ok.sum() >= 2:
        files["odometry"] = write_tum(out / "odometry.tum", res.stamps[ok], res.odom_poses[ok])
