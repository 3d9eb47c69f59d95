"""Record types that cross folders: what a log yields and what the stages exchange.

SI units inside (metres, radians); stamps are integer nanoseconds (as in ROS 2 and MCAP) so that a
record written and read back is bit-exact, with a float `stamp` in seconds for arithmetic.
Frames follow REP 103/105 (docs/design.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

DEPTH_ENCODINGS = ("16UC1", "32FC1")  # mono16 is read as 16UC1 (same bytes, millimetres)


def seconds_to_ns(t: float) -> int:
    """Seconds (float) to integer nanoseconds, rounded."""
    return int(round(t * 1e9))


@dataclass(frozen=True)
class Transform:
    """A rigid transform that maps points in `child` coordinates into `parent` coordinates."""

    parent: str
    child: str
    translation: np.ndarray  # (3,) metres
    rotation: np.ndarray  # (4,) unit quaternion x, y, z, w
    stamp_ns: int = 0

    @classmethod
    def identity(cls, parent: str, child: str) -> Transform:
        return cls(parent, child, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

    @classmethod
    def from_xyz_rpy(cls, parent: str, child: str, xyz, rpy, stamp_ns: int = 0) -> Transform:
        """From a translation and roll, pitch, yaw (fixed axes x, y, z, as in ROS)."""
        q = Rotation.from_euler("xyz", rpy).as_quat()
        return cls(parent, child, np.asarray(xyz, dtype=float), q, stamp_ns)

    @classmethod
    def from_matrix(cls, parent: str, child: str, m: np.ndarray, stamp_ns: int = 0) -> Transform:
        return cls(parent, child, np.array(m[:3, 3], dtype=float), Rotation.from_matrix(m[:3, :3]).as_quat(), stamp_ns)

    @property
    def stamp(self) -> float:
        return self.stamp_ns * 1e-9

    def matrix(self) -> np.ndarray:
        """4×4 homogeneous matrix parent←child."""
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(self.rotation).as_matrix()
        m[:3, 3] = self.translation
        return m

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map N×3 points from the child frame into the parent frame."""
        m = self.matrix()
        return np.asarray(points) @ m[:3, :3].T + m[:3, 3]

    def inverse(self) -> Transform:
        return Transform.from_matrix(self.child, self.parent, np.linalg.inv(self.matrix()), self.stamp_ns)

    def compose(self, other: Transform) -> Transform:
        """self ∘ other: parent(self) ← child(other); other.parent must be self.child."""
        if other.parent != self.child:
            raise ValueError(f"cannot compose {self.parent}←{self.child} with {other.parent}←{other.child}")
        return Transform.from_matrix(self.parent, other.child, self.matrix() @ other.matrix(), self.stamp_ns)

    def rpy(self) -> np.ndarray:
        return Rotation.from_quat(self.rotation).as_euler("xyz")


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics of a depth camera, as in sensor_msgs/CameraInfo."""

    width: int
    height: int
    K: np.ndarray  # 3×3
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = "plumb_bob"
    frame_id: str = ""
    topic: str = ""
    stamp_ns: int = 0

    @classmethod
    def from_fov(cls, width: int, height: int, fov_h: float, fov_v: float, frame_id: str = "") -> CameraModel:
        """The field-of-view model when no CameraInfo exists: fx = (w/2)/tan(fH/2), fy = (h/2)/tan(fV/2).

        (The thesis's eq. 2.1–2.2 reaches only half the field of view; docs/design.md.)
        """
        fx = (width / 2.0) / np.tan(fov_h / 2.0)
        fy = (height / 2.0) / np.tan(fov_v / 2.0)
        K = np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(width, height, K, np.zeros(5), "plumb_bob", frame_id)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def fov_h(self) -> float:
        """Horizontal field of view (rad) spanned by the image's columns."""
        return float(np.arctan(self.cx / self.fx) + np.arctan((self.width - 1 - self.cx) / self.fx))

    @property
    def fov_v(self) -> float:
        return float(np.arctan(self.cy / self.fy) + np.arctan((self.height - 1 - self.cy) / self.fy))


@dataclass(frozen=True)
class DepthFrame:
    """One depth image as it came (uint16 mm for 16UC1, float32 m for 32FC1); `meters()` converts once."""

    stamp_ns: int
    image: np.ndarray  # H×W uint16 or float32
    encoding: str  # "16UC1" or "32FC1"
    frame_id: str = ""
    topic: str = ""

    @property
    def stamp(self) -> float:
        return self.stamp_ns * 1e-9

    def meters(self) -> np.ndarray:
        """Depth in metres as float32; invalid pixels are 0 (16UC1) or NaN/0 (32FC1), as they came."""
        if self.encoding == "16UC1":  # (one pass: the same float32 products as astype, then ×)
            return np.multiply(self.image, np.float32(0.001), dtype=np.float32)
        return self.image.astype(np.float32, copy=False)


@dataclass(frozen=True)
class Scan:
    """A planar range scan, as in sensor_msgs/LaserScan: beam i points at angle_min + i·angle_increment.

    Ranges outside [range_min, range_max) or not finite are no-returns (REP 117: +inf means nothing
    within range_max).
    """

    stamp_ns: int
    ranges: np.ndarray  # (n,) float32 metres
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    frame_id: str = ""
    topic: str = ""
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    time_increment: float = 0.0
    scan_time: float = 0.0

    @property
    def stamp(self) -> float:
        return self.stamp_ns * 1e-9

    @property
    def angle_max(self) -> float:
        return self.angle_min + (len(self.ranges) - 1) * self.angle_increment

    @cached_property
    def angles(self) -> np.ndarray:
        return self.angle_min + np.arange(len(self.ranges)) * self.angle_increment

    def valid(self) -> np.ndarray:
        r = self.ranges
        return np.isfinite(r) & (r >= self.range_min) & (r < self.range_max)

    def points(self) -> np.ndarray:
        """Beam end points (N×2, metres, scan frame) of the beams that returned."""
        ok = self.valid()
        r = self.ranges[ok].astype(np.float64)
        a = self.angles[ok]
        return np.column_stack((r * np.cos(a), r * np.sin(a)))


@dataclass(frozen=True)
class Odometry:
    """A planar pose (x, y, yaw) of `child_frame_id` in `frame_id`, as in nav_msgs/Odometry."""

    stamp_ns: int
    x: float
    y: float
    yaw: float
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    topic: str = ""
    z: float = 0.0

    @property
    def stamp(self) -> float:
        return self.stamp_ns * 1e-9


class _Samples:
    """What the column records (OdometrySamples, ImuSamples) share: samples with their stamps in log order."""

    stamps_ns: np.ndarray  # (n,) int64

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def stamp_ns(self) -> int:
        """The first sample's stamp (where the batch stands in the log's order)."""
        return int(self.stamps_ns[0])

    @property
    def end_ns(self) -> int:
        """The latest sample's stamp (the batch reaches this far; the samples after its first may come ahead of
        other topics' records, as a chunk holds them)."""
        return int(self.stamps_ns.max())


@dataclass(frozen=True)
class OdometrySamples(_Samples):
    """Consecutive Odometry records of one topic as columns: what `LogReader.read_batched` hands for a stretch of a
    50–100 Hz odometry stream (an MCAP chunk's worth), so that it costs a few numpy calls, not a record each."""

    stamps_ns: np.ndarray  # (n,) int64, in the order of the log
    x: np.ndarray  # (n,) float64
    y: np.ndarray
    yaw: np.ndarray
    z: np.ndarray
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    topic: str = ""

    def records(self) -> list[Odometry]:
        """The samples as the Odometry records `read` gives."""
        return [Odometry(int(t), x, y, a, self.frame_id, self.child_frame_id, self.topic, z)
                for t, x, y, a, z in zip(self.stamps_ns.tolist(), self.x.tolist(), self.y.tolist(), self.yaw.tolist(),
                                         self.z.tolist())]


_IMU_FIELDS = (("angular_velocity", 3), ("linear_acceleration", 3), ("orientation", 4), ("orientation_cov", 9),
               ("angular_velocity_cov", 9), ("linear_acceleration_cov", 9))


@dataclass(frozen=True)
class ImuSamples(_Samples):
    """Consecutive Imu records of one topic as columns (n × the Imu's fields): a 200 Hz gyro's stretch of the log
    (`LogReader.read_batched`), a few numpy calls instead of a record each."""

    stamps_ns: np.ndarray  # (n,) int64, in the order of the log
    angular_velocity: np.ndarray  # (n, 3) rad/s
    linear_acceleration: np.ndarray  # (n, 3) m/s²
    orientation: np.ndarray  # (n, 4) x, y, z, w
    orientation_cov: np.ndarray  # (n, 9)
    angular_velocity_cov: np.ndarray  # (n, 9)
    linear_acceleration_cov: np.ndarray  # (n, 9)
    frame_id: str = ""
    topic: str = ""

    @property
    def has_angular_velocity(self) -> np.ndarray:
        """Per sample, as Imu.has_angular_velocity (covariance[0] ≠ −1)."""
        return self.angular_velocity_cov[:, 0] != -1.0

    @property
    def has_linear_acceleration(self) -> np.ndarray:
        return self.linear_acceleration_cov[:, 0] != -1.0

    @property
    def yaw_rate(self) -> np.ndarray:
        """Per sample, as Imu.yaw_rate."""
        return self.angular_velocity[:, 2]

    def select(self, keep: np.ndarray) -> ImuSamples:
        """The samples where `keep` (a boolean mask) is true."""
        return ImuSamples(self.stamps_ns[keep], *(getattr(self, name)[keep] for name, _ in _IMU_FIELDS),
                          frame_id=self.frame_id, topic=self.topic)

    def records(self) -> list[Imu]:
        """The samples as the Imu records `read` gives."""
        cols = [getattr(self, name) for name, _ in _IMU_FIELDS]
        return [Imu(int(t), *(c[i] for c in cols), self.frame_id, self.topic)
                for i, t in enumerate(self.stamps_ns.tolist())]


@dataclass(frozen=True)
class Imu:
    """One sensor_msgs/Imu sample in `frame_id` (body rates rad/s, specific force m/s², orientation x, y, z, w).

    Covariances are row-major 3×3 as in the message: element 0 = −1 means that quantity is not provided
    (a raw MEMS stream has no orientation); all zeros means "covariance unknown" (the message spec).
    """

    stamp_ns: int
    angular_velocity: np.ndarray  # (3,) rad/s
    linear_acceleration: np.ndarray  # (3,) m/s², gravity included (a resting IMU reads +9.81 on z)
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))  # (4,) x, y, z, w
    orientation_cov: np.ndarray = field(default_factory=lambda: np.array([-1.0] + [0.0] * 8))  # (9,)
    angular_velocity_cov: np.ndarray = field(default_factory=lambda: np.zeros(9))  # (9,)
    linear_acceleration_cov: np.ndarray = field(default_factory=lambda: np.zeros(9))  # (9,)
    frame_id: str = ""
    topic: str = ""

    def __post_init__(self) -> None:
        for name, n in _IMU_FIELDS:  # float64 arrays of their length (kept as given when they are: 200 Hz records)
            v = getattr(self, name)
            if type(v) is not np.ndarray or v.dtype != np.float64 or v.shape != (n,):
                object.__setattr__(self, name, np.asarray(v, dtype=np.float64).reshape(n))

    @property
    def stamp(self) -> float:
        return self.stamp_ns * 1e-9

    @property
    def has_orientation(self) -> bool:
        """False when orientation_covariance[0] is −1 (orientation not provided, sensor_msgs/Imu)."""
        return bool(self.orientation_cov[0] != -1.0)

    @property
    def has_angular_velocity(self) -> bool:
        return bool(self.angular_velocity_cov[0] != -1.0)

    @property
    def has_linear_acceleration(self) -> bool:
        return bool(self.linear_acceleration_cov[0] != -1.0)

    @property
    def has_angular_velocity_cov(self) -> bool:
        """True when the gyro's covariance is given: not −1 (not provided) and not all zeros (unknown)."""
        c = self.angular_velocity_cov
        return bool(c[0] != -1.0 and np.any(c != 0.0))

    @property
    def has_linear_acceleration_cov(self) -> bool:
        c = self.linear_acceleration_cov
        return bool(c[0] != -1.0 and np.any(c != 0.0))

    @property
    def yaw_rate(self) -> float:
        """Rate about the frame's z axis (rad/s); for an IMU mounted level on base_link, the robot's yaw rate."""
        return float(self.angular_velocity[2])


@dataclass(frozen=True)
class Transforms:
    """One tf2_msgs/TFMessage: transforms from /tf (moving) or /tf_static (mounts)."""

    stamp_ns: int
    transforms: tuple[Transform, ...]
    static: bool
    topic: str = ""

    @property
    def stamp(self) -> float:
        return self.stamp_ns * 1e-9


Record = DepthFrame | CameraModel | Scan | Odometry | Transforms | Imu


def yaw_to_quat(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(yaw / 2.0), np.cos(yaw / 2.0)])


def quat_to_yaw(x: float, y: float, z: float, w: float) -> float:
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))
