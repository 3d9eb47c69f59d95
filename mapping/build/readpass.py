"""Pass 1 of `kosmap build`: the log read once.

Depth frames go to the frame pool (mapping/runtime/framepool.py: FSPF+ and every KOS level per frame); the
per-step KOS scans come back in order, cameras merged (mapping/kosstream.py). The chosen KOS scan goes to one
SLAM feed and the laser to another (mapping/slamfeed.py), each with the wheel odometry and the gyro; the scans
of every band, the laser and fused scans and the plane clouds go to the spill (mapping/build/spill.py); each
frame's statistics go to stats.csv. Ctrl-C (or a KeyboardInterrupt from `on_progress`) stops the reading: what
was read is kept, marked partial.
"""

from __future__ import annotations

import csv
import os
import signal
import threading
import time
from array import array
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.frontend.camera import lookup_static
from kosmap.frontend.depthstream import DepthItem
from kosmap.frontend.kos import FUSED, OBSTACLE, fuse_with_laser
from kosmap.frontend.kosframe import KosFrame
from kosmap.frontend.logs import open_log
from kosmap.frontend.odometry import scan_points_base
from kosmap.frontend.records import Imu, ImuSamples, Odometry, OdometrySamples, Scan, Transform, Transforms
from kosmap.mapping.build.spill import Spill
from kosmap.mapping.config import Config
from kosmap.mapping.lasercal import KosLaserCal
from kosmap.mapping.kosstream import KOS_PREFIX, KosStep, KosStream, ScanRun, run_gravity
from kosmap.mapping.runtime.framepool import FramePool
from kosmap.mapping.slamfeed import laser_mount, laser_period, odometry_columns

STATS_COLUMNS = ("frame", "topic", "stamp", "ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct", "remaining",
                 "planes", "points", "fspf_ms", "kos_ms")
TABLE_5_2 = ("ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct", "planes", "fspf_ms", "kos_ms")


@dataclass
class LogSources:
    """What the log holds, read from its index before any record: the topics, message counts and duration."""

    det: object  # frontend.logs.topics.Topics
    counts: dict[str, int]
    duration: float

    @property
    def has_depth(self) -> bool:
        return bool(self.det.depth)

    @property
    def has_laser(self) -> bool:
        return bool(self.det.scan)

    def expected_units(self, bcfg) -> int:
        """Depth frames the run will process (or laser scans in a log without depth): the progress total."""
        det, counts, duration = self.det, self.counts, self.duration
        if det.depth:
            n = 0
            for t in det.depth:
                c = counts.get(t, 0)
                n += min(c, int(duration * bcfg.depth_rate) + 1) if bcfg.depth_rate > 0 else c
            return n
        c = counts.get(det.scan, 0)
        return (min(c, int(duration * bcfg.laser_rate) + 1) if bcfg.laser_rate > 0 and c > 1.2 * bcfg.laser_rate * duration
                else c)


@dataclass
class Progress:
    """What `on_progress` sees after each unit of work (a depth frame, or a laser scan in a log without depth)."""

    frames: int
    scans: int
    log_s: float
    total_s: float
    units: int = 0  # the run's expected units of work (depth frames, else laser scans)
    unit: str = "depth frames"

    @property
    def done(self) -> int:
        """Units of work done: depth frames, or laser scans in a log without depth."""
        return self.frames if self.unit == "depth frames" else self.scans


@dataclass
class ReadResult:
    """What pass 1 read: the spill, the counts, the log time covered, the ground truth and the per-frame stats."""

    spill: Spill
    frames: int
    laser_kept: int
    laser_seen: int
    partial: bool
    seconds: float  # wall time of the read
    cpu_s: float
    log_s: float  # log time read
    laser_mount: np.ndarray | None  # (x, y, yaw) of the laser in base_link
    gt: np.ndarray  # (N, 4): t s, x, y, yaw of the ground-truth topic
    stats: dict[str, np.ndarray]  # per frame, the TABLE_5_2 columns
    run: ScanRun
    statics: list[Transforms]


