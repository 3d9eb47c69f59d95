"""`kosmap build`: a log → FSPF+ → KOS → SLAM → occupancy grids → comparisons → report, in one streaming pass.

Pass 1 reads the log once. Depth frames go to a process pool (mapping/framepool.py: FSPF+ and every KOS level
per frame, seeded by the frame's index, so the results equal a serial run's); the per-step KOS scans come back
in order, cameras merged (mapping/kosscan.py); the chosen KOS scan goes to one SLAM and, when the log has one,
the laser to another, each with the wheel odometry interpolated at its stamps (mapping/slam.py). Everything a
map needs later is appended to files in a temporary folder (the "spill"), never kept in memory, so memory
stays flat however long the log. After the SLAMs' final solves, pass 2 reads the spill back once and builds
the grids of every source and level from the optimised poses, and writes the Foxglove MCAP. Then the maps are
compared (KOS vs laser vs blueprint), and metrics.json, the TUM trajectories, stats.csv, the effective config
and the report (mapping/report.py) are written.

Ctrl-C (or a KeyboardInterrupt from `on_progress`) stops reading; what was read is mapped and written as
usual, marked partial in metrics.json and the report, unless the output folder holds a complete earlier build,
which is then kept. Everything is written into a staging folder whose files replace the previous build's only
when the build completes (mapping/outdir.py), so a failed, stopped or killed run leaves the folder as it was.
"""

from __future__ import annotations

import csv
import json
import multiprocessing as mp
import os
import shutil
import signal
import tempfile
import threading
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.camera import lookup_static
from kosmap.frontend.depthstream import DepthItem
from kosmap.frontend.errors import ConfigError, KosmapError, TopicError
from kosmap.frontend.kos import FUSED, OBSTACLE, fuse_with_laser
from kosmap.frontend.kosframe import KosFrame
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.odometry import OdometryConfig, scan_points_base
from kosmap.frontend.records import Imu, ImuSamples, Odometry, OdometrySamples, Scan, Transform, Transforms, yaw_to_quat
from kosmap.mapping.config import Config, config_dict, write_config
from kosmap.mapping.childproc import die_with_parent
from kosmap.mapping.framepool import FramePool, check_workers, default_workers, executor_peak_rss_mb, peak_rss_mb
from kosmap.mapping.grid import GridBuilder, OccupancyGrid
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.kosscan import KOS_PREFIX, KosStream, KosStep, ScanRun
from kosmap.mapping.outdir import SPILL_PREFIX, check_out, claim, commit, discard, holds_complete_run
from kosmap.mapping.slamproc import RemoteFeed, SlamProcessError
from kosmap.mapping.slamfeed import SlamFeed, laser_mount, laser_period, no_odom_warning, odometry_columns

STATS_COLUMNS = ("frame", "topic", "stamp", "ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct", "remaining",
                 "planes", "points", "fspf_ms", "kos_ms")
TABLE_5_2 = ("ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct", "planes", "fspf_ms", "kos_ms")
PLANES_TOPIC = "/kosmap/planes/points"
OUTPUTS = ("metrics.json", "report.html", "report.md", "map_*.png", "map_*.pgm", "map_*.yaml", "overlay_*.png",
           "trajectory_*.tum", "ground_truth.tum", "odometry.tum", "stats.csv", "kosmap.mcap", "summary.png",
           "frames.png", "trajectories.png")  # what a build writes into its folder (removed first when present)
BUILD_FILES = OUTPUTS + ("config.toml",)  # and its effective config: mapping/outdir.py tells ours from the user's


# ---- SLAM feeding ---------------------------------------------------------------------------------------------------

# SlamFeed (mapping/slamfeed.py) hands each SLAM its scans, as it does for `kosmap slam`.


# ---- the spill: per-step scans on disk between the passes -----------------------------------------------------------

class _Series:
    """Fixed-width float32 rows appended to a file, with a stamp per row added by `add` (8 bytes a scan: all the
    series keeps in memory); read back in chunks (`_RowReader`)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fh = open(path, "wb")
        self.stamps = array("q")
        self.rows = 0
        self.width = 0
        self.meta: dict = {}

    def add(self, stamp_ns: int, row: np.ndarray) -> bool:
        row = np.ascontiguousarray(row, np.float32).reshape(-1)
        if self.width == 0:
            self.width = row.size
        elif row.size != self.width:
            return False  # a scan of another shape (a changed laser configuration): skipped
        self.fh.write(row.tobytes())
        self.stamps.append(int(stamp_ns))
        self.rows += 1
        return True

    def add_rows(self, rows: np.ndarray) -> int:
        """Several rows at once, without stamps (the caller indexes them: Spill.cloud_index); returns the first
        row's number. A stamp per row here cost 8 bytes per plane point, 19 MB over a 10-minute log."""
        rows = np.ascontiguousarray(rows, np.float32)
        if self.width == 0:
            self.width = rows.shape[1]
        self.fh.write(rows.tobytes())
        first = self.rows
        self.rows += len(rows)
        return first

    def __len__(self) -> int:
        return self.rows

    def close(self) -> None:
        if not self.fh.closed:
            self.fh.close()

    def reader(self) -> _RowReader:
        self.close()
        return _RowReader(self.path, max(self.width, 1))


class _RowReader:
    """Rows of a spill file, read forward in chunks: no memory map, whose touched pages would count as resident
    memory growing with the log."""

    def __init__(self, path: Path | str, width: int, chunk: int = 512) -> None:
        self.fh = open(path, "rb")
        self.width, self.chunk = int(width), chunk
        self.lo = 0
        self.buf = np.zeros((0, self.width), np.float32)

    def get(self, i: int) -> np.ndarray:
        if not self.lo <= i < self.lo + len(self.buf):
            self.fh.seek(4 * i * self.width)
            self.buf = np.fromfile(self.fh, np.float32, count=self.chunk * self.width).reshape(-1, self.width)
            self.lo = i
        return self.buf[i - self.lo]

    def block(self, first: int, n: int) -> np.ndarray:
        self.fh.seek(4 * first * self.width)
        return np.fromfile(self.fh, np.float32, count=n * self.width).reshape(-1, self.width)

    def close(self) -> None:
        self.fh.close()


