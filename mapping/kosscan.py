"""`kosmap scan`: a log's depth frames → FSPF+ → multi-level KOS scans, fused with the laser, written out.

Outputs (thesis §5.3, Fig. 5.13–5.20): an MCAP with sensor_msgs/LaserScan per level on /kinect_scan/<level>
(plus the obstacle and fused scans, the laser and /tf_static, so Foxglove overlays them), the scan points as
CSV (the thesis stored them in text files), top-view figures of laser and levels, stats and the config.
"""

from __future__ import annotations

import csv
import json
import math
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kosmap.frontend.camera import lookup_static
from kosmap.frontend.depthstream import DepthItem, DepthResolver
from kosmap.frontend.errors import LogError, TopicError
from kosmap.frontend.kos import FUSED, OBSTACLE, Bearings, bearings_for, camera_view, fuse_with_laser, in_view
from kosmap.frontend.kosframe import KosFrame, merge_cameras
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.records import DepthFrame, Scan, Transform, Transforms
from kosmap.mapping.config import Config, write_config
from kosmap.mapping.framepool import FramePool
from kosmap.mapping.mapio import save_figure

KOS_PREFIX = "/kinect_scan/"


class CameraSync:
    """Groups frames of several cameras into time steps: each frame of the first topic, with every other
    topic's frame nearest in time (within `tol_ns`)."""

    def __init__(self, topics: list[str], tol_ns: int) -> None:
        self.primary, self.others = topics[0], topics[1:]
        self.tol = tol_ns
        self.pending: deque[KosFrame] = deque()
        self.recent: dict[str, deque[KosFrame]] = {t: deque() for t in self.others}

    def push(self, f: KosFrame) -> list[list[KosFrame]]:
        (self.pending if f.topic == self.primary else self.recent[f.topic]).append(f)
        return self._ready(f.stamp_ns)

    def flush(self) -> list[list[KosFrame]]:
        return self._ready(None)

    def _ready(self, now: int | None) -> list[list[KosFrame]]:
        out = []
        while self.pending and (now is None or not self.others or self.pending[0].stamp_ns + self.tol < now):
            p = self.pending.popleft()
            step = [p]
            for t in self.others:
                q = self.recent[t]
                while q and q[0].stamp_ns < p.stamp_ns - self.tol:
                    q.popleft()
                near = [f for f in q if abs(f.stamp_ns - p.stamp_ns) <= self.tol]
                if near:
                    step.append(min(near, key=lambda f: abs(f.stamp_ns - p.stamp_ns)))
            out.append(step)
        return out


class _RawDepth(DepthFrame):
    """A 16UC1 frame whose `meters()` is the raw image: the frame stage converts it (mapping/framepool.py), in the
    worker when there are workers, so the reading process neither converts nor ships float32 frames."""

    def meters(self) -> np.ndarray:
        return self.image


@dataclass
class KosStep:
    """One time step: the merged KOS scans of every level (and the fused scan when a laser is near in time)."""

    stamp_ns: int
    scans: dict[str, Scan]
    frames: list[KosFrame]
    laser: Scan | None = None


@dataclass
class ScanRun:
    """Everything `kos_steps` learned about the log besides the steps themselves."""

    topics: dict = field(default_factory=dict)
    bearings: Bearings | None = None
    laser_mount: Transform | None = None
    statics: list[Transforms] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    total_frames: int = 0


