"""Read-time checks of the records every reader yields: what is physically impossible never reaches the pipeline.

One `RecordGuard` per open log (frontend/logs/base.py `LogReader._usable` applies it to every record of every
format). It skips records whose numbers cannot be measurements (non-finite or impossible stamps, poses, beam
geometry, camera intrinsics, degenerate images), and bridges odometry jumps faster than any robot moves: the pose
after the jump continues from the pose before it (no motion across the jump), as the odometry of a wheel encoder
that was reset or glitched. Each kind of problem gives one warning naming the topic, the first time and what to do,
and is counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.records import CameraModel, DepthFrame, Odometry, OdometrySamples, Scan, Transforms

# Stamps in ns: from the epoch to 2^62 ns (year 2116). Beyond, int64 arithmetic on stamps (differences, sums of
# offsets) overflows; before the epoch no recorder writes.
MAX_STAMP_NS = 1 << 62
# Odometry faster than this is a glitch, not motion: 20 m/s (72 km/h) is beyond any robot that maps with a
# 2D laser or a depth camera (wheelchairs, warehouse AGVs and field robots drive below 5 m/s).
MAX_SPEED = 20.0
# An odometry pose and its stamp may be taken up to a message period apart (10 Hz: 0.1 s; converted logs such as
# the Intel bag show 0.9 m steps 4 ms apart): a jump is measured against MAX_SPEED × (dt + this).
STAMP_JITTER_S = 0.1
MAX_BEAMS = 1 << 16  # a LaserScan of more beams than this (0.005° steps over 360°) is no real scanner
MIN_IMAGE_SIDE = 2  # a single row or column spans no field of view (the KOS divides by width − 1)
MAX_PRINCIPAL_OFFSET = 4.0  # a principal point this many image sizes outside the image is not a calibration


@dataclass
class _Bridge:
    """Per odometry topic: the last raw and corrected pose, and the correction applied since the last jump."""

    stamp_ns: int
    raw: np.ndarray
    fixed: np.ndarray
    offset: np.ndarray | None = None  # None: no jump yet


@dataclass
class RecordGuard:
    """The checks of one open log; `warn` gets each problem's one warning, `skipped` counts them by warning."""

    name: str  # the log's file name
    warn: object  # callable(str)
    skipped: dict[str, int] = field(default_factory=dict)
    _odom: dict[str, _Bridge] = field(default_factory=dict)
    _image_size: dict[str, tuple[int, int]] = field(default_factory=dict)
    _camera_size: dict[str, tuple[int, int]] = field(default_factory=dict)  # per frame id: the last CameraInfo's

    def check(self, rec):
        """The record, corrected where it is bridged, or None when it is skipped."""
        if rec is None:
            return None
        stamp = getattr(rec, "stamp_ns", 0)
        if isinstance(rec, OdometrySamples):
            return self._odometry_samples(rec)
        if not 0 <= stamp < MAX_STAMP_NS:
            return self._skip(rec, "an impossible time stamp", stamp, "check the recorder's clock")
        if isinstance(rec, Odometry):
            return self._odometry(rec)
        if isinstance(rec, Scan):
            why = scan_problem(rec)
            return self._skip(rec, why, stamp, "check the laser driver") if why else rec
        if isinstance(rec, CameraModel):
            why = camera_problem(rec)
            if why:
                return self._skip(rec, why, stamp, "check the driver's calibration; the field-of-view model "
                                                   "([depth] fov_h_deg, fov_v_deg) serves the images")
            self._camera_size[rec.frame_id] = (rec.width, rec.height)
            return rec
        if isinstance(rec, DepthFrame):
            return self._depth(rec)
        if isinstance(rec, Transforms):
            why = transforms_problem(rec)
            return self._skip(rec, why, stamp, "check the tf publisher") if why else rec
        return rec

    # -- kinds ---------------------------------------------------------------------------------------------------------
    def _depth(self, rec: DepthFrame):
        img = rec.image
        if img.ndim != 2 or min(img.shape) < MIN_IMAGE_SIDE:
            return self._skip(rec, f"a depth image of {'×'.join(map(str, img.shape))} pixels", rec.stamp_ns,
                              "check the camera driver and the depth topic")
        first = self._image_size.setdefault(rec.topic, img.shape)
        if first != img.shape:
            return self._skip(rec, f"a depth image of {img.shape[1]}×{img.shape[0]} pixels after ones of "
                                   f"{first[1]}×{first[0]}", rec.stamp_ns,
                              "a topic's image size must not change: map each part of the log on its own")
        cw, ch = self._camera_size.get(rec.frame_id, (img.shape[1], img.shape[0]))
        if abs(img.shape[1] * ch - img.shape[0] * cw) > 0.01 * cw * ch:  # (camera_for scales a same-aspect info)
            self._count(f"the depth images on {rec.topic} are {img.shape[1]}×{img.shape[0]} pixels, the camera info "
                        f"of {rec.frame_id} says {cw}×{ch}, another aspect: its intrinsics do not fit these images "
                        f"and the field-of-view model ([depth] fov_h_deg, fov_v_deg) is used: check the driver's "
                        f"calibration", rec.topic, "aspect")
        return rec

    def _odometry(self, rec: Odometry):
        x, y, yaw = rec.x, rec.y, rec.yaw
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(yaw)) or max(abs(x), abs(y)) > 1e7:
            return self._skip(rec, "a non-finite or impossible pose", rec.stamp_ns, "check the odometry driver")
        raw = np.array([x, y, yaw])
        b = self._odom.get(rec.topic)
        if b is None:
            self._odom[rec.topic] = _Bridge(rec.stamp_ns, raw, raw)
            return rec
        fixed = raw if b.offset is None else se2.compose(b.offset, raw)
        dist = math.hypot(x - b.raw[0], y - b.raw[1])
        dt = abs(rec.stamp_ns - b.stamp_ns) * 1e-9
        if dist > MAX_SPEED * (dt + STAMP_JITTER_S):
            # Bridged: the pose continues from the last one (no motion across the jump), the rest shifted with it.
            b.offset = se2.compose(b.fixed, se2.inverse(raw))
            fixed = b.fixed.copy()
            self._count(f"odometry on {rec.topic} jumps {dist:.1f} m in {dt:.3f} s (first at "
                        f"t={rec.stamp_ns * 1e-9:.3f} s), faster than any robot drives ({MAX_SPEED:g} m/s); such "
                        f"jumps are bridged as if the robot stood still across them: check the odometry driver (a "
                        f"reset or glitch)", rec.topic, "jump")
        b.stamp_ns, b.raw, b.fixed = rec.stamp_ns, raw, fixed
        if b.offset is None:
            return rec
        return Odometry(rec.stamp_ns, float(fixed[0]), float(fixed[1]), float(fixed[2]), rec.frame_id,
                        rec.child_frame_id, rec.topic, rec.z)

    def _odometry_samples(self, rec: OdometrySamples):
        """The batch checked sample by sample where a sample is bad or jumps (rare); else as it is."""
        ok = (np.isfinite(rec.x) & np.isfinite(rec.y) & np.isfinite(rec.yaw) & (rec.stamps_ns >= 0)
              & (rec.stamps_ns < MAX_STAMP_NS) & (np.abs(rec.x) <= 1e7) & (np.abs(rec.y) <= 1e7))
        b = self._odom.get(rec.topic)
        if ok.all() and (b is None or b.offset is None):
            xs = np.concatenate([[b.raw[0]] if b else [], rec.x])
            ys = np.concatenate([[b.raw[1]] if b else [], rec.y])
            ts = np.concatenate([[b.stamp_ns] if b else [], rec.stamps_ns]).astype(np.float64) * 1e-9
            if (np.hypot(np.diff(xs), np.diff(ys)) <= MAX_SPEED * (np.abs(np.diff(ts)) + STAMP_JITTER_S)).all():
                last = np.array([rec.x[-1], rec.y[-1], rec.yaw[-1]])
                self._odom[rec.topic] = _Bridge(int(rec.stamps_ns[-1]), last, last)
                return rec
        recs = [r for r in (self.check(o) for o in rec.records()) if r is not None]
        if not recs:
            return None
        return OdometrySamples(np.array([r.stamp_ns for r in recs], np.int64), np.array([r.x for r in recs]),
                               np.array([r.y for r in recs]), np.array([r.yaw for r in recs]),
                               np.array([r.z for r in recs]), rec.frame_id, rec.child_frame_id, rec.topic)

    # -- counting ------------------------------------------------------------------------------------------------------
    def _skip(self, rec, why: str, stamp_ns: int, todo: str):
        topic = getattr(rec, "topic", "") or "?"
        self._count(f"a {type(rec).__name__} on {topic} has {why} (first at t={stamp_ns * 1e-9:.3f} s); such records "
                    f"are skipped: {todo}", topic, type(rec).__name__ + why.split(" of ")[0])
        return None

    def _count(self, text: str, topic: str, kind: str) -> None:
        key = f"{topic}:{kind}"
        if key not in self.skipped:
            self.warn(f"{self.name}: {text}")
        self.skipped[key] = self.skipped.get(key, 0) + 1