class Spill:
    """Temporary files for pass 2: KOS steps (every band, NaN out of view), laser scans, fused scans, plane points."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.kos = _Series(folder / "kos.f32")
        self.laser = _Series(folder / "laser.f32")
        self.fused = _Series(folder / "fused.f32")
        self.planes = _Series(folder / "planes.f32")  # rows of 4: x y z class (base_link); one cloud per index entry
        self.cloud_index: list[tuple[int, int, int]] = []  # (stamp, first row, rows): one cloud a second

    def add_cloud(self, stamp_ns: int, pts: np.ndarray, cls: np.ndarray) -> None:
        first = self.planes.add_rows(np.column_stack((pts, cls)).astype(np.float32))
        self.cloud_index.append((int(stamp_ns), first, len(pts)))

    def close(self) -> None:
        for s in (self.kos, self.laser, self.fused, self.planes):
            s.close()


# ---- results --------------------------------------------------------------------------------------------------------

class BuildInterrupted(KosmapError):
    """Ctrl-C stopped a build whose folder holds a complete earlier build: that one is kept, not the partial one."""

    exit_code = 130


@dataclass
class BuildResult:
    """What `build` wrote and measured."""

    out: Path
    metrics: dict
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def partial(self) -> bool:
        return bool(self.metrics.get("partial"))


@dataclass
class Progress:
    """What `on_progress` sees after each unit of work (a depth frame, or a laser scan in a log without depth)."""

    frames: int
    scans: int
    log_s: float
    total_s: float


def _stats(v) -> dict:
    a = np.asarray(v, np.float64)
    if not a.size:
        return {"n": 0, "mean": None, "std": None, "median": None, "p90": None}
    return {"n": int(a.size), "mean": float(a.mean()), "std": float(a.std()), "median": float(np.median(a)),
            "p90": float(np.percentile(a, 90))}




def _renamed(doc, old: str, new: str):
    """`doc` (metrics: dicts, lists, strings, paths) with each path under folder `old` under folder `new` instead."""
    if isinstance(doc, dict):
        return {k: _renamed(v, old, new) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_renamed(v, old, new) for v in doc]
    if isinstance(doc, Path):
        return Path(_renamed(str(doc), old, new))
    if isinstance(doc, str) and (doc == old or doc.startswith(old + os.sep)):
        return new + doc[len(old):]
    return doc


def _write_text(path: Path, text: str) -> Path:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


# ---- the build --------------------------------------------------------------------------------------------------------

def build(log: str | Path, out_dir: str | Path, cfg: Config | None = None, blueprint: str | Path | None = None,
          workers: int | None = None, progress: bool = False, on_progress: Callable[[Progress], None] | None = None,
          report: bool = True, say: Callable[[str], None] | None = None,
          blueprint_scale: float | None = None, reads: tuple = ()) -> BuildResult:
    """Build every map of `log` into `out_dir` (see the module doc); returns the metrics and the files written.

    `workers`: processes for the per-frame stage (None = every core, 0 = serial in this process; the maps are
    the same). `progress`: a rich progress bar on stderr. `on_progress`: called after each frame (or laser scan
    in a log without depth); raising KeyboardInterrupt there stops the run like Ctrl-C. `say`: where phase
    messages go (None = nowhere). `blueprint_scale`: metres per pixel of a plain-image blueprint (None for a
    map_server YAML, which has its resolution). `reads`: other files the run reads (--config): like the log and
    the blueprint, never replaced by an output in `out_dir`.
    """
    from kosmap.mapping.slam import Slam

    t_start = time.perf_counter()
    cpu_start = time.process_time()
    cfg = cfg or Config()
    log = Path(log)
    out = Path(out_dir)
    say = say or (lambda _m: None)
    workers = default_workers() if workers is None else check_workers(int(workers))
    bcfg = cfg.build
    check_out(out)
    bp_grid = None
    if blueprint is not None:
        from kosmap.mapping.mapio import read_blueprint

        bp_grid = read_blueprint(blueprint, blueprint_scale, cfg.compare.blueprint_dark)  # fails before any work
    with open_log(log, cfg.topics.on_damage) as lg:
        info = lg.info()
        det = detect_topics(info.types(), cfg.topics)
        counts = {t: info.count(t) for t in info.types()}
        duration = float(info.duration)
    has_depth, has_laser = bool(det.depth), bool(det.scan)
    if not has_depth and not has_laser:
        raise TopicError(f"{log.name} has neither a depth image topic nor a laser scan topic: nothing to map "
                         f"(see `kosmap info {log.name}`; name them with --depth-topic / --scan-topic)")
    bands = [b[0] for b in cfg.kos.bands()]
    if has_depth and bcfg.slam_scan not in bands:
        raise ConfigError(f"config [build] slam_scan = {bcfg.slam_scan!r} is not a KOS scan of this config; "
                          f"choose one of {', '.join(bands)}")
    from kosmap.mapping.slam import kos_odometry_config

    kos_ocfg: OdometryConfig = kos_odometry_config(cfg)  # the same front end as `kosmap slam --source kos`
    from kosmap.mapping.slam import kos_graph_config

    kos_gcfg = kos_graph_config(cfg)  # the same graph as `kosmap slam --source kos` (KOS_GRAPH, then [build] kos_graph)

    bp_files = () if blueprint is None else (Path(blueprint), *(Path(blueprint).with_suffix(x) for x in (".png", ".pgm")))
    # a file of the user's, or one this run reads, under one of our names stops here; the run writes into a staging
    # folder whose files replace the previous build's only when it completes (mapping/outdir.py)
    stage = claim(out, BUILD_FILES, inputs=(log, *bp_files, *reads))
    final_out, out = out, stage.dir
    spill_dir = Path(tempfile.mkdtemp(prefix=SPILL_PREFIX, dir=out))
    warnings: list[str] = []
    pool = None
    feeds: dict[str, SlamFeed | RemoteFeed] = {}
    try:
        files: dict[str, Path] = {"config": write_config(cfg, out / "config.toml")}
        # One set of worker processes for the whole build, forked now while this process is small: the frames in
        # pass 1, then the grid and comparison jobs. Workers forked after pass 1 counted every page of this process
        # (by then holding SLAM's state) as their own resident memory: 167 → 259 MB from a 1- to a 10-minute log.
        _warm_grid()  # compiled (or loaded) before the fork: every worker inherits the grid kernel
        use_odom = bool(det.odom) and cfg.odometry.use_wheel_odometry
        if has_depth:
            feeds["kos"] = SlamFeed(Slam(kos_ocfg, kos_gcfg), use_odom, bool(det.imu))
        if has_laser:
            feeds["laser"] = SlamFeed(Slam(cfg.odometry, cfg.graph), use_odom, bool(det.imu))
        if workers > 0 and "fork" in mp.get_all_start_methods():
            # each SLAM in a process of its own beside the reading (mapping/slamproc.py), forked before any
            # thread starts; the same inputs in the same order, so the same maps as serial
            for name in list(feeds):  # one at a time: a failed fork leaves the ones made in `feeds` to be closed
                feeds[name] = RemoteFeed(feeds[name], name)
        if has_depth:
            pool = FramePool(cfg.fspf, cfg.depth, cfg.kos, workers, bcfg.in_flight or None)
        p1 = _pass1(log, det, cfg, counts, duration, workers, progress, on_progress, spill_dir, warnings, pool,
                    feeds.get("kos"), feeds.get("laser"))
        if p1["partial"] and holds_complete_run(final_out, "build"):
            raise BuildInterrupted(f"interrupted after {p1['log_s']:.1f} s of log; the complete build already in "
                                   f"{final_out} is kept (run again to replace it)")
        rss = {"after_read": peak_rss_mb()}
        say(("interrupted: mapping what was read, " if p1["partial"] else "")
            + f"{p1['frames']} depth frames, {p1['laser_kept']} laser scans read in {p1['seconds']:.1f} s")
        t_slam = time.perf_counter()
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
        slam_finish_s = time.perf_counter() - t_slam
        if not results:  # why: a SLAM's own failure, else what the reading skipped
            from kosmap.mapping.slam import nothing_reached_slam

            failed = [w.replace(" produced no trajectory", "") for w in warnings if "SLAM produced no trajectory" in w]
            raise KosmapError(f"{log.name}: {failed[0]}" if failed else nothing_reached_slam(log, "scan", warnings))
        rss["after_slam"] = peak_rss_mb()
        spill: Spill = p1["spill"]
        t_maps = time.perf_counter()
        jobs = _Jobs(workers, pool.executor if pool is not None else None)
        try:
            compares = _Compares(bp_grid, cfg, jobs)
            grids, traj = _pass2(spill, p1, results, cfg, out, files, bands, jobs, compares)
            maps_s = time.perf_counter() - t_maps
            say(f"SLAM solved in {slam_finish_s:.1f} s; {len(grids)} maps built and written in {maps_s:.1f} s")
            t_cmp = time.perf_counter()
            frames_png: Path | None | bool = True
            traj_png: Path | None | bool = True
            if report:  # drawn here while the workers compare (this process would only wait)
                from kosmap.mapping.report import frames_figure, trajectory_figure

                if has_depth:
                    frames_png = frames_figure(out)
                traj_png = trajectory_figure(out, {"sources": {"blueprint": None if blueprint is None else str(blueprint),
                                                               "blueprint_scale": blueprint_scale}})
            comparisons, overlays = compares.finish(out, files, warnings)
            compare_s = time.perf_counter() - t_cmp
        finally:
            jobs_rss = executor_peak_rss_mb(jobs.ex)  # read while they live: their own pool ends at close
            jobs.close()
        rss["after_maps_and_compare"] = peak_rss_mb()
        metrics = _metrics(log, det, info_counts=counts, duration=duration, p1=p1, results=results, grids=grids,
                           traj=traj, comparisons=comparisons, overlays=overlays, cfg=cfg, blueprint=blueprint,
                           workers=workers, warnings=warnings,
                           timing={"read_and_frames_s": p1["seconds"], "slam_finish_s": slam_finish_s,
                                   "maps_s": maps_s, "compare_s": compare_s})
        metrics = _renamed(metrics, str(out), str(final_out))  # the files' paths as they will be once in place
        if blueprint_scale is not None:  # a plain-image blueprint: the report's trajectory figure reads it again
            metrics["sources"]["blueprint_scale"] = blueprint_scale
        metrics["memory"] = {"peak_rss_mb_main": rss, "peak_rss_mb_workers": jobs_rss,
                             "peak_rss_mb_slam": {n: f.peak_rss_mb for n, f in feeds.items() if isinstance(f, RemoteFeed)}}
        metrics["timing"]["total_s"] = time.perf_counter() - t_start
        metrics["timing"]["cpu_s"] = time.process_time() - cpu_start
        metrics["timing"]["realtime_factor"] = (p1["log_s"] / metrics["timing"]["total_s"]
                                                if metrics["timing"]["total_s"] > 0 else None)
        files["metrics"] = _write_text(out / "metrics.json", json.dumps(json_safe(metrics), indent=2) + "\n")
        if report:
            from kosmap.mapping.report import write_report

            t_rep = time.perf_counter()
            files.update(write_report(out, metrics, frames_png, traj_png))
            # total_s and the real-time factor stay what the report shows (and the console prints): up to the report
            metrics["timing"]["report_s"] = time.perf_counter() - t_rep
            files["metrics"] = _write_text(out / "metrics.json", json.dumps(json_safe(metrics), indent=2) + "\n")
    except BaseException:  # failed, or stopped by a second Ctrl-C or SIGTERM: the previous build stays as it was
        discard(stage)
        raise
    finally:
        for feed in feeds.values():
            feed.close()
        if pool is not None:
            pool.close(cancel=True)
        shutil.rmtree(spill_dir, ignore_errors=True)
    try:
        files = {k: final_out / p.name if isinstance(p, Path) else p for k, p in files.items()}  # where they now are
        files["manifest"] = commit(stage, partial=bool(p1["partial"]))
    except BaseException:
        discard(stage)
        raise
    return BuildResult(final_out, json_safe(metrics), files)


def _expected_units(det, counts: dict, duration: float, bcfg) -> int:
    """Depth frames the run will process (or laser scans in a log without depth): the progress bar's total."""
    if det.depth:
        n = 0
        for t in det.depth:
            c = counts.get(t, 0)
            n += min(c, int(duration * bcfg.depth_rate) + 1) if bcfg.depth_rate > 0 else c
        return n
    c = counts.get(det.scan, 0)
    return min(c, int(duration * bcfg.laser_rate) + 1) if bcfg.laser_rate > 0 and c > 1.2 * bcfg.laser_rate * duration else c


