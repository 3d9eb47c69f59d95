"""`build`: the stages of `kosmap build` in their order (the package's doc says what each does)."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from kosmap.backend.slam import SlamResult
from kosmap.frontend.errors import ConfigError, KosmapError, TopicError
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.mapping.build.compares import Compares
from kosmap.mapping.build.grids import GridsInFlight, MapOut, plan_grids, write_trajectories
from kosmap.mapping.build.jobs import Jobs, warm_grid
from kosmap.mapping.build.mcap import write_mcap
from kosmap.mapping.build.metrics import Timing, build_metrics
from kosmap.mapping.build.readpass import LogSources, Progress, ReadPass, ReadResult
from kosmap.mapping.build.slams import kos_slam_configs, solve_slams, start_slams
from kosmap.mapping.config import Config, write_config
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.lasercal import write_mount_toml
from kosmap.mapping.mapio import read_blueprint
from kosmap.mapping.report import frames_figure, trajectory_figure, write_report
from kosmap.mapping.runtime.framepool import FramePool, check_workers, default_workers, executor_peak_rss_mb, peak_rss_mb
from kosmap.mapping.runtime.outdir import (SPILL_PREFIX, abandon, check_out, claim, commit, discard,
                                           holds_complete_run)
from kosmap.mapping.runtime.slamproc import RemoteFeed

OUTPUTS = ("metrics.json", "report.html", "report.md", "map_*.png", "map_*.pgm", "map_*.yaml", "overlay_*.png",
           "trajectory_*.tum", "ground_truth.tum", "odometry.tum", "stats.csv", "kosmap.mcap", "summary.png",
           "frames.png", "trajectories.png", "mount.toml")  # what a build writes into its folder (removed first when present)
BUILD_FILES = OUTPUTS + ("config.toml",)  # and its effective config: mapping/runtime/outdir.py tells ours from the user's


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


def build(log: str | Path, out_dir: str | Path, cfg: Config | None = None, blueprint: str | Path | None = None,
          workers: int | None = None, on_progress: Callable[[Progress], None] | None = None,
          report: bool = True, say: Callable[[str], None] | None = None,
          blueprint_scale: float | None = None, reads: tuple = ()) -> BuildResult:
    """Build every map of `log` into `out_dir` (the package's doc); returns the metrics and the files written.

    `workers`: processes for the per-frame stage (None = every core, 0 = serial in this process; the maps are
    the same). `on_progress`: called after each frame (or laser scan in a log without depth); raising
    KeyboardInterrupt there stops the run like Ctrl-C. `say`: where phase messages go (None = nowhere).
    `blueprint_scale`: metres per pixel of a plain-image blueprint (None for a map_server YAML, which has its
    resolution). `reads`: other files the run reads (--config): like the log and the blueprint, never replaced by
    an output in `out_dir`.
    """
    t_start, cpu_start = time.perf_counter(), time.process_time()
    cfg = cfg or Config()
    log, out = Path(log), Path(out_dir)
    say = say or (lambda _m: None)
    workers = default_workers() if workers is None else check_workers(int(workers))
    check_out(out)
    # everything that can be refused is refused before the folder is touched
    bp_grid = None if blueprint is None else read_blueprint(blueprint, blueprint_scale, cfg.compare.blueprint_dark)
    src = inspect_log(log, cfg)
    kos_cfgs = kos_slam_configs(cfg)
    bp_files = () if blueprint is None else (Path(blueprint), *(Path(blueprint).with_suffix(x) for x in (".png", ".pgm")))
    # a file of the user's, or one this run reads, under one of our names stops here; the run writes into a staging
    # folder whose files replace the previous build's only when it completes (mapping/runtime/outdir.py)
    final_out, stage = out, None
    warnings: list[str] = []
    pool: FramePool | None = None
    feeds: dict = {}
    spill_dir = None
    try:
        stage = claim(final_out, BUILD_FILES, inputs=(log, *bp_files, *reads))
        out = stage.dir
        spill_dir = Path(tempfile.mkdtemp(prefix=SPILL_PREFIX, dir=out))
        files: dict[str, Path] = {"config": write_config(cfg, out / "config.toml")}
        # One set of worker processes for the whole build, forked now while this process is small: the frames in
        # pass 1, then the grid and comparison jobs. Workers forked after pass 1 counted every page of this process
        # (by then holding SLAM's state) as their own resident memory: 167 → 259 MB from a 1- to a 10-minute log.
        warm_grid()  # compiled (or loaded) before the fork: every worker inherits the grid kernel
        start_slams(feeds, src, cfg, kos_cfgs, workers)
        if src.has_depth:
            pool = FramePool(cfg.fspf, cfg.depth, cfg.kos, workers, cfg.build.in_flight or None)
        read = ReadPass(src, cfg, spill_dir, warnings, pool, feeds.get("kos"), feeds.get("laser"), on_progress).read(log)
        if read.partial and holds_complete_run(final_out, "build"):
            raise BuildInterrupted(f"interrupted after {read.log_s:.1f} s of log; the complete build already in "
                                   f"{final_out} is kept (run again to replace it)")
        rss = {"after_read": peak_rss_mb()}
        if read.run.gravity is not None:
            say("\n".join(read.run.gravity.lines()))
        files |= write_mount_toml(out, read.run.laser_alignment, warnings, say)
        say(("interrupted: mapping what was read, " if read.partial else "")
            + f"{read.frames} depth frames, {read.laser_kept} laser scans read in {read.seconds:.1f} s")
        t_slam = time.perf_counter()
        results = solve_slams(feeds, log, warnings)
        slam_finish_s = time.perf_counter() - t_slam
        rss["after_slam"] = peak_rss_mb()
        jobs = Jobs(workers, pool.executor if pool is not None else None)
        try:
            t_maps = time.perf_counter()
            compares = Compares(bp_grid, cfg, jobs)
            maps = make_maps(read, results, cfg, out, files, jobs, compares)
            maps_s = time.perf_counter() - t_maps
            say(f"SLAM solved in {slam_finish_s:.1f} s; {len(maps)} maps built and written in {maps_s:.1f} s")
            t_cmp = time.perf_counter()
            figures = draw_figures(out, src, blueprint, blueprint_scale) if report else (True, True)
            comparisons, overlays = compares.finish(out, files, warnings)
            compare_s = time.perf_counter() - t_cmp
        finally:
            jobs_rss = executor_peak_rss_mb(jobs.ex)  # read while they live: their own pool ends at close
            jobs.close()
        rss["after_maps_and_compare"] = peak_rss_mb()
        metrics = build_metrics(log, src, read, results, maps, comparisons, overlays, cfg, blueprint, workers, warnings,
                                Timing(read.seconds, slam_finish_s, maps_s, compare_s))
        metrics = _renamed(metrics, str(out), str(final_out))  # the files' paths as they will be once in place
        # where the depth cameras' gravity came from, and the mounts it gave (mapping/gravitymount.py); the camera's
        # yaw and x, y against the laser (mapping/lasercal.py)
        metrics["gravity"] = read.run.gravity.as_dict() if read.run.gravity is not None else None
        metrics["laser_alignment"] = read.run.laser_alignment
        if blueprint_scale is not None:  # a plain-image blueprint: the report's trajectory figure reads it again
            metrics["sources"]["blueprint_scale"] = blueprint_scale
        metrics["memory"] = {"peak_rss_mb_main": rss, "peak_rss_mb_workers": jobs_rss,
                             "peak_rss_mb_slam": {n: f.peak_rss_mb for n, f in feeds.items() if isinstance(f, RemoteFeed)}}
        write_metrics_and_report(out, metrics, files, read, t_start, cpu_start, figures if report else None)
    except BaseException:  # failed, or stopped by a second Ctrl-C or SIGTERM: the previous build stays as it was
        abandon(final_out, stage)
        raise
    finally:
        for feed in feeds.values():
            feed.close()
        if pool is not None:
            pool.close(cancel=True)
        if spill_dir is not None:
            shutil.rmtree(spill_dir, ignore_errors=True)
    try:
        files = {k: final_out / p.name if isinstance(p, Path) else p for k, p in files.items()}  # where they now are
        files["manifest"] = commit(stage, partial=read.partial)
    except BaseException:
        discard(stage)
        raise
    return BuildResult(final_out, json_safe(metrics), files)


def inspect_log(log: Path, cfg: Config) -> LogSources:
    """The log's topics, counts and duration from its index; a log with nothing to map, or a [build] slam_scan that
    is no KOS scan of the config, is refused here."""
    with open_log(log, cfg.topics.on_damage) as lg:
        info = lg.info()
        det = detect_topics(info.types(), cfg.topics)
        src = LogSources(det, {t: info.count(t) for t in info.types()}, float(info.duration))
    if not src.has_depth and not src.has_laser:
        raise TopicError(f"{log.name} has neither a depth image topic nor a laser scan topic: nothing to map "
                         f"(see `kosmap info {log.name}`; name them with --depth-topic / --scan-topic)")
    bands = [b[0] for b in cfg.kos.bands()]
    if src.has_depth and cfg.build.slam_scan not in bands:
        raise ConfigError(f"config [build] slam_scan = {cfg.build.slam_scan!r} is not a KOS scan of this config; "
                          f"choose one of {', '.join(bands)}")
    return src


def make_maps(read: ReadResult, results: dict[str, SlamResult], cfg: Config, out: Path, files: dict[str, Path],
              jobs: Jobs, compares: Compares) -> dict[str, MapOut]:
    """Pass 2: the grids (jobs), the trajectories and, while the grids are built, the MCAP; each grid starts its
    comparisons as soon as it is done."""
    grids = GridsInFlight(plan_grids(read, results, cfg), cfg, jobs, compares)
    write_trajectories(out, results, read.gt, files)
    maps: dict[str, MapOut] = {}

    def written() -> dict:
        maps.update(grids.collect(out, results, files))
        return {name: m.grid for name, m in maps.items()}

    files["mcap"] = write_mcap(out / "kosmap.mcap", read.spill, read.statics, read.gt, results, written, grids.poll)
    return maps


def draw_figures(out: Path, src: LogSources, blueprint, blueprint_scale) -> tuple:
    """The report's frame and trajectory figures, drawn while the workers compare (this process would only wait)."""
    frames_png = frames_figure(out) if src.has_depth else True
    traj_png = trajectory_figure(out, {"sources": {"blueprint": None if blueprint is None else str(blueprint),
                                                   "blueprint_scale": blueprint_scale}})
    return frames_png, traj_png


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


def _write_json(path: Path, doc: dict) -> Path:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(json_safe(doc), indent=2) + "\n")
    os.replace(tmp, path)
    return path


def write_metrics_and_report(out: Path, metrics: dict, files: dict[str, Path], read: ReadResult, t_start: float,
                             cpu_start: float, figures: tuple | None) -> None:
    """metrics.json with the totals, then (with `figures`) the report; total_s and the real-time factor stay what
    the report shows (and the console prints): up to the report."""
    t = metrics["timing"]
    t["total_s"] = time.perf_counter() - t_start
    t["cpu_s"] = time.process_time() - cpu_start
    t["realtime_factor"] = read.log_s / t["total_s"] if t["total_s"] > 0 else None
    files["metrics"] = _write_json(out / "metrics.json", metrics)
    if figures is not None:
        t_rep = time.perf_counter()
        files.update(write_report(out, metrics, *figures))
        t["report_s"] = time.perf_counter() - t_rep
        files["metrics"] = _write_json(out / "metrics.json", metrics)
