"""SLAM over a log: its scans (the laser's, or the KOS scans of its depth frames) and wheel odometry read in one
pass into the SLAM core (backend/slam.py) through a SlamFeed (mapping/slamfeed.py); the run's accuracy
(`evaluate`), summary, map and files.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kosmap.backend.kosprofile import kos_graph_config, kos_odometry_config
from kosmap.backend.slam import Slam, SlamResult
from kosmap.frontend import se2
from kosmap.frontend.errors import ConfigError, KosmapError, TopicError
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.odometry import OdometryConfig, scan_points_base
from kosmap.frontend.records import ImuSamples, Odometry, OdometrySamples, Scan, Transforms
from kosmap.mapping.config import Config
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.kosstream import KosStream, ScanRun, run_gravity
from kosmap.mapping.runtime.framepool import FramePool
from kosmap.mapping.slamfeed import SlamFeed, laser_mount, laser_period, no_odom_warning, odometry_columns


def run_slam(path: str | Path, cfg=None, source: str = "laser", progress: Callable[[float, float], None] | None = None,
             keep_scans: bool = False, max_seconds: float | None = None, workers: int = 0) -> SlamResult:
    """Read a log in one pass and run SLAM on its laser scans (`source="laser"`) or on the KOS scans of its
    depth camera(s) (`source="kos"`: FSPF+ → KOS per frame in `workers` processes, 0 = here), with its
    wheel odometry.

    `cfg` is a mapping.config.Config (defaults when None); `progress(done_s, total_s)` is called as log time
    advances; `keep_scans` keeps the Scan records (for the map); `max_seconds` stops after that much log
    time (for slices).
    """
    cfg = cfg or Config()
    if source == "kos":
        return _run_slam_kos(path, cfg, progress, keep_scans, max_seconds, workers)
    if source != "laser":
        raise KosmapError(f"unknown source '{source}'; use laser or kos")
    t_start = time.perf_counter()
    ocfg: OdometryConfig = cfg.odometry
    slam = Slam(ocfg, cfg.graph, map_cell=cfg.grid.resolution)
    kept: list[Scan] | None = [] if keep_scans else None
    warnings: list[str] = []
    with open_log(path, cfg.topics.on_damage) as log:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.scan:
            raise TopicError(f"{Path(path).name} has no sensor_msgs/LaserScan topic; --source laser needs one (see `kosmap info`)")
        use_odom = bool(det.odom) and ocfg.use_wheel_odometry
        feed = SlamFeed(slam, use_odom, bool(det.imu))  # the build's feed (mapping/slamfeed.py): the same inputs
        topics = [det.scan] + ([det.odom] if det.odom else []) + ([det.tf_static] if det.tf_static else [])
        topics += [det.ground_truth] if det.ground_truth else []  # read for scoring only, never used by SLAM
        topics += [det.imu] if feed.use_imu else []
        period = laser_period(cfg.build.laser_rate, info.count(det.scan), float(info.duration))
        gt: list[np.ndarray] = []
        statics: list[Transforms] = []
        st = {"base": "base_link", "mount": None, "last": None, "first": None, "now": None}
        total = info.duration
        for rec in log.read_batched(topics):
            if rec.stamp_ns and (st["now"] is None or rec.stamp_ns > st["now"]):
                st["now"] = rec.stamp_ns
            if isinstance(rec, (Odometry, OdometrySamples)):
                cols = odometry_columns(rec)
                if rec.topic == det.ground_truth:
                    gt.append(np.column_stack(cols))
                    continue
                if rec.topic == det.odom:
                    if st["base"] == "base_link" and rec.child_frame_id:
                        st["base"] = rec.child_frame_id.lstrip("/") or "base_link"
                    feed.wheel_samples(*cols)
            elif isinstance(rec, ImuSamples):
                ok = rec.has_angular_velocity
                feed.gyro_samples(rec.stamps_ns[ok], rec.yaw_rate[ok])
            elif isinstance(rec, Transforms):
                if rec.static:
                    statics.append(rec)
            elif rec.topic == det.imu:
                feed.imu(rec)
            elif isinstance(rec, Scan):
                if st["first"] is None:
                    st["first"] = rec.stamp_ns
                if max_seconds is not None and (rec.stamp_ns - st["first"]) * 1e-9 > max_seconds:
                    break
                if st["last"] is None or rec.stamp_ns - st["last"] >= period - 1_000_000:
                    if st["mount"] is None:
                        st["mount"] = laser_mount(statics, st["base"], rec.frame_id)
                        warnings.extend([st["mount"].warning] if st["mount"].warning else [])
                    st["last"] = rec.stamp_ns
                    rec = st["mount"].read(rec)
                    feed.push_laser(rec, st["mount"].pose)
                    if kept is not None:
                        kept.append(rec)
                if progress is not None:
                    progress((rec.stamp_ns - st["first"]) * 1e-9, total)
            feed.advance(st["now"])
        feed.end()
        warnings.extend(log.warnings)
    result = feed.result()
    if result is None:
        raise KosmapError(nothing_reached_slam(path, "laser scan", warnings))
    result.timings["total"] = time.perf_counter() - t_start
    result.timings["read"] = result.timings["total"] - sum(v for k, v in result.timings.items() if k != "total")
    result.mount = st["mount"].pose if st["mount"] is not None else np.zeros(3)
    result.duration_s = (result.stamps_ns[-1] - result.stamps_ns[0]) * 1e-9 if len(result.stamps_ns) else 0.0
    empty = result.stretches.get("unusable_scans", 0)
    if empty:
        warnings.append(f"{empty} scan(s) had fewer than {ocfg.min_points} returns: posed from odometry only")
    w = no_odom_warning(feed.no_odom, result.stretches, "laser")
    warnings.extend([w] if w else [])
    result.warnings = warnings + result.warnings
    result.scans = kept
    if gt:
        g = np.concatenate(gt)
        result.ground_truth = (g[:, 0] * 1e-9, g[:, 1:4])
    return result


def nothing_reached_slam(path, what: str, warnings: list[str]) -> str:
    """The error of a run where no scan reached SLAM, with the first thing the reading skipped (the reason, when
    the log's scans or frames could not be used) rather than a count of zero scans."""
    first = next((w for w in warnings if "skipped" in w), warnings[0] if warnings else None)
    why = f": {first.removeprefix(Path(path).name + ': ')}" if first else " (every scan was empty?)"
    return f"{Path(path).name}: no {what} reached SLAM{why}; nothing to map"


def _run_slam_kos(path, cfg, progress, keep_scans: bool, max_seconds: float | None, workers: int) -> SlamResult:
    """SLAM on the KOS scan named by [build] slam_scan (obstacle by default) of every time step
    (mapping/kosstream.py's KosStream), with the log's wheel odometry; the ground-truth topic is read for scoring."""
    t_start = time.perf_counter()
    bands = [b[0] for b in cfg.kos.bands()]
    name = cfg.build.slam_scan
    if name not in bands:
        raise ConfigError(f"config [build] slam_scan = {name!r} is not a KOS scan of this config; choose one of {', '.join(bands)}")
    ocfg = kos_odometry_config(cfg)
    gcfg = kos_graph_config(cfg)
    slam = Slam(ocfg, gcfg, map_cell=cfg.grid.resolution)
    kept: list[Scan] | None = [] if keep_scans else None
    warnings: list[str] = []
    gt_t: list[float] = []
    gt_p: list[tuple[float, float, float]] = []
    state = {"t0": None, "empty": 0, "stop": False}
    with open_log(path, cfg.topics.on_damage) as log:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.depth:
            raise TopicError(f"{Path(path).name} has no depth image topic; --source kos needs one (see `kosmap info`; "
                             f"name it with --depth-topic)")
        use_odom = bool(det.odom) and ocfg.use_wheel_odometry
        use_imu = bool(det.imu) and gcfg.imu
        feed = SlamFeed(slam, use_odom, use_imu)
        run = ScanRun()
        total = info.duration
        min_period = int(1e9 / cfg.build.depth_rate) if cfg.build.depth_rate > 0 else 0

        def on_step(step) -> None:
            if state["t0"] is None:
                state["t0"] = step.stamp_ns
            if max_seconds is not None and (step.stamp_ns - state["t0"]) * 1e-9 > max_seconds:
                state["stop"] = True
                return
            sc = step.scans[name]
            pts = scan_points_base(sc.ranges, sc.angles, sc.valid(), None, ocfg.min_range, ocfg.max_range)
            if len(pts) < ocfg.min_points:
                state["empty"] += 1
            feed.push(step.stamp_ns, pts)
            if kept is not None:
                kept.append(sc)
            if progress is not None:
                progress((step.stamp_ns - state["t0"]) * 1e-9, total)

        topics = det.wanted()
        with FramePool(cfg.fspf, cfg.depth, cfg.kos, workers) as pool:
            stream = KosStream(det, cfg, run, pool, min_period_ns=min_period, fuse=False,
                               mounts=run_gravity(path, cfg, run))  # the mounts `kosmap build` uses
            now = None
            for rec in log.read(topics):
                if rec.stamp_ns and (now is None or rec.stamp_ns > now):
                    now = rec.stamp_ns
                if isinstance(rec, Odometry):
                    if rec.topic == det.ground_truth:  # scoring only, never used by SLAM
                        gt_t.append(rec.stamp)
                        gt_p.append((rec.x, rec.y, rec.yaw))
                        continue
                    if rec.topic == det.odom:
                        feed.odom(rec)
                elif use_imu and rec.topic == det.imu:
                    feed.imu(rec)
                for step in stream.feed(rec):
                    on_step(step)
                feed.advance(now)
                if state["stop"]:
                    break
            if not state["stop"]:
                for step in stream.flush():
                    on_step(step)
        feed.advance(None)
        warnings.extend(run.warnings)
        warnings.extend(log.warnings)
    if not slam.stamps:
        raise KosmapError(nothing_reached_slam(path, "KOS scan", warnings))
    result = slam.finish()
    result.timings["total"] = time.perf_counter() - t_start
    result.timings["read"] = result.timings["total"] - sum(v for k, v in result.timings.items() if k != "total")
    result.mount = np.zeros(3)  # KOS scans are in base_link
    result.duration_s = (result.stamps_ns[-1] - result.stamps_ns[0]) * 1e-9 if len(result.stamps_ns) else 0.0
    if state["empty"]:
        warnings.append(f"{state['empty']} KOS scan(s) had fewer than {ocfg.min_points} returns: posed from odometry only")
    w = no_odom_warning(feed.no_odom, result.stretches, "KOS")
    warnings.extend([w] if w else [])
    result.warnings = warnings + result.warnings
    result.scans = kept
    if gt_t:
        result.ground_truth = (np.array(gt_t), np.array(gt_p))
    return result


def evaluate(result: SlamResult, relations: str | Path | np.ndarray | None = None,
             ground_truth: str | Path | tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Accuracy of a run: the relations metric (in the scan's frame, which the relations relate) and the
    loops' precision against the trajectory the relations describe; ATE, RPE and loop precision against a
    TUM ground truth (base_link), or against the log's own ground-truth topic when no file is given."""
    from kosmap.backend import metrics as M
    from kosmap.backend.trajio import read_tum

    out: dict = {}
    mount = np.repeat(result.mount[None], max(len(result.loops), 1), 0)[: len(result.loops)]
    kstamp = np.array([k.stamp_ns for k in result.keyframes]) * 1e-9
    la = np.array([lc.a for lc in result.loops], dtype=int)
    lb = np.array([lc.b for lc in result.loops], dtype=int)
    meas = np.array([lc.rel for lc in result.loops]).reshape(-1, 3)
    if relations is not None:
        rel = M.read_relations(relations) if not isinstance(relations, np.ndarray) else relations
        sensor = result.sensor_poses()
        out["relations"] = M.relations_metric(result.stamps, sensor, rel)
        out["relations_split_30s"] = M.relations_metric_split(result.stamps, sensor, rel)
        if len(meas):
            ref = M.reference_from_relations(rel)
            local = se2.compose(result.local_poses, np.repeat(result.mount[None], len(result.local_poses), 0))
            pa, ca = ref.at(kstamp[la], result.stamps, local)
            pb, cb = ref.at(kstamp[lb], result.stamps, local)
            meas_s = se2.compose(se2.compose(se2.inverse(mount), meas), mount)  # base → sensor frame
            out["loop_precision"] = M.loop_precision(meas_s, pa, pb, ca, cb)
            out["loop_precision"]["reference"] = "trajectory solved from the relations, carried by the front end"
    if ground_truth is None and result.ground_truth is not None:
        ground_truth = result.ground_truth
    if ground_truth is not None:
        tg, pg = read_tum(ground_truth) if not isinstance(ground_truth, tuple) else ground_truth
        out["ate"] = M.ate(result.stamps, result.poses, tg, pg)
        out["rpe"] = M.rpe(result.stamps, result.poses, tg, pg)
        out["ate_frontend"] = M.ate(result.stamps, result.local_poses, tg, pg)
        has_odom = np.all(np.isfinite(result.odom_poses), axis=1) if len(result.odom_poses) else np.zeros(0, bool)
        if has_odom.sum() >= 2:  # the baseline SLAM must beat: the log's wheel odometry at the same stamps
            out["ate_odometry"] = M.ate(result.stamps[has_odom], result.odom_poses[has_odom], tg, pg)
        if len(meas):
            ref = M.Reference(np.asarray(tg, dtype=float), np.asarray(pg, dtype=float), np.zeros(len(tg), int))
            order = np.argsort(ref.t)
            ref = M.Reference(ref.t[order], ref.poses[order], ref.comp)
            pa, ca = ref.at(kstamp[la], max_diff=0.1)
            pb, cb = ref.at(kstamp[lb], max_diff=0.1)
            out["loop_precision_gt"] = M.loop_precision(meas, pa, pb, ca, cb)
    return out


def build_map(result: SlamResult, grid_cfg=None):
    """The log-odds occupancy grid (mapping/grid.py) of the kept scans at their optimised poses."""
    from kosmap.mapping.grid import GridBuilder

    if not result.scans:
        raise KosmapError("the run kept no scans; call run_slam(..., keep_scans=True) to build a map")
    b = GridBuilder(grid_cfg, mount=tuple(result.mount))
    for pose, scan in zip(result.poses, result.scans):
        b.add(pose, scan)
    return b.to_occupancy()




def summary(result: SlamResult) -> dict:
    """Counts and timings of a run (what metrics.json holds besides the accuracy)."""
    edges = result.graph.edges
    kinds = {e.kind for e in edges}
    return {"scans": int(len(result.stamps_ns)), "matched_scans": int(result.matched.sum()),
            "keyframes": len(result.keyframes), "loops": len(result.loops),
            "factors": {k: sum(e.kind == k for e in edges) for k in ("match", "odom", "gyro", "loop", "heading", "motion")},
            "stretches": result.stretches, "consistency": result.consistency,
            "heading": result.heading_stats,
            "recoveries": int(result.recoveries), "duration_s": result.duration_s,
            "seconds": dict(result.timings), "realtime_factor": result.realtime_factor,
            "mount": result.mount.tolist(), "loop_search": result.loop_stats,
            "odometry_scale": result.graph.odom_scale if "odom" in kinds and result.graph.cfg.odom_scale == "estimate" else None,
            "gyro_bias_deg_s": (math.degrees(result.graph.gyro_bias_mean) if "gyro" in kinds and result.graph.cfg.gyro_bias == "estimate"
                                else None),
            "odometry_noise": result.odom_noise, "spacing": result.spacing, "imu": result.imu_stats,
            "warnings": list(result.warnings)}


def save_run(result: SlamResult, out: str | Path, cfg=None, metrics: dict | None = None, grid=None) -> dict[str, Path]:
    """Write trajectory.tum (every scan, base_link), keyframes.tum, graph.g2o, metrics.json, map.png +
    map.pgm/map.yaml (when a grid is given) and config.toml into `out`; returns the paths."""
    import json
    import os

    from kosmap.backend.trajio import write_tum
    from kosmap.mapping.config import write_config

    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    paths = {"trajectory": write_tum(d / "trajectory.tum", result.stamps, result.poses),
             "keyframes": write_tum(d / "keyframes.tum", np.array([k.stamp_ns for k in result.keyframes]) * 1e-9,
                                    result.graph.est),
             "graph": result.graph.write_g2o(d / "graph.g2o")}
    doc = {"run": summary(result), **(metrics or {})}
    tmp = d / "metrics.json.partial"
    tmp.write_text(json.dumps(json_safe(doc), indent=2))
    os.replace(tmp, d / "metrics.json")
    paths["metrics"] = d / "metrics.json"
    if grid is not None:
        from kosmap.mapping.mapio import grid_picture, write_map_server, write_png

        paths["map_png"] = write_png(grid_picture(grid, result.poses), d / "map.png")
        paths["map_yaml"] = write_map_server(grid, d / "map.yaml")
    if cfg is not None:
        paths["config"] = write_config(cfg, d / "config.toml")
    return paths