class KosStream:
    """FSPF+ → KOS per depth frame, cameras merged per time step, fused with the nearest laser scan: fed the
    records of a log one by one (`feed`), it returns the finished steps; `flush` at the end returns the rest.

    The per-frame work goes to a `FramePool` (serial or a process pool). What a step sees besides its frames
    (the lasers and cameras read so far) is captured when its frame is read, so a step is the same however
    far the pool runs behind the reader: serial and parallel runs give identical steps.
    """

    def __init__(self, det, cfg: Config, run: ScanRun, pool: FramePool, limit: int | None = None,
                 on_frame: Callable[[KosFrame], None] | None = None,
                 cloud: Callable[[DepthItem], int] | None = None, min_period_ns: int = 0,
                 fuse: bool = True) -> None:
        self.det, self.cfg, self.run, self.pool = det, cfg, run, pool
        self.limit = None if limit is None else limit * len(det.depth)
        self.on_frame = on_frame
        self.cloud = cloud  # plane points to keep of a frame (KosFrame.cloud; 0 = none)
        self.min_period = int(min_period_ns)  # per camera: frames closer in time than this to the last kept are skipped
        self._last: dict[str, int] = {}
        self.fuse = fuse  # add the scan fused with the laser to each step (else the step only names its laser)
        self._seen: dict[tuple, np.ndarray] = {}  # bins in view, per set of cameras
        self.resolver = DepthResolver(det, cfg.depth)
        self.sync = CameraSync(det.depth, tol_ns=25_000_000)
        self.cams: dict[str, tuple] = {}
        self.lasers: deque[Scan] = deque(maxlen=16)
        self.submitted = 0
        self.stopped = False  # a frame beyond the limit arrived: the caller stops reading
        run.topics = det.as_dict()

    def _view(self) -> tuple:
        return tuple(self.lasers), tuple(self.cams.values())

    def feed(self, rec) -> list[KosStep]:
        """Absorb one record (depth frames go to the pool); the steps finished by now."""
        if isinstance(rec, Scan) and rec.topic == self.det.scan:
            self.lasers.append(rec)
            return []
        if self.min_period and isinstance(rec, DepthFrame) and rec.topic in self.det.depth:
            last = self._last.get(rec.topic)
            if last is not None and rec.stamp_ns - last < self.min_period - 1_000_000:  # 1 ms slack for stamp jitter
                self.resolver.count += 1  # the frame keeps its index (its seed) whether or not others are skipped
                return []
            self._last[rec.topic] = rec.stamp_ns
        if isinstance(rec, DepthFrame) and rec.encoding == "16UC1":
            rec = _RawDepth(rec.stamp_ns, rec.image, rec.encoding, rec.frame_id, rec.topic)
        item = self.resolver.observe(rec)
        if isinstance(rec, Transforms) and rec.static:
            self.run.statics.append(rec)
        if item is None:
            return []
        if self.limit is not None and self.submitted >= self.limit:
            self.stopped = True
            return []
        run, cfg = self.run, self.cfg
        if item.topic not in self.cams:
            self.cams[item.topic] = (item.camera, item.mount)
            if run.bearings is None:
                # the grid of bins is fixed by the first frame: one camera's view, or a full circle for several
                if len(self.det.depth) == 1:
                    run.bearings = bearings_for([(item.camera, item.mount)], cfg.kos.angle_increment_deg)
                else:
                    inc = cfg.kos.angle_increment_deg or math.degrees(
                        (lambda v: (v[1] - v[0]) / (item.camera.width - 1))(camera_view(item.camera, item.mount)))
                    run.bearings = bearings_for([(item.camera, item.mount)] * 2, inc)
        self.pool.submit(item, run.bearings, False, self._view(), self.cloud(item) if self.cloud else 0)
        self.submitted += 1
        return self._collect(False)

    def flush(self) -> list[KosStep]:
        """Wait for every frame in flight; the remaining steps."""
        steps = self._collect(True)
        view = self._view()
        return steps + [self._finish(s, view) for s in self.sync.flush()]

    def _collect(self, wait_all: bool) -> list[KosStep]:
        steps = []
        for f, view in self.pool.results(wait_all):
            if self.on_frame:
                self.on_frame(f)
            steps += [self._finish(s, view) for s in self.sync.push(f)]
        return steps

    def _finish(self, step_frames: list[KosFrame], view: tuple) -> KosStep:
        lasers, cams = view
        run, cfg = self.run, self.cfg
        b = run.bearings
        ranges = merge_cameras(step_frames)
        key = tuple(id(c) for c in cams)
        seen = self._seen.get(key)
        if seen is None:
            seen = self._seen[key] = in_view(b, list(cams))
        scans = {}
        for k, (name, _, _) in enumerate(cfg.kos.bands()):
            r = ranges[k].copy()
            r[~seen] = np.nan
            scans[name] = Scan(step_frames[0].stamp_ns, r, b.angle_min, b.angle_increment, cfg.depth.min_depth,
                               cfg.depth.max_depth, "base_link", KOS_PREFIX + name)
        laser = None
        if lasers:
            laser = min(lasers, key=lambda s: abs(s.stamp_ns - step_frames[0].stamp_ns))
            if abs(laser.stamp_ns - step_frames[0].stamp_ns) > 100_000_000:
                laser = None
        if laser is not None and self.fuse:
            if run.laser_mount is None:
                run.laser_mount = lookup_static(self.resolver.statics, "base_link", laser.frame_id) or \
                    Transform.identity("base_link", laser.frame_id)
            scans[FUSED] = fuse_with_laser(laser, run.laser_mount, scans[OBSTACLE], KOS_PREFIX + FUSED)
        return KosStep(step_frames[0].stamp_ns, scans, step_frames, laser)