def _pass1(log: Path, det, cfg: Config, counts: dict, duration: float, workers: int, progress: bool,
           on_progress, spill_dir: Path, warnings: list[str], pool: FramePool | None, kos_feed, laser_feed) -> dict:
    """Read the log once: frames to `pool` (the caller's, left open for pass 2), steps and laser scans to the
    SLAM feeds (ended here, solved by the caller) and the spill, stats to stats.csv."""
    bcfg = cfg.build
    out = spill_dir.parent
    spill = Spill(spill_dir)
    bands = [b[0] for b in cfg.kos.bands()]
    feeds = [f for f in (kos_feed, laser_feed) if f is not None]
    statics: list[Transforms] = []
    static_keys: set[tuple] = set()
    gt = array("d")  # t, x, y, yaw flattened
    stats = {k: array("f") for k in TABLE_5_2}
    state = {"frames": 0, "laser_kept": 0, "laser_seen": 0, "t0": None, "t": None, "end": None, "laser_mount": None,
             "last_laser": None, "last_fused": None, "laser_tf": None, "next_cloud": None, "base": "base_link",
             "stop": False, "partial": False}
    laser_period_ns = laser_period(bcfg.laser_rate, counts.get(det.scan, 0), duration) if det.scan else 0
    cloud_period = int(bcfg.mcap_planes_period * 1e9)
    run = ScanRun()
    total = _expected_units(det, counts, duration, bcfg)
    csv_path = out / "stats.csv.partial"
    csv_fh = open(csv_path, "w", newline="")
    writer = csv.writer(csv_fh)
    writer.writerow(STATS_COLUMNS)

    def cloud(item: DepthItem) -> int:
        """Plane points to keep of this frame for the MCAP: a cloud every mcap_planes_period seconds."""
        if cloud_period <= 0:
            return 0
        if state["next_cloud"] is None or item.stamp_ns >= state["next_cloud"] - 1_000_000:  # 1 ms: stamp jitter
            state["next_cloud"] = item.stamp_ns + cloud_period
            return bcfg.mcap_plane_points
        return 0

    def on_frame(f: KosFrame) -> None:
        s = f.stats
        row = {"ineligible_pct": s.ineligible_pct, "inlier_pct": s.inlier_pct, "dropped_pct": s.dropped_pct,
               "outlier_pct": s.outlier_pct, "planes": s.planes, "fspf_ms": f.fspf_ms, "kos_ms": f.kos_ms}
        for k, v in row.items():
            stats[k].append(float(v))
        writer.writerow([f.index, f.topic, f"{f.stamp_ns * 1e-9:.6f}", f"{s.ineligible_pct:.3f}", f"{s.inlier_pct:.3f}",
                         f"{s.dropped_pct:.3f}", f"{s.outlier_pct:.3f}", s.remaining, s.planes, f.n_points,
                         f"{f.fspf_ms:.3f}", f"{f.kos_ms:.3f}"])
        if f.cloud is not None and len(f.cloud[0]):  # subsampled in the frame stage (kosframe.plane_cloud)
            pts, cls = f.cloud
            mount = stream.cams[f.topic][1]  # set when the topic's first frame was read, before any result
            spill.add_cloud(f.stamp_ns, mount.apply(pts.astype(np.float64)), cls)
        state["frames"] += 1
        tick()

    bar = task = None

    def tick() -> None:
        t0, t = state["t0"], state["t"]
        log_s = (t - t0) * 1e-9 if t0 is not None and t is not None else 0.0
        if bar is not None:
            el = time.perf_counter() - t_begin
            done = state["frames"] if det.depth else state["laser_kept"]
            bar.update(task, completed=done, rate=f"{done / el:.0f}" if el > 0 else "–",
                       rt=f"{log_s / el:.1f}" if el > 0 else "–")
        if on_progress is not None:
            on_progress(Progress(state["frames"], state["laser_kept"], log_s, duration))

    def on_step(step: KosStep) -> None:
        ranges = np.stack([step.scans[b].ranges for b in bands])
        spill.kos.add(step.stamp_ns, ranges)
        sc = step.scans[bcfg.slam_scan]
        if kos_feed is not None:
            o = kos_feed.slam.ocfg
            kos_feed.push(step.stamp_ns, scan_points_base(sc.ranges, sc.angles, sc.valid(), None, o.min_range, o.max_range))
        laser = step.laser  # fused here, at the laser map's rate, not for every step (KosStream fuse=False)
        if laser is not None and bcfg.fused_map and laser_feed is not None:
            last = state["last_fused"]
            if last is None or laser.stamp_ns - last >= laser_period_ns - 1_000_000:
                if state["laser_tf"] is None:  # its matrix, made once
                    state["laser_tf"] = (lookup_static(statics, "base_link", laser.frame_id)
                                         or Transform.identity("base_link", laser.frame_id)).matrix()
                fused = fuse_with_laser(laser, state["laser_tf"], step.scans[OBSTACLE], KOS_PREFIX + FUSED)
                if spill.fused.add(fused.stamp_ns, fused.ranges):
                    state["last_fused"] = fused.stamp_ns
                    if not spill.fused.meta:
                        spill.fused.meta = {"angle_min": fused.angle_min, "angle_increment": fused.angle_increment,
                                            "range_min": fused.range_min, "range_max": fused.range_max,
                                            "frame_id": fused.frame_id}

    def on_laser(scan: Scan) -> None:
        state["laser_seen"] += 1
        last = state["last_laser"]
        if last is not None and scan.stamp_ns - last < laser_period_ns - 1_000_000:
            return
        if state["laser_mount"] is None:  # the same lookup as `kosmap slam` (mapping/slamfeed.py)
            state["laser_mount"], w = laser_mount(statics, state["base"], scan.frame_id)
            warnings.extend([w] if w else [])
        if not spill.laser.add(scan.stamp_ns, scan.ranges):
            return
        if not spill.laser.meta:
            spill.laser.meta = {"angle_min": scan.angle_min, "angle_increment": scan.angle_increment,
                                "range_min": scan.range_min, "range_max": scan.range_max, "frame_id": scan.frame_id,
                                "topic": scan.topic, "time_increment": scan.time_increment}
        state["last_laser"] = scan.stamp_ns
        state["laser_kept"] += 1
        laser_feed.push_laser(scan, state["laser_mount"])
        if not det.depth:
            tick()

    # Ctrl-C: finish what was read (a second Ctrl-C aborts)
    old_handler = None
    if threading.current_thread() is threading.main_thread():
        def _sigint(_sig, _frm):
            state["stop"] = True
            signal.signal(signal.SIGINT, old_handler or signal.default_int_handler)
        old_handler = signal.signal(signal.SIGINT, _sigint)

    stream = None
    if pool is not None:
        min_period = int(1e9 / bcfg.depth_rate) if bcfg.depth_rate > 0 else 0
        stream = KosStream(det, cfg, run, pool, on_frame=on_frame, cloud=cloud, min_period_ns=min_period,
                           fuse=False)
    t_begin = time.perf_counter()
    cpu0 = time.process_time()
    lg = open_log(log, cfg.topics.on_damage)
    try:
        if progress:
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
            from rich.progress import Progress as Bar

            bar = Bar(TextColumn("[bold]build[/]"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[unit]}, {task.fields[rate]}/s, {task.fields[rt]}× real time"),
                      TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=True)
            bar.start()
            task = bar.add_task("build", total=total, rate="–", rt="–",
                                unit="depth frames" if det.depth else "laser scans")
        try:
            for rec in lg.read_batched(det.wanted()):
                if state["stop"]:
                    raise KeyboardInterrupt
                batch = isinstance(rec, (OdometrySamples, ImuSamples))  # a stretch of samples (read_batched)
                # The log's "now" is where the record stands: a batch stands at its first sample, so the scans' odometry
                # timeout runs as in `read` (at its last, a chunk longer than ODOM_WAIT_S released scans whose odometry
                # was in the next chunk). Its last sample only extends how much log was read.
                st = rec.stamp_ns
                if st and (state["t"] is None or st > state["t"]):
                    state["t"] = st
                    if state["t0"] is None:
                        state["t0"] = st
                if batch and (state["end"] is None or rec.end_ns > state["end"]):
                    state["end"] = rec.end_ns
                if isinstance(rec, (Odometry, OdometrySamples)):
                    t, x, y, yaw = odometry_columns(rec)
                    if rec.topic == det.ground_truth:
                        gt.extend(np.column_stack((t * 1e-9, x, y, yaw)).ravel().tolist())
                        continue
                    if rec.topic == det.odom:
                        if state["base"] == "base_link" and rec.child_frame_id:
                            state["base"] = rec.child_frame_id.lstrip("/") or "base_link"
                        for f in feeds:
                            f.wheel_samples(t, x, y, yaw)
                elif isinstance(rec, ImuSamples):
                    if det.imu and rec.topic == det.imu:
                        ok = rec.has_angular_velocity  # (Slam.add_imu skips a sample without)
                        for f in feeds:
                            f.gyro_samples(rec.stamps_ns[ok], rec.yaw_rate[ok])
                elif isinstance(rec, Transforms) and rec.static:
                    key = tuple((t.parent, t.child, *np.asarray(t.translation, float).tolist(),
                                 *np.asarray(t.rotation, float).tolist()) for t in rec.transforms)
                    if key in static_keys:  # a recorder may republish /tf_static every second: kept once (here
                        continue  # and by the depth stream), not once per message for the whole run
                    static_keys.add(key)
                    statics.append(rec)
                elif det.imu and rec.topic == det.imu:
                    for f in feeds:
                        f.imu(rec)
                elif isinstance(rec, Scan) and rec.topic == det.scan and laser_feed is not None:
                    on_laser(rec)
                # (the gyro and odometry: nothing for the depth stream, which steps when it submits a frame)
                if stream is not None and not batch and not isinstance(rec, (Odometry, Imu)):
                    for step in stream.feed(rec):
                        on_step(step)
                for f in feeds:
                    f.advance(state["t"])
        except KeyboardInterrupt:
            state["partial"] = True
            if pool is not None:
                pool.drop()  # the frames in flight are not waited for; the workers stay for pass 2
        if not state["partial"] and stream is not None:
            for step in stream.flush():
                on_step(step)
        for f in feeds:
            f.end()
        run.warnings.extend(lg.warnings)
    finally:
        lg.close()
        if bar is not None:
            bar.stop()
        if old_handler is not None:
            signal.signal(signal.SIGINT, old_handler)
        csv_fh.close()
        spill.close()
    os.replace(csv_path, out / "stats.csv")
    warnings.extend(run.warnings)
    g = np.asarray(gt, np.float64).reshape(-1, 4)
    t0, t = state["t0"], max((x for x in (state["t"], state["end"]) if x is not None), default=None)
    return {"spill": spill, "frames": state["frames"], "laser_kept": state["laser_kept"],
            "laser_seen": state["laser_seen"], "partial": state["partial"],
            "seconds": time.perf_counter() - t_begin, "cpu_s": time.process_time() - cpu0,
            "log_s": (t - t0) * 1e-9 if t0 is not None and t is not None else 0.0, "t0_ns": t0,
            "laser_mount": state["laser_mount"],
            "gt": g, "stats": {k: np.asarray(v) for k, v in stats.items()}, "run": run, "statics": statics,
            "total": total}


