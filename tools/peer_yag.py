"""The laser SLAM benchmark's peer: OpenKarto's correlative scan matcher and pose graph as packaged by yag-slam
(PyPI `yag-slam`, the `bench` extra; its C++ parts come as wheels: karto_scanmatcher, sparse_bundle_adjustment).

What it maps, so that the peer is fed what kosmap is fed:
- the scans: the log's laser scans as kosmap's SLAM reads them (mapping/slamfeed.py: the same topics, the same
  [build] laser_rate thinning), each Scan (sensor_msgs/LaserScan fields) → a yag `LocalizedRangeScan` with the same
  angle_min / angle_increment / range limits; a no-return (not finite, outside [range_min, range_max)) becomes a
  reading beyond Karto's range threshold, which Karto skips;
- the odometry: the wheel odometry at each scan's stamp by kosmap's one rule (`odom_at`), composed with the laser's
  mount (`laser_mount`), as the scan's odom pose: Karto poses the laser's own frame (its scan config has no mount),
  which is the frame the benchmark relations relate;
- the keyframes: a scan enters Karto's graph when the laser moved `min_distance` or turned `min_rotation` since the
  last one entered (the ROS node's rule, with OpenKarto's own spacing); the matcher and loop settings are yag-slam's
  ROS node's defaults: one setting for every log, as kosmap's;
- the trajectory back: every scan's pose is its latest keyframe's optimised pose ⊕ the odometry since that keyframe
  (the map→odom correction the ROS node publishes), so every relation stamp has a pose.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kosmap.backend.consistency import consistency, keep_points
from kosmap.frontend import se2
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.odometry import WheelOdometry
from kosmap.frontend.records import Odometry, OdometrySamples, Scan, Transforms
from kosmap.mapping.config import Config
from kosmap.mapping.slamfeed import laser_mount, laser_period, odom_at, odometry_columns

INSTALL_HINT = "yag-slam not installed: pip install -e .[bench]"


def unavailable() -> str | None:
    """None when yag-slam imports, else why not (the line the benchmark prints in the peer's row)."""
    try:
        import karto_scanmatcher  # noqa: F401
        import yag_slam.graph_slam  # noqa: F401
    except ImportError:
        return INSTALL_HINT
    except Exception as e:  # a wheel that does not load here (ABI, missing system library)
        return f"yag-slam does not load: {type(e).__name__}: {e}"
    return None


@dataclass
class LaserLog:
    """What both SLAMs are fed: the laser scans used, the odometry of the laser's frame at each (NaN where none)."""

    scans: list[Scan]
    odom: np.ndarray  # (S, 3) wheel odometry ⊕ mount at each scan's stamp
    mount: np.ndarray  # (3,) the laser in the robot's frame

    @property
    def stamps(self) -> np.ndarray:
        return np.array([s.stamp_ns for s in self.scans], np.int64) * 1e-9


@dataclass(frozen=True)
class YagSettings:
    """yag-slam's ROS node defaults (ros1/slam_node_ros1, setup_mapper; GraphSlam's own loop search distance, which
    the node does not override) with OpenKarto's keyframe spacing (Mapper's MinimumTravelDistance 0.2 m and
    MinimumTravelHeading 10°, slam_karto's too): the node's 0.5 m / 0.5 rad leaves three times as much of the path
    to the odometry between keyframes (docs/benchmarks.md gives both)."""

    min_distance: float = 0.2  # m the laser moves before a scan enters the graph
    min_rotation: float = math.radians(10.0)  # rad it turns before a scan enters the graph
    range_threshold: float = 20.0  # m, Karto ignores returns farther than this
    seq: dict = field(default_factory=lambda: {
        "angle_variance_penalty": 0.349, "distance_variance_penalty": 0.3, "coarse_search_angle_offset": 0.349,
        "coarse_angle_resolution": 0.0349, "fine_search_angle_resolution": 0.00349, "use_response_expansion": True,
        "minimum_angle_penalty": 0.9, "search_size": 0.3, "resolution": 0.01, "smear_deviation": 0.07})
    loop: dict = field(default_factory=lambda: {"search_size": 4.0, "resolution": 0.05, "smear_deviation": 0.03})
    loop_search_dist: float = 3.0
    loop_search_min_chain_size: int = 10
    scan_buffer_len: int = 10
    min_response_coarse: float = 0.6
    min_response_fine: float = 0.7
    loop_closure: bool = True  # False: sequential matching only (no loop matcher)


@dataclass
class YagRun:
    poses: np.ndarray  # (S, 3) every scan's laser pose in the map
    key_idx: np.ndarray  # (K,) the scans that entered yag-slam's graph
    loops: int  # loop closures yag-slam accepted


@dataclass
class PeerResult:
    stamps: np.ndarray  # (S,) s
    poses: np.ndarray  # (S, 3) the laser's frame, map
    keyframes: int
    loops: int
    wall_s: float
    cpu_s: float
    duration_s: float
    consistency: dict


def read_laser_log(path: str | Path, cfg: Config | None = None, max_seconds: float | None = None) -> LaserLog:
    """The laser scans and the laser's odometry at them, by the topics, thinning, odometry rule and mount lookup
    of kosmap's laser SLAM (mapping/slam.py, mapping/slamfeed.py)."""
    cfg = cfg or Config()
    wheel = WheelOdometry()
    scans: list[Scan] = []
    statics: list[Transforms] = []
    base, last = "base_link", None
    with open_log(path, cfg.topics.on_damage) as log:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.scan:
            raise ValueError(f"{Path(path).name} has no laser scan topic")
        period = laser_period(cfg.build.laser_rate, info.count(det.scan), float(info.duration))
        topics = [det.scan] + ([det.odom] if det.odom else []) + ([det.tf_static] if det.tf_static else [])
        for rec in log.read_batched(topics):
            if isinstance(rec, (Odometry, OdometrySamples)) and rec.topic == det.odom:
                if base == "base_link" and rec.child_frame_id:
                    base = rec.child_frame_id.lstrip("/") or "base_link"
                for t, x, y, a in zip(*(c.tolist() for c in odometry_columns(rec))):
                    wheel.add(t, x, y, a)
            elif isinstance(rec, Transforms) and rec.static:
                statics.append(rec)
            elif isinstance(rec, Scan):
                if scans and max_seconds is not None and (rec.stamp_ns - scans[0].stamp_ns) * 1e-9 > max_seconds:
                    break
                if last is None or rec.stamp_ns - last >= period - 1_000_000:
                    scans.append(rec)
                    last = rec.stamp_ns
    if not scans:
        raise ValueError(f"{Path(path).name}: no laser scans")
    lm = laser_mount(statics, base, scans[0].frame_id)
    mount, scans = lm.pose, [lm.read(s) for s in scans]
    odom = np.full((len(scans), 3), np.nan)
    for i, s in enumerate(scans):
        q = odom_at(wheel, s.stamp_ns) if len(wheel) else None
        if q is not None:
            odom[i] = se2.compose(q, mount)
    return LaserLog(scans, odom, mount)


def karto_ranges(scan: Scan, range_threshold: float) -> np.ndarray:
    """The scan's ranges with every no-return moved beyond Karto's range threshold (Karto skips those)."""
    r = np.asarray(scan.ranges, np.float64).copy()
    r[~scan.valid()] = max(range_threshold, scan.range_max) + 1.0
    return r


def to_yag(scan: Scan, pose: np.ndarray, settings: YagSettings):
    """One of our scans at `pose` (x, y, yaw of the laser) → yag-slam's LocalizedRangeScan (odom = corrected)."""
    from yag_slam.models import LocalizedRangeScan

    thr = min(settings.range_threshold, scan.range_max)
    return LocalizedRangeScan(karto_ranges(scan, thr).tolist(), scan.angle_min, scan.angle_max, scan.angle_increment,
                              scan.range_min, scan.range_max, thr, float(pose[0]), float(pose[1]), float(pose[2]))


def pose_of(yscan, odom: bool = False) -> np.ndarray:
    """A yag-slam scan's corrected (or odom) pose as (x, y, yaw)."""
    p = yscan.odom_pose if odom else yscan.corrected_pose
    return np.array([p.x, p.y, p.euler[-1]])


def make_mapper(settings: YagSettings):
    from yag_slam.graph_slam import GraphSlam
    from yag_slam.scan_matching import Scan2DMatcherCpp

    seq = {**settings.seq, "range_threshold": settings.range_threshold}
    loop = {**seq, **settings.loop}
    loop_matcher = Scan2DMatcherCpp(loop, loop=True) if settings.loop_closure else None
    return GraphSlam(Scan2DMatcherCpp(seq), loop_matcher, scan_buffer_len=settings.scan_buffer_len,
                     loop_search_dist=settings.loop_search_dist,
                     loop_search_min_chain_size=settings.loop_search_min_chain_size,
                     min_response_coarse=settings.min_response_coarse, min_response_fine=settings.min_response_fine)


def _fill_odometry(odom: np.ndarray) -> np.ndarray:
    """Odometry with each missing row held at the last known one (Karto needs a pose for every scan; before the
    first sample, the origin)."""
    out = odom.copy()
    prev = np.zeros(3)
    for i in range(len(out)):
        if np.isfinite(out[i]).all():
            prev = out[i]
        else:
            out[i] = prev
    return out


def run_yag(log: LaserLog, settings: YagSettings | None = None) -> YagRun:
    """yag-slam's GraphSlam over the log: every scan's laser pose, which scans were its keyframes, loops closed."""
    settings = settings or YagSettings()
    if not np.isfinite(log.odom).any():
        raise ValueError("the log has no wheel odometry; yag-slam's keyframes and matching start from it")
    mapper = make_mapper(settings)
    odom = _fill_odometry(log.odom)
    key_of = np.zeros(len(odom), np.int64)
    keys: list = []
    key_idx: list[int] = []
    loops = 0
    for i, scan in enumerate(log.scans):
        if keys:
            d = se2.between(odom[key_idx[-1]], odom[i])
            if np.hypot(d[0], d[1]) < settings.min_distance and abs(d[2]) < settings.min_rotation:
                key_of[i] = len(keys) - 1
                continue
        y = to_yag(scan, odom[i], settings)
        _, closed = mapper.process_scan(y)
        loops += bool(closed)
        keys.append(y)
        key_idx.append(i)
        key_of[i] = len(keys) - 1
    kc = np.array([pose_of(k) for k in keys])  # after the last optimisation (run_opt writes every vertex back)
    ki = np.array(key_idx)
    poses = se2.compose(kc[key_of], se2.between(odom[ki][key_of], odom))
    return YagRun(poses, ki, loops)


def run_peer(path: str | Path, cfg: Config | None = None, max_seconds: float | None = None,
             settings: YagSettings | None = None) -> PeerResult:
    """Read the log and run yag-slam on it, timed as kosmap's run is (reading included)."""
    w0, c0 = time.perf_counter(), time.process_time()
    log = read_laser_log(path, cfg, max_seconds)
    run = run_yag(log, settings)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    st = log.stamps
    return PeerResult(st, run.poses, len(run.key_idx), run.loops, wall, cpu, float(st[-1] - st[0]),
                      peer_consistency(log, run))


def peer_consistency(log: LaserLog, run: YagRun) -> dict:
    """kosmap's self-consistency figure (backend/consistency.py) of yag-slam's keyframes: their laser poses and
    scan points (the laser's frame); no loop residuals (yag-slam does not expose them)."""
    ki = run.key_idx
    pts = [keep_points(log.scans[i].points()) for i in ki]
    t = log.stamps[ki] - log.stamps[0]
    return consistency(t, run.poses[ki], pts).as_dict()