@contextmanager
def _stop_on_sigint(stop: Callable[[], None]) -> Iterator[None]:
    """Ctrl-C calls `stop` (finish what was read) and restores the handler (a second Ctrl-C aborts)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = None

    def handler(_sig, _frm):
        stop()
        signal.signal(signal.SIGINT, old or signal.default_int_handler)

    old = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


class ReadPass:
    """Pass 1 over one log (`run`); the SLAM feeds are ended here and solved by the caller, the frame pool is the
    caller's (left open for the grid and comparison jobs)."""

    def __init__(self, src: LogSources, cfg: Config, spill_dir: Path, warnings: list[str], pool: FramePool | None,
                 kos_feed, laser_feed, on_progress: Callable[[Progress], None] | None = None) -> None:
        self.src, self.det, self.cfg, self.bcfg = src, src.det, cfg, cfg.build
        self.out = spill_dir.parent
        self.spill = Spill(spill_dir, [b[0] for b in cfg.kos.bands()])
        self.warnings, self.pool = warnings, pool
        self.kos_feed, self.laser_feed = kos_feed, laser_feed
        self.feeds = [f for f in (kos_feed, laser_feed) if f is not None]
        self.on_progress = on_progress
        self.statics: list[Transforms] = []
        self.static_keys: set[tuple] = set()
        self.gt = array("d")  # t, x, y, yaw flattened
        self.stats = {k: array("f") for k in TABLE_5_2}
        self.frames = self.laser_kept = self.laser_seen = 0
        self.t0: int | None = None  # the log's first and latest stamps read, and the last batch's end
        self.t: int | None = None
        self.end: int | None = None
        self.base = "base_link"  # the wheel odometry's child frame
        self.laser_mount: np.ndarray | None = None
        self.laser_read = None  # LaserMount.read: an upside-down laser's scans read upright (mapping/slamfeed.py)
        self.laser_tf: np.ndarray | None = None  # the laser's mount as a matrix, for the fused scan
        self.last_laser: int | None = None
        self.last_fused: int | None = None
        self.next_cloud: int | None = None
        self.stop = self.partial = False
        bcfg, det = self.bcfg, src.det
        self.laser_period = laser_period(bcfg.laser_rate, src.counts.get(det.scan, 0), src.duration) if det.scan else 0
        self.cloud_period = int(bcfg.mcap_planes_period * 1e9)
        self.run = ScanRun()
        self.lasercal = KosLaserCal(cfg.kos.bands(), len(src.det.depth))  # the camera's yaw and x, y against the laser
        self.total = src.expected_units(bcfg)
        self.stream: KosStream | None = None
        self.writer = None

    # ---- the read ----------------------------------------------------------------------------------------------

    def read(self, log: Path) -> ReadResult:
        """Read `log` once (module doc); stats.csv is written beside the spill's folder."""
        csv_path = self.out / "stats.csv.partial"
        if self.pool is not None:
            min_period = int(1e9 / self.bcfg.depth_rate) if self.bcfg.depth_rate > 0 else 0
            self.stream = KosStream(self.det, self.cfg, self.run, self.pool, on_frame=self.on_frame, cloud=self.cloud,
                                    min_period_ns=min_period, fuse=False, mounts=run_gravity(log, self.cfg, self.run))
        t_begin = time.perf_counter()
        cpu0 = time.process_time()
        lg = open_log(log, self.cfg.topics.on_damage)
        try:
            with open(csv_path, "w", newline="") as csv_fh, _stop_on_sigint(self._request_stop):
                self.writer = csv.writer(csv_fh)
                self.writer.writerow(STATS_COLUMNS)
                try:
                    for rec in lg.read_batched(self.det.wanted()):
                        if self.stop:
                            raise KeyboardInterrupt
                        self.record(rec)
                except KeyboardInterrupt:
                    self.partial = True
                    if self.pool is not None:
                        self.pool.drop()  # the frames in flight are not waited for; the workers stay for pass 2
                if not self.partial and self.stream is not None:
                    for step in self.stream.flush():
                        self.on_step(step)
                for f in self.feeds:
                    f.end()
                self.run.warnings.extend(lg.warnings)
        finally:
            lg.close()
            self.spill.close()
        os.replace(csv_path, self.out / "stats.csv")
        self.warnings.extend(self.run.warnings)
        self._spill_kos_meta()
        if len(self.run.mounts) == 1:
            self.run.laser_alignment = self.lasercal.result(next(iter(self.run.mounts.values())))
        t0, t = self.t0, max((x for x in (self.t, self.end) if x is not None), default=None)
        return ReadResult(self.spill, self.frames, self.laser_kept, self.laser_seen, self.partial,
                          time.perf_counter() - t_begin, time.process_time() - cpu0,
                          (t - t0) * 1e-9 if t0 is not None and t is not None else 0.0, self.laser_mount,
                          np.asarray(self.gt, np.float64).reshape(-1, 4),
                          {k: np.asarray(v) for k, v in self.stats.items()}, self.run, self.statics)

    def _request_stop(self) -> None:
        self.stop = True

    def record(self, rec) -> None:
        """One record (or a batch of odometry or IMU samples) of the log, to where it goes."""
        det = self.det
        batch = isinstance(rec, (OdometrySamples, ImuSamples))  # a stretch of samples (read_batched)
        # The log's "now" is where the record stands: a batch stands at its first sample, so the scans' odometry
        # timeout runs as in `read` (at its last, a chunk longer than ODOM_WAIT_S released scans whose odometry
        # was in the next chunk). Its last sample only extends how much log was read.
        st = rec.stamp_ns
        if st and (self.t is None or st > self.t):
            self.t = st
            if self.t0 is None:
                self.t0 = st
        if batch and (self.end is None or rec.end_ns > self.end):
            self.end = rec.end_ns
        if isinstance(rec, (Odometry, OdometrySamples)):
            t, x, y, yaw = odometry_columns(rec)
            if rec.topic == det.ground_truth:
                self.gt.extend(np.column_stack((t * 1e-9, x, y, yaw)).ravel().tolist())
                return
            if rec.topic == det.odom:
                if self.base == "base_link" and rec.child_frame_id:
                    self.base = rec.child_frame_id.lstrip("/") or "base_link"
                for f in self.feeds:
                    f.wheel_samples(t, x, y, yaw)
        elif isinstance(rec, ImuSamples):
            if det.imu and rec.topic == det.imu:
                ok = rec.has_angular_velocity  # (Slam.add_imu skips a sample without)
                for f in self.feeds:
                    f.gyro_samples(rec.stamps_ns[ok], rec.yaw_rate[ok])
        elif isinstance(rec, Transforms) and rec.static:
            key = tuple((t.parent, t.child, *np.asarray(t.translation, float).tolist(),
                         *np.asarray(t.rotation, float).tolist()) for t in rec.transforms)
            if key in self.static_keys:  # a recorder may republish /tf_static every second: kept once (here
                return  # and by the depth stream), not once per message for the whole run
            self.static_keys.add(key)
            self.statics.append(rec)
        elif det.imu and rec.topic == det.imu:
            for f in self.feeds:
                f.imu(rec)
        elif isinstance(rec, Scan) and rec.topic == det.scan and self.laser_feed is not None:
            self.on_laser(rec)
        # (the gyro and odometry: nothing for the depth stream, which steps when it submits a frame)
        if self.stream is not None and not batch and not isinstance(rec, (Odometry, Imu)):
            for step in self.stream.feed(rec):
                self.on_step(step)
        for f in self.feeds:
            f.advance(self.t)

    # ---- what the stream and the laser hand back -------------------------------------------------------------------

    def cloud(self, item: DepthItem) -> int:
        """Plane points to keep of this frame for the MCAP: a cloud every mcap_planes_period seconds."""
        if self.cloud_period <= 0:
            return 0
        if self.next_cloud is None or item.stamp_ns >= self.next_cloud - 1_000_000:  # 1 ms: stamp jitter
            self.next_cloud = item.stamp_ns + self.cloud_period
            return self.bcfg.mcap_plane_points
        return 0

    def on_frame(self, f: KosFrame) -> None:
        """A processed depth frame: its stats (stats.csv, Table 5.2) and its plane cloud (the spill)."""
        s = f.stats
        row = {"ineligible_pct": s.ineligible_pct, "inlier_pct": s.inlier_pct, "dropped_pct": s.dropped_pct,
               "outlier_pct": s.outlier_pct, "planes": s.planes, "fspf_ms": f.fspf_ms, "kos_ms": f.kos_ms}
        for k, v in row.items():
            self.stats[k].append(float(v))
        self.writer.writerow([f.index, f.topic, f"{f.stamp_ns * 1e-9:.6f}", f"{s.ineligible_pct:.3f}",
                              f"{s.inlier_pct:.3f}", f"{s.dropped_pct:.3f}", f"{s.outlier_pct:.3f}", s.remaining,
                              s.planes, f.n_points, f"{f.fspf_ms:.3f}", f"{f.kos_ms:.3f}"])
        if f.cloud is not None and len(f.cloud[0]):  # subsampled in the frame stage (kosframe.plane_cloud)
            pts, cls = f.cloud
            mount = self.stream.cams[f.topic][1]  # set when the topic's first frame was read, before any result
            self.spill.add_cloud(f.stamp_ns, mount.apply(pts.astype(np.float64)), cls)
        self.frames += 1
        self.tick()

    def on_step(self, step: KosStep) -> None:
        """A time step's KOS scans: every band to the spill, the SLAM scan to its feed, the fused scan (at the
        laser's rate) to the spill."""
        spill, bcfg = self.spill, self.bcfg
        self.lasercal.add(step.scans, step.laser, self.statics)
        ranges = np.stack([step.scans[b].ranges for b in spill.bands])
        spill.kos.add(step.stamp_ns, ranges)
        sc = step.scans[bcfg.slam_scan]
        if self.kos_feed is not None:
            o = self.kos_feed.slam.ocfg
            self.kos_feed.push(step.stamp_ns, scan_points_base(sc.ranges, sc.angles, sc.valid(), None, o.min_range,
                                                               o.max_range))
        laser = step.laser  # fused here, at the laser map's rate, not for every step (KosStream fuse=False)
        if laser is not None and bcfg.fused_map and self.laser_feed is not None:
            last = self.last_fused
            if last is None or laser.stamp_ns - last >= self.laser_period - 1_000_000:
                if self.laser_tf is None:  # its matrix, made once
                    self.laser_tf = (lookup_static(self.statics, "base_link", laser.frame_id)
                                     or Transform.identity("base_link", laser.frame_id)).matrix()
                fused = fuse_with_laser(laser, self.laser_tf, step.scans[OBSTACLE], KOS_PREFIX + FUSED)
                if spill.fused.add(fused.stamp_ns, fused.ranges):
                    self.last_fused = fused.stamp_ns
                    if not spill.fused.meta:
                        spill.fused.meta = {"angle_min": fused.angle_min, "angle_increment": fused.angle_increment,
                                            "range_min": fused.range_min, "range_max": fused.range_max,
                                            "frame_id": fused.frame_id}

    def on_laser(self, scan: Scan) -> None:
        """A laser scan: kept at [build] laser_rate, to the spill and the laser SLAM's feed."""
        self.laser_seen += 1
        last = self.last_laser
        if last is not None and scan.stamp_ns - last < self.laser_period - 1_000_000:
            return
        if self.laser_mount is None:  # the same lookup as `kosmap slam` (mapping/slamfeed.py)
            lm = laser_mount(self.statics, self.base, scan.frame_id)
            self.laser_mount, self.laser_read = lm.pose, lm.read
            self.warnings.extend([lm.warning] if lm.warning else [])
        read_at = scan.stamp_ns  # the thinning's clock, whichever way the laser is mounted
        scan = self.laser_read(scan)
        spill = self.spill
        if not spill.laser.add(scan.stamp_ns, scan.ranges):
            return
        if not spill.laser.meta:
            spill.laser.meta = {"angle_min": scan.angle_min, "angle_increment": scan.angle_increment,
                                "range_min": scan.range_min, "range_max": scan.range_max, "frame_id": scan.frame_id,
                                "topic": scan.topic, "time_increment": scan.time_increment}
        self.last_laser = read_at
        self.laser_kept += 1
        self.laser_feed.push_laser(scan, self.laser_mount)
        if not self.det.depth:
            self.tick()

    def tick(self) -> None:
        """Progress after a unit of work, to `on_progress`."""
        if self.on_progress is None:
            return
        t0, t = self.t0, self.t
        log_s = (t - t0) * 1e-9 if t0 is not None and t is not None else 0.0
        self.on_progress(Progress(self.frames, self.laser_kept, log_s, self.src.duration, self.total,
                                  "depth frames" if self.det.depth else "laser scans"))

    def _spill_kos_meta(self) -> None:
        """The KOS series' scan geometry (the bins fixed by the first frame), for the grids and the MCAP."""
        bear = self.run.bearings
        if bear is not None:
            self.spill.kos.meta = {"angle_min": bear.angle_min, "angle_increment": bear.angle_increment,
                                   "range_min": self.cfg.depth.min_depth, "range_max": self.cfg.depth.max_depth,
                                   "frame_id": "base_link"}
