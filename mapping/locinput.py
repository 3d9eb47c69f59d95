"""What `kosmap localize` reads of a log, in one pass: the scans it localizes (the depth camera's KOS obstacle scan,
or the laser), the wheel odometry and the gyro at each scan's stamp, and the ground truth for scoring.

The scans are kept as end points in base_link (a KOS step of one camera is a few hundred points, a laser scan a
few hundred after thinning), so the particle filter runs over arrays once the log has been read.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.errors import KosmapError, TopicError
from kosmap.frontend.records import Imu, Odometry, Scan, Transforms

GYRO_MAX_GAP_S = 0.1  # a scan interval the gyro leaves uncovered this long is predicted with the wheels' yaw
GYRO_TOL = math.radians(1.0)  # the gyro's yaw step is dropped when it disagrees with the wheels' by more (or 25 %)


@dataclass
class LocalizationInput:
    """The scans of a log with the motion between them; `odom` is the wheel odometry's translation with the gyro's
    yaw at each scan (mapping/slam.py's fused prediction), NaN rows where the log has no odometry."""

    source: str  # "kos" or "laser"
    stamps_ns: np.ndarray  # (S,) int64
    points: list[np.ndarray]  # per scan, N×2 float32 end points in base_link (an hour of 1000-beam laser: ~290 MB)
    odom: np.ndarray  # (S, 3)
    has_odom: bool
    has_gyro: bool
    ground_truth: tuple[np.ndarray, np.ndarray] | None = None  # (stamps s, N×3) of the log's ground-truth topic
    read_s: float = 0.0
    warnings: list[str] = field(default_factory=list)

    @property
    def stamps(self) -> np.ndarray:
        return self.stamps_ns * 1e-9

    @property
    def duration_s(self) -> float:
        return float(self.stamps_ns[-1] - self.stamps_ns[0]) * 1e-9 if len(self.stamps_ns) > 1 else 0.0


class _Motion:
    """Wheel odometry and gyro samples gathered while reading, turned into one pose per scan at the end."""

    def __init__(self) -> None:
        self.odom_t: list[int] = []
        self.odom_p: list[tuple[float, float, float]] = []
        self.gyro_t: list[int] = []
        self.gyro_w: list[float] = []

    def odometry(self, rec: Odometry) -> None:
        self.odom_t.append(rec.stamp_ns)
        self.odom_p.append((rec.x, rec.y, rec.yaw))

    def imu(self, rec: Imu) -> None:
        if rec.has_angular_velocity:
            self.gyro_t.append(rec.stamp_ns)
            self.gyro_w.append(rec.yaw_rate)

    def at(self, stamps_ns: np.ndarray) -> tuple[np.ndarray, bool]:
        """Fused odometry at the scan stamps: wheel translation, gyro yaw where the gyro covers the interval."""
        n = len(stamps_ns)
        if len(self.odom_t) < 2:
            return np.full((n, 3), np.nan), False
        order = np.argsort(np.asarray(self.odom_t), kind="stable")
        t = np.asarray(self.odom_t, np.int64)[order]
        p = np.asarray(self.odom_p, float)[order]
        keep = np.r_[True, np.diff(t) > 0]
        wheel = se2.interpolate(t[keep] * 1e-9, p[keep], stamps_ns * 1e-9)
        if len(self.gyro_t) < 2:
            return wheel, False
        gt = np.asarray(self.gyro_t, np.int64)
        gw = np.asarray(self.gyro_w, float)
        go = np.argsort(gt, kind="stable")
        gt, gw = gt[go], gw[go]
        # yaw integrated by the trapezoid rule, read at the scan stamps (Probabilistic Robotics §5.4: the gyro's
        # rotation replaces the wheels' where both exist)
        cum = np.r_[0.0, np.cumsum(0.5 * (gw[1:] + gw[:-1]) * np.diff(gt) * 1e-9)]
        yaw_at = np.interp(stamps_ns, gt, cum)
        gap = np.r_[np.diff(gt) * 1e-9 > GYRO_MAX_GAP_S, False]
        gap_cum = np.cumsum(gap)  # a gap inside an interval changes the count between its ends
        idx = np.searchsorted(gt, stamps_ns)
        fused = wheel.copy()
        for i in range(1, n):
            inc = se2.between(wheel[i - 1], wheel[i])
            covered = (gt[0] <= stamps_ns[i - 1] and stamps_ns[i] <= gt[-1]
                       and gap_cum[max(idx[i] - 1, 0)] == gap_cum[max(idx[i - 1] - 1, 0)])
            g = yaw_at[i] - yaw_at[i - 1]
            if covered and abs(se2.wrap(g - inc[2])) <= max(GYRO_TOL, 0.25 * abs(inc[2])):
                inc[2] = g
            fused[i] = se2.compose(fused[i - 1], inc)
        return fused, True


def read_input(path: str | Path, cfg, source: str, progress: Callable[[float, float], None] | None = None,
               workers: int = 0) -> LocalizationInput:
    """Read the log once; `source` "kos" (FSPF+ → KOS per depth frame at [localize] depth_rate, the [build]
    slam_scan scan) or "laser" (the LaserScan topic at [localize] laser_rate). TopicError when the log lacks it."""
    from kosmap.frontend.logs import detect_topics, open_log

    if source not in ("kos", "laser"):
        raise KosmapError(f"unknown --source {source!r}; use kos (the depth camera) or laser")
    t0 = time.perf_counter()
    motion = _Motion()
    gt_t: list[float] = []
    gt_p: list[tuple[float, float, float]] = []
    with open_log(path, cfg.topics.on_damage) as log:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        name = Path(path).name
        if source == "kos" and not det.depth:
            raise TopicError(f"{name} has no depth image topic for --source kos (see `kosmap info`); name it with "
                             f"--depth-topic, or use --source laser if it has a laser")
        if source == "laser" and not det.scan:
            raise TopicError(f"{name} has no sensor_msgs/LaserScan topic for --source laser (see `kosmap info`); "
                             f"use --source kos for a depth-camera log")

        def other(rec) -> bool:
            if isinstance(rec, Odometry) and rec.topic == det.ground_truth:
                gt_t.append(rec.stamp)
                gt_p.append((rec.x, rec.y, rec.yaw))
            elif isinstance(rec, Odometry) and rec.topic == det.odom:
                motion.odometry(rec)
            elif isinstance(rec, Imu) and rec.topic == det.imu:
                motion.imu(rec)
            else:
                return False
            return True

        reader = _read_kos if source == "kos" else _read_laser
        stamps, points, warnings = reader(log, det, cfg, other, progress, info.duration, workers, motion)
        warnings = warnings + list(log.warnings)
    if not stamps:
        raise TopicError(f"{name} gave no {'KOS' if source == 'kos' else 'laser'} scans to localize with; check "
                         f"the topics with `kosmap info`")
    stamps_ns = np.asarray(stamps, np.int64)
    order = np.argsort(stamps_ns, kind="stable")
    stamps_ns = stamps_ns[order]
    points = [points[i] for i in order]
    odom, has_gyro = motion.at(stamps_ns)
    has_odom = bool(np.isfinite(odom).all()) and len(motion.odom_t) >= 2
    gt = None
    if gt_t:
        gt = (np.asarray(gt_t), np.asarray(gt_p))
    return LocalizationInput(source, stamps_ns, points, odom, has_odom, has_gyro and has_odom, gt,
                             time.perf_counter() - t0, warnings)


def _read_kos(log, det, cfg, other, progress, total, workers, motion):
    from kosmap.frontend.odometry import scan_points_base
    from kosmap.mapping.kosstream import KosStream, ScanRun, run_gravity
    from kosmap.mapping.runtime.framepool import FramePool

    lc = cfg.localize
    name = cfg.build.slam_scan
    bands = [b[0] for b in cfg.kos.bands()]
    if name not in bands:
        from kosmap.frontend.errors import ConfigError

        raise ConfigError(f"config [build] slam_scan = {name!r} is not a KOS scan of this config; choose one of "
                          f"{', '.join(bands)}")
    stamps: list[int] = []
    points: list[np.ndarray] = []
    first: list[int] = []

    def take(step) -> None:
        sc = step.scans[name]
        stamps.append(step.stamp_ns)
        points.append(scan_points_base(sc.ranges, sc.angles, sc.valid(), None, lc.min_range, lc.max_range).astype(np.float32))
        if progress is not None:
            first.append(step.stamp_ns) if not first else None
            progress((step.stamp_ns - first[0]) * 1e-9, total)

    run = ScanRun()
    min_period = int(1e9 / lc.depth_rate) if lc.depth_rate > 0 else 0
    with FramePool(cfg.fspf, cfg.depth, cfg.kos, workers) as pool:
        stream = KosStream(det, cfg, run, pool, min_period_ns=min_period, fuse=False, keep=_FrameGate(lc, motion),
                           mounts=run_gravity(log.path, cfg, run))  # the mounts `kosmap build` uses
        for rec in log.read(det.wanted()):
            if other(rec):
                continue
            for step in stream.feed(rec):
                take(step)
        for step in stream.flush():
            take(step)
    return stamps, points, list(run.warnings)


class _FrameGate:
    """Which depth frames are worth FSPF+ and KOS (most of a run's time): as AMCL takes a scan only after
    update_min_d or update_min_a of motion, one after the wheels moved or turned that far since the camera's last
    frame read, or frame_max_period_s after it (a standing robot still gets a pose, and no gap of max_gap_s is seen
    where there is none). Every frame (at depth_rate) while the log has no odometry yet, or without read_at_updates."""

    def __init__(self, lc, motion: _Motion) -> None:
        self.min_d, self.min_a = lc.update_min_d, math.radians(lc.update_min_a_deg)
        self.max_dt = int(min(lc.frame_max_period_s, 0.5 * lc.max_gap_s) * 1e9)  # never a false gap
        self.on = bool(lc.read_at_updates)
        self.motion = motion
        self.last: dict[str, tuple[int, tuple[float, float, float] | None]] = {}

    def __call__(self, rec) -> bool:
        now = self.motion.odom_p[-1] if self.motion.odom_p else None
        prev = self.last.get(rec.topic)
        keep = (not self.on or prev is None or now is None or prev[1] is None or rec.stamp_ns - prev[0] >= self.max_dt
                or math.hypot(now[0] - prev[1][0], now[1] - prev[1][1]) >= self.min_d
                or abs(se2.wrap(now[2] - prev[1][2])) >= self.min_a)
        if keep:
            self.last[rec.topic] = (rec.stamp_ns, now)
        return keep


def _read_laser(log, det, cfg, other, progress, total, workers, motion=None):
    from kosmap.frontend.odometry import scan_to_points
    from kosmap.mapping.slamfeed import LaserMount, laser_mount

    lc = cfg.localize
    statics: list[Transforms] = []
    mounts: dict[str, LaserMount] = {}
    warnings: list[str] = []
    stamps: list[int] = []
    points: list[np.ndarray] = []
    min_period = int(1e9 / lc.laser_rate) if lc.laser_rate > 0 else 0
    last = None
    first = None
    topics = [t for t in (det.scan, det.odom, det.imu, det.ground_truth, det.tf_static) if t]
    for rec in log.read(topics):
        if other(rec):
            continue
        if isinstance(rec, Transforms):
            statics.append(rec)
        elif isinstance(rec, Scan) and rec.topic == det.scan:
            first = rec.stamp_ns if first is None else first
            if last is not None and rec.stamp_ns - last < min_period - 1_000_000:
                continue
            last = rec.stamp_ns
            frame = rec.frame_id.lstrip("/") or "base_link"
            if frame not in mounts:  # the lookup `kosmap slam` and `build` make (mapping/slamfeed.py)
                mounts[frame] = laser_mount(statics, "base_link", frame)
                warnings.extend([mounts[frame].warning] if mounts[frame].warning else [])
            lm = mounts[frame]
            stamps.append(rec.stamp_ns)
            points.append(scan_to_points(lm.read(rec), lm.pose, lc.min_range, lc.max_range).astype(np.float32))
            if progress is not None:
                progress((rec.stamp_ns - first) * 1e-9, total)
    return stamps, points, warnings