# ---- pass 2: grids from the optimised poses, the MCAP ------------------------------------------------------------

def _init_job_worker(parent_pid: int) -> None:
    """A grid or comparison worker of a log without depth: Ctrl-C is the parent's; it dies with the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid)


class _Jobs:
    """Independent jobs (one grid, one comparison) in `workers` forked processes (the frame pool's `executor` when
    given: not shut down here), or here when workers = 0; results in submission order. The jobs read the spill
    from disk, so nothing large is copied to them."""

    def __init__(self, workers: int, executor=None) -> None:
        self.ex = executor if workers > 0 else None
        self.own = False
        if workers > 0 and self.ex is None:
            self.own = True
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
            self.ex = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_job_worker,
                                          initargs=(os.getpid(),))

    def submit(self, fn, *args):
        if self.ex is None:
            return _Done(fn(*args))
        return self.ex.submit(fn, *args)

    def close(self) -> None:
        if self.ex is not None and self.own:
            self.ex.shutdown(wait=True, cancel_futures=True)


class _Done:
    def __init__(self, v) -> None:
        self.v = v

    def done(self) -> bool:
        return True

    def result(self):
        return self.v


def _warm_grid() -> None:
    """Compile (or load) the grid kernel here, before forking: the jobs inherit it instead of compiling each."""
    GridBuilder().add(np.zeros(3), Scan(0, np.array([1.0, np.inf], np.float32), 0.0, 0.1, 0.1, 10.0))


def _scan_of(meta: dict, stamp: int, ranges: np.ndarray, topic: str = "") -> Scan:
    return Scan(int(stamp), np.asarray(ranges, np.float32), meta["angle_min"], meta["angle_increment"],
                meta["range_min"], meta["range_max"], meta.get("frame_id", ""), topic,
                time_increment=meta.get("time_increment", 0.0))


def _grid_job(gcfg, mount, path: str, width: int, band: tuple | None, meta: dict, stamps: np.ndarray,
              poses: np.ndarray, idx: np.ndarray) -> OccupancyGrid:
    """One log-odds grid from the spilled scans `idx` (rows of `path`; band k of B per row when `band` = (k, B))."""
    rows = _RowReader(path, width)
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
            b.add(poses[s], _scan_of(meta, stamps[s], r))
    finally:
        rows.close()
    return b.to_occupancy()


def _every(stamps: np.ndarray, rate: float) -> np.ndarray:
    """Indices of the stamps kept at most `rate` per second (all when rate is 0)."""
    if rate <= 0 or not len(stamps):
        return np.arange(len(stamps))
    period, keep, last = int(1e9 / rate) - 1_000_000, [], None
    for i, t in enumerate(stamps):
        if last is None or t - last >= period:
            keep.append(i)
            last = t
    return np.asarray(keep, np.int64)


def _pass2(spill: Spill, p1: dict, results: dict, cfg: Config, out: Path, files: dict, bands: list[str],
           jobs: _Jobs, compares: _Compares) -> tuple[dict, dict]:
    """Every grid from the spill and the optimised poses (one job per map, while this process writes the MCAP);
    maps (PNG, PGM+YAML), trajectories (TUM), the MCAP. Each finished grid starts its comparisons (`compares`)
    while the MCAP is still being written."""
    from kosmap.backend.trajio import write_tum
    from kosmap.mapping.mapio import grid_picture, write_map_server, write_png

    bcfg = cfg.build
    traj = {name: {"stamps_ns": res.stamps_ns, "poses": res.poses} for name, res in results.items()}
    kos_stamps = np.asarray(spill.kos.stamps, np.int64)
    bear = p1["run"].bearings
    kos_meta = None
    if bear is not None:
        kos_meta = {"angle_min": bear.angle_min, "angle_increment": bear.angle_increment,
                    "range_min": cfg.depth.min_depth, "range_max": cfg.depth.max_depth, "frame_id": "base_link"}
    laser_mount = tuple(p1["laser_mount"]) if p1["laser_mount"] is not None else (0.0, 0.0, 0.0)

    def poses_at(name: str, stamps: np.ndarray) -> np.ndarray:
        r = results[name]
        if np.array_equal(r.stamps_ns, stamps):
            return r.poses
        return se2.interpolate(r.stamps_ns.astype(np.float64), r.poses, stamps.astype(np.float64))

    specs: list[tuple[str, dict, tuple]] = []  # (name, info, job args)
    kos_idx = _every(kos_stamps, bcfg.kos_map_rate)
    if len(kos_stamps) and "kos" in results:
        poses = poses_at("kos", kos_stamps)
        for k, b in enumerate(bands):
            specs.append((f"kos_{b}", {"source": "kos", "level": b, "poses": "kos", "scans": len(kos_idx),
                                       "label": f"KOS {b}" + (" (SLAM scan)" if b == bcfg.slam_scan else "")},
                          ((0.0, 0.0, 0.0), spill.kos, (k, len(bands)), kos_meta, kos_stamps, poses, kos_idx)))
    if len(kos_stamps) and "laser" in results and bcfg.kos_on_laser_poses:
        specs.append(("kos_obstacle_at_laser_poses", {"source": "kos", "level": OBSTACLE, "poses": "laser",
                                                      "scans": len(kos_idx), "label": "KOS obstacle at the laser's poses"},
                      ((0.0, 0.0, 0.0), spill.kos, (bands.index(OBSTACLE), len(bands)), kos_meta, kos_stamps,
                       poses_at("laser", kos_stamps), kos_idx)))
    for name, series, level, label in (("laser", spill.laser, None, "laser"),
                                       ("fused", spill.fused, FUSED, "KOS obstacle fused with the laser")):
        if "laser" in results and len(series):  # both on the laser's poses, at laser_map_rate
            st = np.asarray(series.stamps, np.int64)
            idx = _every(st, bcfg.laser_map_rate)
            specs.append((name, {"source": name, "level": level, "poses": "laser", "scans": len(idx), "label": label},
                          (laser_mount, series, None, series.meta, st, poses_at("laser", st), idx)))
    # Longest first (beams to trace: scans × beams per scan), so that no long job starts last while the other
    # worker idles (Graham's LPT rule): the laser and fused maps trace ~4× a KOS map's beams.
    futures: list = [None] * len(specs)
    cost = [len(idx) * (series.width // (band[1] if band else 1)) for _, _, (_, series, band, _, _, _, idx) in specs]
    for k in sorted(range(len(specs)), key=lambda k: -cost[k]):
        mount, series, band, meta, st, poses, idx = specs[k][2]
        series.close()
        futures[k] = jobs.submit(_grid_job, cfg.grid, mount, str(series.path), series.width, band, meta, st, poses, idx)
    compares.expect([name for name, _, _ in specs])

    def poll() -> None:
        """Hand every finished grid to the comparisons (called between batches of MCAP messages)."""
        for (name, _, _), fut in zip(specs, futures):
            if fut.done():
                compares.grid_ready(name, fut.result())

    for name, tr in traj.items():
        files[f"trajectory_{name}"] = write_tum(out / f"trajectory_{name}.tum", tr["stamps_ns"] * 1e-9, tr["poses"])
    g = p1["gt"]
    if len(g):
        files["ground_truth"] = write_tum(out / "ground_truth.tum", g[:, 0], g[:, 1:4])
    res = results.get("kos") or results.get("laser")
    ok = np.isfinite(res.odom_poses).all(axis=1)
    if ok.sum() >= 2:  # the wheel odometry at the scans' stamps: the baseline SLAM should beat
        files["odometry"] = write_tum(out / "odometry.tum", res.stamps[ok], res.odom_poses[ok])

    grids: dict[str, dict] = {}

    def collect() -> dict:
        for (name, info, _), fut in zip(specs, futures):
            grid = fut.result()
            compares.grid_ready(name, grid)
            tr = traj.get(info["poses"])
            png = write_png(grid_picture(grid, None if tr is None else tr["poses"]), out / f"map_{name}.png")
            yml = write_map_server(grid, out / f"map_{name}.yaml")
            files[f"map_{name}"] = yml
            grids[name] = {"grid": grid, "png": png, "yaml": yml, **info,
                           "occupied_cells": int((grid.data >= 65).sum()), "known_cells": int((grid.data >= 0).sum())}
        return grids

    files["mcap"] = _write_mcap(out / "kosmap.mcap", spill, p1, results, collect, bands, kos_meta, kos_stamps, poll)
    return grids, traj


def _write_mcap(path: Path, spill: Spill, p1: dict, results: dict, grids_when_done: Callable[[], dict],
                bands: list[str], kos_meta, kos_stamps, poll: Callable[[], None] = lambda: None) -> Path:
    """One MCAP for Foxglove: KOS scans per level, the laser and fused scans used, plane points (a subsample),
    map → base_link on /tf (from the KOS SLAM, else the laser's), the paths, and every map. `poll` is called
    between batches of messages."""
    from kosmap.frontend.logs.writer import McapWriter

    primary = "kos" if "kos" in results else "laser"
    pres = results[primary]
    # (stamp, kind, index) of every message, written in time order: three int64 arrays (24 bytes a message), not
    # a list of tuples (~100 bytes each)
    parts = [np.asarray(kos_stamps, np.int64), np.array(spill.laser.stamps, np.int64),
             np.array(spill.fused.stamps, np.int64),
             np.array([c[0] for c in spill.cloud_index], np.int64).reshape(-1), np.asarray(pres.stamps_ns, np.int64)]
    ev_t = np.concatenate(parts)
    ev_k = np.concatenate([np.full(len(a), k, np.int64) for k, a in enumerate(parts)])
    ev_i = np.concatenate([np.arange(len(a), dtype=np.int64) for a in parts])
    order = np.lexsort((ev_i, ev_k, ev_t))
    kos_rows, laser_rows, fused_rows, plane_rows = (spill.kos.reader(), spill.laser.reader(), spill.fused.reader(),
                                                    spill.planes.reader())
    t_end = int(ev_t.max()) if len(ev_t) else 0
    with McapWriter(path) as w:
        for rec in p1["statics"]:
            w.write(rec, "/tf_static")
        for c in range(0, len(order), 1024):
            poll()
            sel = order[c:c + 1024]
            for stamp, kind, i in zip(ev_t[sel].tolist(), ev_k[sel].tolist(), ev_i[sel].tolist()):
                if kind == 0:
                    r = kos_rows.get(i).reshape(len(bands), -1)
                    for k, b in enumerate(bands):
                        w.write(_scan_of(kos_meta, stamp, r[k]), KOS_PREFIX + b)
                elif kind == 1:
                    w.write(_scan_of(spill.laser.meta, stamp, laser_rows.get(i)), spill.laser.meta.get("topic") or "/scan")
                elif kind == 2:
                    w.write(_scan_of(spill.fused.meta, stamp, fused_rows.get(i)), KOS_PREFIX + FUSED)
                elif kind == 3:
                    _, first, n = spill.cloud_index[i]
                    rows = plane_rows.block(first, n)
                    w.write_pointcloud(PLANES_TOPIC, stamp, "base_link", rows[:, :3], {"class": rows[:, 3]})
                else:
                    x, y, yaw = pres.poses[i]
                    tf = Transform("map", "base_link", np.array([x, y, 0.0]), yaw_to_quat(float(yaw)), stamp)
                    w.write(Transforms(stamp, (tf,), False, "/tf"), "/tf")
        for name, res in results.items():
            step = max(1, len(res.poses) // 2000)
            w.write_path(f"/kosmap/path/{name}", t_end, "map", res.poses[::step], res.stamps_ns[::step])
        g = p1["gt"]
        if len(g):
            step = max(1, len(g) // 2000)
            w.write_path("/kosmap/path/ground_truth", t_end, "map", g[::step, 1:4], (g[::step, 0] * 1e9).astype(np.int64))
        for name, gi in grids_when_done().items():
            gr: OccupancyGrid = gi["grid"]
            w.write_grid(f"/kosmap/map/{name}", t_end, "map", gr.data, gr.resolution, gr.origin)
    for r in (kos_rows, laser_rows, fused_rows, plane_rows):
        r.close()
    return path


# ---- comparisons --------------------------------------------------------------------------------------------------

def _compare_job(a: OccupancyGrid, b: OccupancyGrid, ccfg, more: tuple = ()) -> list[tuple]:
    """A vs B, then each map of `more` vs B through A's alignment (maps made on A's poses share A's frame): per map,
    (metrics, overlay picture, None) or (None, None, why not)."""
    from kosmap.mapping.compare import Alignment, CompareError, align, compare, overlay_picture

    try:
        alignment = align(a, b, ccfg) if ccfg.align else Alignment()
    except CompareError as e:  # A does not align: nor does what shares its frame
        return [(None, None, str(e))] * (1 + len(more))
    out: list[tuple] = []
    for grid in (a, *more):
        try:
            c = compare(grid, b, ccfg, alignment)
        except CompareError as e:
            out.append((None, None, str(e)))
            continue
        out.append((c.metrics, overlay_picture(c), None))
    return out


# Maps made on the laser SLAM's poses share the laser map's frame: compared with the blueprint through the laser map's
# alignment, not one of their own (which could shift a map to hide its errors, and cost ~2 s a map).
ON_LASER_POSES = ("fused", "kos_obstacle_at_laser_poses")


class _Compares:
    """KOS vs blueprint, laser vs blueprint (with the maps on the laser's poses), KOS vs laser (and the extra maps vs
    blueprint), one job each, each submitted as soon as its maps exist: the workers compare while this process
    still writes the MCAP (started after every map, they left the workers idle for the MCAP's seconds and this
    process for theirs)."""

    def __init__(self, bp: OccupancyGrid | None, cfg: Config, jobs: _Jobs) -> None:
        self.bp, self.cfg, self.jobs = bp, cfg, jobs
        self.pairs: list[tuple[str, str]] = []
        self.joined: dict[tuple[str, str], tuple[str, ...]] = {}  # a job's pair → the maps compared with A's alignment
        self.grids: dict[str, OccupancyGrid] = {}
        self.futures: dict[tuple[str, str], Any] = {}

    def expect(self, names: list[str]) -> None:
        """The maps pass 2 will make, in its order: they fix the pairs and the order of the results."""
        bcfg = self.cfg.build
        kos_main = f"kos_{bcfg.slam_scan}"
        self.pairs = []
        if self.bp is not None:
            for name in names:
                if name == kos_main or name in ("laser", *ON_LASER_POSES) or \
                        (bcfg.compare_levels and name.startswith("kos_")):
                    self.pairs.append((name, "blueprint"))
        if kos_main in names and "laser" in names:
            self.pairs.append((kos_main, "laser"))
        self.joined = {}
        if ("laser", "blueprint") in self.pairs:
            self.joined[("laser", "blueprint")] = tuple(n for n in ON_LASER_POSES if (n, "blueprint") in self.pairs)

    def grid_ready(self, name: str, grid: OccupancyGrid) -> None:
        """Submit every comparison whose maps are now all there."""
        self.grids[name] = grid
        riders = {n for more in self.joined.values() for n in more}
        for a, b in self.pairs:
            more = self.joined.get((a, b), ())
            ready = all(n in self.grids for n in (a, *more)) and (b == "blueprint" or b in self.grids)
            if ready and (a, b) not in self.futures and not (b == "blueprint" and a in riders):
                other = self.bp if b == "blueprint" else self.grids[b]
                self.futures[(a, b)] = self.jobs.submit(_compare_job, self.grids[a], other, self.cfg.compare,
                                                        tuple(self.grids[n] for n in more))

    def finish(self, out: Path, files: dict, warnings: list[str]) -> tuple[dict, dict]:
        """Every comparison's metrics and overlay picture (written), in the pairs' order."""
        from kosmap.mapping.mapio import write_png

        results = {}
        for pair, fut in self.futures.items():
            got = fut.result()
            for k, (name, res) in enumerate(zip((pair[0], *self.joined.get(pair, ())), got)):
                if k and res[0] is not None:
                    res[0]["alignment"]["from"] = pair[0]  # the map whose alignment it shares
                elif k and got[0][0] is None:  # (its error is the first map's: say whose)
                    res = (None, None, f"the {pair[0]} map, whose alignment it shares, did not align: {res[2]}")
                results[(name, pair[1])] = res
        comparisons, overlays = {}, {}
        for a, b in self.pairs:
            if (a, b) not in results:  # a map that was not made
                continue
            key = f"{a}_vs_{b}"
            metrics, img, err = results[(a, b)]
            if err is not None:
                warnings.append(f"{key}: {err}")
                continue
            comparisons[key] = {"a": a, "b": b, **metrics}
            overlays[key] = files[f"overlay_{key}"] = write_png(img, out / f"overlay_{key}.png")
        return comparisons, overlays


# ---- metrics ------------------------------------------------------------------------------------------------------

def _metrics(log: Path, det, info_counts: dict, duration: float, p1: dict, results: dict, grids: dict, traj: dict,
             comparisons: dict, overlays: dict, cfg: Config, blueprint, workers: int, warnings: list[str],
             timing: dict) -> dict:
    from kosmap.backend import metrics as M
    from kosmap.mapping.slam import evaluate, summary

    st = p1["stats"]
    frames = p1["frames"]
    slam = {}
    g = p1["gt"]
    for name, res in results.items():
        s = summary(res)
        s.pop("warnings", None)
        acc = {}
        if len(g) >= 2:
            try:
                acc = evaluate(res, ground_truth=(g[:, 0], g[:, 1:4]))
                ok = np.isfinite(res.odom_poses).all(axis=1)
                if ok.sum() >= 2:
                    acc["ate_odometry"] = M.ate(res.stamps[ok], res.odom_poses[ok], g[:, 0], g[:, 1:4])
            except KosmapError as e:
                warnings.append(f"{name} trajectory not scored against the ground truth: {e}")
        slam[name] = {**s, **acc, "scans_in": int(len(res.stamps_ns))}
    pass1 = timing["read_and_frames_s"]
    fspf, kos = st["fspf_ms"], st["kos_ms"]
    t52 = {k: _stats(st[k]) for k in TABLE_5_2}
    t55 = {"fspf_ms": _stats(fspf), "kos_ms": _stats(kos),
           "per_core_hz": 1000.0 / float(np.mean(fspf + kos)) if frames else None,
           "system_hz": frames / pass1 if pass1 > 0 and frames else None,
           "map_creation_s": timing["maps_s"] + timing["slam_finish_s"],
           "workers": workers}
    depth_in_log = sum(info_counts.get(t, 0) for t in det.depth)
    return {
        "kosmap": "build", "partial": p1["partial"],
        "log": {"path": str(log), "duration_s": duration, "read_s": p1["log_s"], "topics": det.as_dict()},
        "interrupted_at_s": p1["log_s"] if p1["partial"] else None,
        "sources": {"kos": bool(det.depth), "laser": bool(det.scan), "ground_truth": bool(len(g)),
                    "blueprint": None if blueprint is None else str(blueprint)},
        "frames": {"processed": frames, "in_log": depth_in_log, "cameras": len(det.depth),
                   "steps": len(p1["spill"].kos), "depth_rate_hz": cfg.build.depth_rate,
                   "laser_scans_in_log": info_counts.get(det.scan, 0) if det.scan else 0,
                   "laser_scans_read": p1["laser_seen"], "laser_scans_used": p1["laser_kept"],
                   "laser_rate_hz": cfg.build.laser_rate},
        "table_5_2": t52, "table_5_5": t55,
        "timing": {**timing, "read_and_frames_cpu_s": p1["cpu_s"], "log_s": p1["log_s"]},
        "slam": slam, "slam_scan": cfg.build.slam_scan,
        "maps": {k: {kk: v for kk, v in gi.items() if kk != "grid"} | {
            "width": gi["grid"].width, "height": gi["grid"].height, "resolution": gi["grid"].resolution,
            "origin": list(gi["grid"].origin)} for k, gi in grids.items()},
        "comparisons": comparisons, "overlays": {k: str(v) for k, v in overlays.items()},
        "config": config_dict(cfg), "warnings": list(dict.fromkeys(warnings)),
    }
