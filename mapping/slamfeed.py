"""Scans into one SLAM, each with the wheel odometry at its stamp (what `kosmap build` and `kosmap slam --source
kos` feed it; mapping/runtime/slamproc.py runs the same feed in a process of its own)."""

from __future__ import annotations

from bisect import bisect_left
from collections import deque

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.odometry import WheelOdometry, scan_points_base, scan_to_points
from kosmap.frontend.records import Odometry

ODOM_WAIT_S = 1.0  # a scan waits at most this long (log time) for the wheel odometry sample after it
ODOM_STALE_S = 0.5  # a scan farther than this from every odometry sample gets no odometry prior


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
        beam by beam (time_increment > 0): its points are made once the odometry around its stamp is in,
        de-skewed with the odometry's twist (frontend/deskew.py) when there is one."""
        self.pending.append((int(stamp_ns), points, deskew))

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
            odom = self._odom_at(stamp) if self.use_odom else None
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
        """SLAM's solved run (backend/slam.py SlamResult), None when no scan reached it; KosmapError when it failed."""
        return self.slam.finish() if self.slam.stamps else None

    def close(self) -> None:
        """Nothing to release in this process (mapping/runtime/slamproc.py's feed stops its process)."""

    def _odom_at(self, stamp: int) -> np.ndarray | None:
        """Interpolated between the samples around `stamp` (the later within ODOM_WAIT_S); else held at the
        nearer sample within ODOM_STALE_S; else None."""
        t, p = self.wheel.t, self.wheel.p
        wait, stale = int(ODOM_WAIT_S * 1e9), int(ODOM_STALE_S * 1e9)
        i = bisect_left(t, stamp)
        after = i < len(t) and t[i] - stamp <= wait
        if after and i > 0:
            a = (stamp - t[i - 1]) / (t[i] - t[i - 1]) if t[i] > t[i - 1] else 1.0
            q = (1.0 - a) * np.array(p[i - 1]) + a * np.array(p[i])
        elif after and t[i] - stamp <= stale:
            q = np.array(p[i])
        elif i > 0 and stamp - t[i - 1] <= stale:
            q = np.array(p[i - 1])
        else:
            return None
        q[2] = float(se2.wrap(q[2]))
        return q

