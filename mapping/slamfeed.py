"""The one way scans reach SLAM, for `kosmap slam` (mapping/slam.py) and `kosmap build` (mapping/build/) alike:
the wheel odometry at a scan's stamp (`odom_at`), the laser's mount (`laser_mount`), which laser scans are used
(`laser_period`) and when a scan is handed over (`SlamFeed`). The same log gives both commands the same inputs in
the same order, so the same trajectory.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.camera import lookup_static
from kosmap.frontend.odometry import WheelOdometry, scan_points_base, scan_to_points
from kosmap.frontend.records import Odometry, OdometrySamples, Scan

ODOM_WAIT_S = 1.0  # a scan waits at most this long (log time) for the wheel odometry sample after it
ODOM_STALE_S = 0.5  # a scan farther than this from every odometry sample gets no odometry prior
# Two samples farther apart than this are not interpolated between: the robot's motion across a gap in the
# odometry is unknown (a straight line through it bent the map), so a scan there is matched without odometry.
ODOM_MAX_GAP_S = 2 * ODOM_STALE_S


def odom_at(wheel: WheelOdometry, stamp: int) -> np.ndarray | None:
    """The wheel odometry at `stamp`: interpolated between the samples around it when they are at most
    ODOM_MAX_GAP_S apart (the later within ODOM_WAIT_S); else held at the nearer sample within ODOM_STALE_S; else
    None."""
    t, p = wheel.t, wheel.p
    wait, stale, gap = int(ODOM_WAIT_S * 1e9), int(ODOM_STALE_S * 1e9), int(ODOM_MAX_GAP_S * 1e9)
    i = bisect_left(t, stamp)
    after = i < len(t) and t[i] - stamp <= wait
    if after and i > 0 and t[i] - t[i - 1] <= gap:
        a = (stamp - t[i - 1]) / (t[i] - t[i - 1]) if t[i] > t[i - 1] else 1.0
        q = (1.0 - a) * np.array(p[i - 1]) + a * np.array(p[i])
    elif after and t[i] - stamp <= stale and (i == 0 or stamp - t[i - 1] > t[i] - stamp):
        q = np.array(p[i])
    elif i > 0 and stamp - t[i - 1] <= stale:
        q = np.array(p[i - 1])
    else:
        return None
    q[2] = float(se2.wrap(q[2]))
    return q


@dataclass(frozen=True)
class LaserMount:
    """The laser's planar pose (x, y, yaw) in the robot's frame, and whether it is mounted upside down (its z axis
    down: it scans the other way round, REP 103, and its scans are read `upright`)."""

    pose: np.ndarray
    flipped: bool = False
    warning: str | None = None  # no static transform found: the laser is taken as mounted at the robot's origin

    def read(self, scan: Scan) -> Scan:
        """The scan as SLAM, the maps and the localizer take it."""
        return upright(scan) if self.flipped else scan


def laser_mount(statics, base: str, frame: str) -> LaserMount:
    """The laser's mount from the static transforms: `base` (the wheel odometry's child frame) ← `frame`, else
    base_link ← `frame`; else at the origin, with a warning to say so."""
    tf = lookup_static(statics, base, frame) or lookup_static(statics, "base_link", frame)
    if tf is not None:
        return LaserMount(np.array([tf.translation[0], tf.translation[1], tf.rpy()[2]], float), tf.matrix()[2, 2] < 0)
    if frame.lstrip("/") in (base, "base_link", ""):
        return LaserMount(np.zeros(3))
    return LaserMount(np.zeros(3), False,
                      f"no static transform from {base} to {frame}; the laser is taken as mounted at {base}")


def upright(scan: Scan) -> Scan:
    """An upside-down laser's scan as an upright laser with the same planar pose would see it: its beam i bears
    −(angle_min + i·angle_increment), so the beams are reversed and start at −angle_max; their times run backwards
    from the last beam's, which becomes the stamp (frontend/deskew.py takes beam i at stamp + i·time_increment, a
    negative increment included)."""
    ti = float(scan.time_increment) if math.isfinite(scan.time_increment) else 0.0
    last = int(round(ti * max(len(scan.ranges) - 1, 0) * 1e9))
    return replace(scan, stamp_ns=scan.stamp_ns + last, ranges=scan.ranges[::-1].copy(), angle_min=-scan.angle_max,
                   intensities=scan.intensities[::-1].copy(), time_increment=-ti)


def laser_period(rate_hz: float, n_scans: int, duration_s: float) -> int:
    """Nanoseconds between the laser scans SLAM uses ([build] laser_rate; 0 = every scan): a laser averaging no
    more than 1.2× the rate keeps every scan (bursty stamps would lose some)."""
    if rate_hz <= 0 or (duration_s > 0 and n_scans / duration_s <= 1.2 * rate_hz):
        return 0
    return int(1e9 / rate_hz)


class SlamFeed:
    """Scans into one `Slam`, each with the wheel odometry at its stamp.

    A scan waits until an odometry sample at or after its stamp has been read, or until the log has moved
    ODOM_WAIT_S past it; the pose it gets depends only on the samples within that window (never on how far
    the reader ran ahead), so a scan that reaches the feed late (from the worker pool) gets the same prior as
    one that came at once: serial and parallel runs feed SLAM identical inputs.
    """

    def __init__(self, slam, use_odom: bool, use_imu: bool = False) -> None:
        self.slam = slam
        self.use_odom = use_odom
        self.use_imu = use_imu and slam.gcfg.imu  # the log's gyro: scans also wait for its samples
        slam.expect_imu = self.use_imu
        slam.health.expect_odom = use_odom
        self.wheel = WheelOdometry()
        self.pending: deque[tuple[int, np.ndarray]] = deque()
        self.added = 0
        self.no_odom = 0

    def odom(self, rec: Odometry) -> None:
        self.wheel_sample(rec.stamp_ns, rec.x, rec.y, rec.yaw)

    def wheel_sample(self, stamp_ns: int, x: float, y: float, yaw: float) -> None:
        """One wheel odometry pose (what `odom` takes of a record)."""
        self.wheel.add(stamp_ns, x, y, yaw)

    def wheel_samples(self, stamps_ns: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> None:
        """Wheel odometry poses in their order (an OdometrySamples' columns)."""
        for t, a, b, c in zip(stamps_ns.tolist(), x.tolist(), y.tolist(), yaw.tolist()):
            self.wheel.add(t, a, b, c)

    def imu(self, rec) -> None:
        """One Imu record: straight to SLAM (its gyro factors wait for the samples by themselves)."""
        if self.use_imu:
            self.slam.add_imu(rec)

    def gyro(self, stamp_ns: int, yaw_rate: float) -> None:
        """One gyro sample of an Imu record that has angular velocity (what Slam.add_imu takes of it)."""
        if self.use_imu:
            self.slam.add_imu(stamp_ns, yaw_rate)

    def gyro_samples(self, stamps_ns: np.ndarray, yaw_rates: np.ndarray) -> None:
        """Gyro samples in their order (of an ImuSamples, those with angular velocity)."""
        if self.use_imu:
            self.slam.add_imu_many(stamps_ns, yaw_rates)

    def push(self, stamp_ns: int, points: np.ndarray | None, deskew: tuple | None = None) -> None:
        """A scan's points (base_link), or None with `deskew` = (scan, mount, min_range, max_range) for a scan taken
        beam by beam (time_increment ≠ 0): its points are made once the odometry around its stamp is in,
        de-skewed with the odometry's twist (frontend/deskew.py) when there is one."""
        self.pending.append((int(stamp_ns), points, deskew))

    def push_laser(self, scan: Scan, mount: np.ndarray) -> None:
        """A laser scan mounted at `mount` (x, y, yaw in base_link): de-skewed when taken beam by beam and the
        config asks for it, else its end points as they are."""
        o = self.slam.ocfg
        inc = abs(float(scan.angle_increment))
        self.slam.set_sensor(inc * len(scan.ranges), inc)  # the keyframe spacing follows the scanner's FOV
        if o.deskew and abs(scan.time_increment) > 0:  # its points are made when the odometry has caught up
            self.push(scan.stamp_ns, None, (scan, mount, o.min_range, o.max_range))
        else:
            self.push(scan.stamp_ns, scan_points_base(scan.ranges, scan.angles, scan.valid(), mount, o.min_range,
                                                      o.max_range))

    def advance(self, now_ns: int | None) -> None:
        """Hand SLAM every pending scan whose odometry is settled (`now_ns` None: the log has ended)."""
        wait = int(ODOM_WAIT_S * 1e9)
        while self.pending:
            stamp, pts, deskew = self.pending[0]
            settled = ((not self.use_odom or self.wheel.covers(stamp))
                       and (not self.use_imu or self.slam.gyro.covers(stamp)))
            if now_ns is not None and not settled and now_ns - stamp <= wait:
                return
            self.pending.popleft()
            odom = odom_at(self.wheel, stamp) if self.use_odom else None
            if self.use_odom and odom is None:
                self.no_odom += 1
            if deskew is not None:
                scan, mount, lo, hi = deskew
                twist = self.wheel.twist_at(stamp, mount) if self.use_odom else None
                pts = (scan_to_points(scan, mount, lo, hi, twist) if twist is not None
                       else scan_points_base(scan.ranges, scan.angles, scan.valid(), mount, lo, hi))
            self.slam.add_scan(stamp, pts, odom)
            self.added += 1
            self.wheel.drop_before(stamp - int(2e9))

    def end(self) -> None:
        """The log has ended (or the read was interrupted): every pending scan goes to SLAM."""
        self.advance(None)

    def result(self):
        """SLAM's solved run (mapping/slam.py SlamResult), None when no scan reached it; KosmapError when it failed."""
        return self.slam.finish() if self.slam.stamps else None

    def close(self) -> None:
        """Nothing to release in this process (mapping/runtime/slamproc.py's feed stops its process)."""


def no_odom_warning(no_odom: int, stretches: dict, what: str) -> str | None:
    """The line for the `no_odom` scans that got no wheel odometry, unless the run's stretch warning already names
    them (`stretches`: SlamResult.stretches, backend/slamhealth.py)."""
    if not no_odom or stretches.get("no_odometry_s"):
        return None
    return f"{no_odom} {what} scan(s) had no wheel odometry within {ODOM_STALE_S} s: matched without it"


def odometry_columns(rec: Odometry | OdometrySamples) -> tuple[np.ndarray, ...]:
    """(stamps ns, x, y, yaw) of an OdometrySamples, or of one Odometry record as columns of one."""
    if isinstance(rec, OdometrySamples):
        return rec.stamps_ns, rec.x, rec.y, rec.yaw
    return np.array([rec.stamp_ns], np.int64), np.array([rec.x]), np.array([rec.y]), np.array([rec.yaw])
