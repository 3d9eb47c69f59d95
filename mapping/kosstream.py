"""The KOS stream: a log's depth frames → FSPF+ → multi-level KOS scans per frame (in the frame pool), cameras merged
per time step, each step with the laser scan nearest in time (thesis §4.3, Algorithm 7). `kosmap scan`
(mapping/kosscan.py), `kosmap build` (mapping/build/readpass.py) and `kosmap slam --source kos` read it.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kosmap.frontend.camera import lookup_static
from kosmap.frontend.depthstream import DepthItem, DepthResolver
from kosmap.frontend.errors import TopicError
from kosmap.frontend.kos import FUSED, OBSTACLE, Bearings, bearings_for, camera_view, fuse_with_laser, in_view
from kosmap.frontend.kosframe import KosFrame, merge_cameras
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.records import DepthFrame, Scan, Transform, Transforms
from kosmap.mapping.config import Config
from kosmap.mapping.gravitymount import GravityMount, resolve_gravity
from kosmap.mapping.runtime.framepool import FramePool

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
    """A 16UC1 frame whose `meters()` is the raw image: the frame stage converts it (mapping/runtime/framepool.py), in the
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
    gravity: GravityMount | None = None  # where gravity came from and the mounts it gave
    mounts: dict[str, Transform] = field(default_factory=dict)  # per depth topic, the mount its frames used
    laser_alignment: dict | None = None  # the camera's yaw and x, y against the laser (mapping/lasercal.py)


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
                 fuse: bool = True, mounts: dict[str, Transform] | None = None,
                 keep: Callable[[DepthFrame], bool] | None = None) -> None:
        self.det, self.cfg, self.run, self.pool = det, cfg, run, pool
        self.limit = None if limit is None else limit * len(det.depth)
        self.on_frame = on_frame
        self.cloud = cloud  # plane points to keep of a frame (KosFrame.cloud; 0 = none)
        self.min_period = int(min_period_ns)  # per camera: frames closer in time than this to the last kept are skipped
        self._last: dict[str, int] = {}
        self.keep = keep  # a depth frame past min_period that it refuses is skipped as well (the caller's rule)
        self.fuse = fuse  # add the scan fused with the laser to each step (else the step only names its laser)
        self.mounts = mounts or {}  # optical frame id → the gravity-aligned mount that replaces the given one
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
        if isinstance(rec, DepthFrame) and rec.topic in self.det.depth and (self.min_period or self.keep is not None):
            last = self._last.get(rec.topic)
            # 1 ms slack for stamp jitter; `keep` is asked only of a frame the period lets through
            early = bool(self.min_period) and last is not None and rec.stamp_ns - last < self.min_period - 1_000_000
            if early or (self.keep is not None and not self.keep(rec)):
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
        if item.frame_id in self.mounts:
            item.mount = self.mounts[item.frame_id]
        if self.limit is not None and self.submitted >= self.limit:
            self.stopped = True
            return []
        run, cfg = self.run, self.cfg
        if item.topic not in self.cams:
            self.cams[item.topic] = (item.camera, item.mount)
            run.mounts[item.topic] = item.mount
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


def run_gravity(log_path: Path, cfg: Config, run: ScanRun) -> dict:
    """The run's gravity (mapping/gravitymount.py: the mount, the IMU or the frames), recorded in `run` with its
    warnings; returns the gravity-aligned depth-camera mounts every KosStream of the run is given."""
    grav = resolve_gravity(log_path, cfg)
    run.gravity = grav
    run.warnings.extend(grav.warnings())
    return grav.mounts


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
        mounts = run_gravity(log_path, cfg, run)
        with FramePool(cfg.fspf, cfg.depth, cfg.kos, workers) as pool:
            stream = KosStream(det, cfg, run, pool, limit, on_frame, mounts=mounts)
            for rec in log.read(det.wanted()):
                yield from stream.feed(rec)
                if stream.stopped:
                    break
            yield from stream.flush()
        run.warnings.extend(log.warnings)
    finally:
        log.close()