def kos_steps(log_path: Path, cfg: Config, run: ScanRun, limit: int | None = None,
              on_frame: Callable[[KosFrame], None] | None = None, workers: int = 0) -> Iterator[KosStep]:
    """Stream the log once: FSPF+ → KOS per depth frame (in `workers` processes; 0 = here), cameras merged per
    step, fused with the nearest laser scan."""
    log = open_log(log_path, cfg.topics.on_damage)
    try:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.depth:
            raise TopicError(f"{Path(log_path).name} has no depth image topic; kosmap scan needs one (name it with --depth-topic)")
        run.total_frames = sum(info.count(t) for t in det.depth)
        if limit is not None:
            run.total_frames = min(run.total_frames, limit * len(det.depth))
        with FramePool(cfg.fspf, cfg.depth, cfg.kos, workers) as pool:
            stream = KosStream(det, cfg, run, pool, limit, on_frame)
            for rec in log.read(det.wanted()):
                yield from stream.feed(rec)
                if stream.stopped:
                    break
            yield from stream.flush()
        run.warnings.extend(log.warnings)
    finally:
        log.close()


def _figure(path: Path, step: KosStep, laser_mount: Transform | None, levels: list[str], t0_ns: int) -> None:
    """Top view like the thesis's Fig. 5.13–5.20: the laser scan and the KOS of each level, overlaid."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6), dpi=110)
    if step.laser is not None:
        p = step.laser.points()
        if laser_mount is not None:
            p = laser_mount.apply(np.column_stack((p, np.zeros(len(p)))))[:, :2]
        ax.scatter(p[:, 0], p[:, 1], s=2, c="0.6", label="laser")
    colours = plt.cm.viridis(np.linspace(0, 0.9, max(1, len(levels))))
    for name, col in zip(levels, colours):
        pts = step.scans[name].points()
        ax.scatter(pts[:, 0], pts[:, 1], s=3, color=col, label=f"KOS {name}")
    pts = step.scans[OBSTACLE].points()
    ax.scatter(pts[:, 0], pts[:, 1], s=6, facecolors="none", edgecolors="r", linewidths=0.5, label="KOS obstacle")
    ax.plot([0], [0], "k^", ms=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, base_link)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"KOS levels and laser, t = {(step.stamp_ns - t0_ns) * 1e-9:.2f} s")
    ax.legend(loc="upper right", fontsize=7, markerscale=3)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def run_scan(log_path: Path, out: Path, cfg: Config, *, figures: int = 3, limit: int | None = None,
             progress: bool = True) -> dict:
    """Write the KOS scans of every depth frame of `log_path` into `out`; returns (and writes) the summary."""
    from kosmap.mapping.outdir import check_out, writing

    out = check_out(out)
    with open_log(log_path, cfg.topics.on_damage) as log:  # refuse a log without depth before writing anything
        if not detect_topics(log.info().types(), cfg.topics).depth:
            raise TopicError(f"{Path(log_path).name} has no depth image topic; kosmap scan needs one (name it with --depth-topic)")
    with writing(out, SCAN_FILES, inputs=(log_path,), command="scan") as stage:  # replace the last scan's when done
        return _scan_into(log_path, stage, cfg, figures, limit, progress)


SCAN_FILES = ("config.toml", "kos.mcap", "scan_points.csv", "kos_top_*.png", "summary.json")  # what a scan writes


def _scan_into(log_path: Path, out: Path, cfg: Config, figures: int, limit: int | None, progress: bool) -> dict:
    """run_scan's work, into a folder claimed for it."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from kosmap.frontend.logs.writer import McapWriter

    write_config(cfg, out / "config.toml")
    run = ScanRun()
    levels = [b[0] for b in cfg.kos.bands() if b[0] != OBSTACLE]
    fspf_ms, kos_ms, fill = [], [], {name: [] for name in levels + [OBSTACLE]}
    csv_tmp = out / "scan_points.csv.partial"
    steps = 0
    bar = Progress(TextColumn("KOS"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[rate]}"),
                   TimeRemainingColumn(), disable=not progress, transient=True)
    figure_steps: list[KosStep] = []
    try:
        with McapWriter(out / "kos.mcap") as writer, open(csv_tmp, "w", newline="") as fh, bar:
            task = bar.add_task("frames", total=None, rate="")
            w = csv.writer(fh)
            w.writerow(["stamp", "scan", "bearing_rad", "range_m", "x_m", "y_m"])
            statics_written = 0

            def on_frame(f: KosFrame) -> None:
                fspf_ms.append(f.fspf_ms)
                kos_ms.append(f.kos_ms)
                bar.update(task, total=run.total_frames, advance=1,
                           rate=f"{1000.0 / max(1e-6, np.median(fspf_ms[-30:]) + np.median(kos_ms[-30:])):.0f} frames/s")

            for step in kos_steps(log_path, cfg, run, limit=limit, on_frame=on_frame):
                while statics_written < len(run.statics):
                    writer.write(run.statics[statics_written], "/tf_static")
                    statics_written += 1
                steps += 1
                if step.laser is not None:
                    writer.write(step.laser)
                for name, scan in step.scans.items():
                    writer.write(scan)
                    ok = np.isfinite(scan.ranges)
                    if name in fill:
                        fill[name].append(ok.mean())
                    a, r = scan.angles[ok], scan.ranges[ok]
                    t = f"{step.stamp_ns * 1e-9:.6f}"
                    w.writerows((t, name, f"{ai:.5f}", f"{ri:.4f}", f"{ri * math.cos(ai):.4f}", f"{ri * math.sin(ai):.4f}")
                                for ai, ri in zip(a, r))
                n_steps = max(1, run.total_frames // max(1, len(run.topics["depth"])))
                if figures and len(figure_steps) < figures and (steps - 1) % max(1, n_steps // figures) == 0:
                    figure_steps.append(step)
    except BaseException:  # interrupted or failed: leave no CSV that looks complete (the MCAP writer aborts itself)
        csv_tmp.unlink(missing_ok=True)
        raise
    if steps == 0:  # every depth frame skipped by the reader: say why, and leave no output looking valid
        why = run.warnings[0].removeprefix(Path(log_path).name + ": ") if run.warnings else "no depth frame could be read"
        raise LogError(f"{Path(log_path).name}: no depth frame gave a KOS scan: {why}")
    csv_tmp.replace(out / "scan_points.csv")
    for i, step in enumerate(figure_steps):
        _figure(out / f"kos_top_{i}.png", step, run.laser_mount, levels, figure_steps[0].stamp_ns)
    summary = {
        "log": str(log_path), "steps": steps, "topics": run.topics,
        "bearings": {"angle_min": run.bearings.angle_min, "angle_increment": run.bearings.angle_increment,
                     "bins": run.bearings.n} if run.bearings else None,
        "levels": cfg.kos.levels, "band": cfg.kos.band, "source": cfg.kos.source,
        "fspf_ms_median": float(np.median(fspf_ms)) if fspf_ms else None,
        "kos_ms_median": float(np.median(kos_ms)) if kos_ms else None,
        "filled_fraction": {k: float(np.mean(v)) if v else 0.0 for k, v in fill.items()},
        "fused": run.laser_mount is not None, "warnings": run.warnings,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