def scan_problem(s: Scan) -> str | None:
    """Why a scan's beam geometry is unusable, else None."""
    n = len(s.ranges)
    if n > MAX_BEAMS:
        return f"{n} beams"
    if n == 0:  # no returns at all: nothing to check (the pipeline counts such scans)
        return None
    if not (math.isfinite(s.angle_min) and math.isfinite(s.angle_increment)):
        return "a non-finite angle_min or angle_increment"
    if n > 1 and s.angle_increment == 0:
        return f"an angle_increment of {s.angle_increment:g} rad for {n} beams"
    if not (math.isfinite(s.range_max) or s.range_max == math.inf) or math.isnan(s.range_min) or s.range_max <= 0:
        return "an unusable range_min or range_max"
    return None


def camera_problem(c: CameraModel) -> str | None:
    """Why a camera's intrinsics are unusable (they divide every pixel's ray), else None."""
    K = np.asarray(c.K, dtype=float)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        return "non-finite intrinsics"
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0 and fy > 0):
        return f"focal lengths fx={fx:g}, fy={fy:g} (must be > 0)"
    if min(c.width, c.height) < MIN_IMAGE_SIDE:
        return f"an image size of {c.width}×{c.height}"
    w, h = c.width, c.height
    if not (-MAX_PRINCIPAL_OFFSET * w <= cx <= (1 + MAX_PRINCIPAL_OFFSET) * w
            and -MAX_PRINCIPAL_OFFSET * h <= cy <= (1 + MAX_PRINCIPAL_OFFSET) * h):
        return f"a principal point ({cx:g}, {cy:g}) far outside its {w}×{h} image"
    return None


def transforms_problem(rec: Transforms) -> str | None:
    """Why a tf message is unusable (a transform with a non-finite or impossible translation or rotation), else
    None."""
    for tf in rec.transforms:
        t, q = np.asarray(tf.translation, dtype=float), np.asarray(tf.rotation, dtype=float)
        if not (np.isfinite(t).all() and np.isfinite(q).all()) or np.abs(t).max(initial=0) > 1e7:
            return f"a transform {tf.parent} → {tf.child} with non-finite or impossible numbers"
    return None
