"""The simulator's settings: one range-checked dataclass, defaults from datasheets and realistic robots.

Lives in tools/ (mapping must not import tools); `kosmap simulate --set key=value` overrides a field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from kosmap.frontend.errors import ConfigError
from kosmap.frontend.params import StageConfig, param
from kosmap.tools.simulate.motion import OdometryNoise
from kosmap.tools.simulate.render import LaserModel, camera_mount, kinect_v2_model, laser_mount
from kosmap.tools.simulate.imu import ImuNoise
from kosmap.tools.simulate.sensors import DepthNoise, LaserNoise

_POS = {"lo": 0.0, "lo_open": True}


@dataclass
class SimConfig(StageConfig):
    """[simulate]: robot motion, sensors (Kinect v2, Hokuyo UTM-30LX, wheel odometry), noise, topics."""

    section = "simulate"
    seed: int = param(0, lo=0, doc="random seed: the same seed gives a byte-identical log")
    duration: float = param(0.0, lo=0.0, hi=7 * 86400.0, doc="seconds to simulate; 0 = until the path ends", unit="s")
    start_time: float = param(1_700_000_000.0, lo=0.0, doc="stamp of the first message (epoch)", unit="s")
    # motion
    speed_min: float = param(0.3, **_POS, doc="slowest cruise speed of a leg", unit="m/s")
    speed_max: float = param(0.6, **_POS, doc="fastest cruise speed of a leg", unit="m/s")
    accel: float = param(0.5, **_POS, doc="linear acceleration", unit="m/s²")
    turn_rate_deg: float = param(45.0, **_POS, doc="turn-in-place rate", unit="deg/s")
    turn_accel_deg: float = param(90.0, **_POS, doc="angular acceleration", unit="deg/s²")
    robot_radius: float = param(0.25, lo=0.0, doc="the path keeps this far from every solid", unit="m")
    # depth cameras (Kinect v2)
    depth_rate: float = param(30.0, **_POS, doc="depth frame rate", unit="Hz")
    depth_width: int = param(512, lo=2, doc="depth image width", unit="px")
    depth_height: int = param(424, lo=2, doc="depth image height", unit="px")
    fov_h_deg: float = param(70.6, lo=1.0, hi=179.0, doc="horizontal field of view", unit="deg")
    fov_v_deg: float = param(60.0, lo=1.0, hi=179.0, doc="vertical field of view", unit="deg")
    camera_xyz: list = param([0.1, 0.0, 1.0], doc="front camera_link in base_link", unit="m")
    camera_rpy_deg: list = param([0.0, 0.0, 0.0], doc="front camera roll, pitch (> 0 looks down), yaw", unit="deg")
    camera_ns: str = param("/kinect2/sd", doc="front camera topic namespace (kinect2_bridge)")
    camera_frame: str = param("kinect2_ir_optical_frame", doc="front camera optical frame id")
    rear_camera: bool = param(False, doc="add a rear-facing camera")
    rear_xyz: list = param([-0.1, 0.0, 1.0], doc="rear camera_link in base_link", unit="m")
    rear_rpy_deg: list = param([0.0, 0.0, 180.0], doc="rear camera roll, pitch, yaw", unit="deg")
    rear_ns: str = param("/kinect2_rear/sd", doc="rear camera topic namespace")
    rear_frame: str = param("kinect2_rear_ir_optical_frame", doc="rear camera optical frame id")
    extra_cameras: list = param([], doc="more depth cameras: a list of tables {ns, frame (default from ns), "
                                "xyz (m), rpy_deg (default level)}, each with its own topics and mount")
    surface_ids: bool = param(False, doc="also write each depth frame's ground-truth surface ids (<ns>/surface_id)")
    depth_min_range: float = param(0.5, lo=0.0, doc="nearer returns are invalid (0)", unit="m")
    depth_max_range: float = param(8.0, **_POS, doc="farther returns are invalid (0)", unit="m")
    depth_sigma_1m: float = param(0.0015, lo=0.0, doc="axial noise σ at 1 m", unit="m")
    depth_sigma_4m: float = param(0.010, lo=0.0, doc="axial noise σ at 4 m", unit="m")
    depth_sigma_angle: float = param(0.0001, lo=0.0, doc="incidence-angle noise term (Fankhauser et al. 2015)", unit="m")
    depth_dropout: float = param(0.005, lo=0.0, hi=1.0, doc="probability of a random invalid pixel")
    grazing_start_deg: float = param(70.0, lo=0.0, hi=90.0, doc="incidence where grazing dropouts begin", unit="deg")
    grazing_end_deg: float = param(85.0, lo=0.0, hi=90.0, doc="incidence where every pixel drops out", unit="deg")
    flying_prob: float = param(0.5, lo=0.0, hi=1.0, doc="probability that a depth-edge pixel becomes a flying pixel")
    flying_edge: float = param(0.05, lo=0.0, doc="depth jump (or 3 % of depth) that makes an edge", unit="m")
    corner_radius: float = param(1.3, lo=0.0, doc="normalised radius beyond which the rectified image is empty (corner = 1.414)")
    # laser (Hokuyo UTM-30LX)
    laser: bool = param(True, doc="simulate the laser scanner")
    laser_rate: float = param(40.0, **_POS, doc="scan rate", unit="Hz")
    laser_beams: int = param(1081, lo=2, doc="beams per scan")
    laser_fov_deg: float = param(270.0, lo=1.0, hi=360.0, doc="angular span of a scan", unit="deg")
    laser_range_min: float = param(0.1, lo=0.0, doc="minimum range", unit="m")
    laser_range_max: float = param(30.0, **_POS, doc="maximum range (farther: no return, +inf)", unit="m")
    laser_sigma: float = param(0.01, lo=0.0, doc="range noise σ below 10 m", unit="m")
    laser_sigma_far: float = param(0.03, lo=0.0, doc="range noise σ beyond 10 m", unit="m")
    laser_dropout: float = param(0.001, lo=0.0, hi=1.0, doc="probability of a random no-return")
    laser_scan_time: float = param(0.025, lo=0.0, doc="time of one revolution (beams are cast from the pose at their own time)", unit="s")
    laser_xyz: list = param([0.15, 0.0, 0.35], doc="laser in base_link", unit="m")
    laser_rpy_deg: list = param([0.0, 0.0, 0.0], doc="laser roll, pitch, yaw", unit="deg")
    laser_frame: str = param("laser", doc="laser frame id")
    scan_topic: str = param("/scan", doc="laser topic")
    # odometry and ground truth
    odom_rate: float = param(50.0, **_POS, doc="wheel odometry rate", unit="Hz")
    odom_scale_error_left: float = param(0.010, lo=-0.5, hi=0.5, doc="left wheel radius error: its odometry counts this "
                                         "fraction more than it rolled (distance scale = mean of the wheels')")
    odom_scale_error_right: float = param(0.011, lo=-0.5, hi=0.5, doc="right wheel radius error; right − left makes "
                                          "a heading drift of (right − left)/wheel_base rad per metre")
    odom_wheel_base: float = param(0.5, **_POS, doc="distance between the drive wheels", unit="m")
    odom_scale_error: float = param(0.0, lo=-0.5, hi=0.5, doc="common translation scale error on top of the wheels'")
    odom_rot_scale_error: float = param(0.005, lo=-0.5, hi=0.5, doc="wheel base error: rotation scale on top of the "
                                        "wheels' (total turn-in-place scale (1 + this)(1 + mean wheel error))")
    odom_heading_bias_deg_per_m: float = param(0.1, lo=-10.0, hi=10.0, doc="heading drift per metre on top of the "
                                               "wheels' (total: OdometryNoise.heading_drift_deg_per_m)", unit="deg/m")
    odom_trans_noise: float = param(0.01, lo=0.0, doc="translation noise σ per √m", unit="m/√m")
    odom_rot_noise_deg: float = param(1.0, lo=0.0, doc="rotation noise σ per √rad turned", unit="deg/√rad")
    odom_rot_noise_per_m_deg: float = param(0.5, lo=0.0, doc="rotation noise σ per √m driven", unit="deg/√m")
    odom_topic: str = param("/odom", doc="wheel odometry topic (frame odom → base_link)")
    # IMU (a consumer MEMS part, e.g. BMI088 / ICM-20948 class, mounted level on base_link, frame imu_frame)
    imu: bool = param(True, doc="simulate a sensor_msgs/Imu stream (gyro + accelerometer, no orientation)")
    imu_rate: float = param(200.0, **_POS, doc="IMU sample rate", unit="Hz")
    imu_topic: str = param("/imu", doc="IMU topic")
    imu_frame: str = param("imu_link", doc="IMU frame id (identity mount on base_link in /tf_static)")
    imu_on_camera: bool = param(False, doc="the IMU sits on the front depth camera (a camera's built-in IMU): its "
                                "samples in the camera's optical frame, its frame id the camera's (imu_frame unused)")
    tf_static: bool = param(True, doc="write the mounts to /tf_static (false: a log without them, e.g. a handheld "
                            "camera's)")
    gyro_noise_density: float = param(0.005, lo=0.0, doc="gyro white noise density (angle random walk); σ per "
                                      "sample = density·√imu_rate", unit="deg/s/√Hz")
    gyro_bias_sigma: float = param(0.02, lo=0.0, doc="σ of the gyro's turn-on bias per axis (what a start-up "
                                   "calibration leaves)", unit="deg/s")
    gyro_bias_walk: float = param(0.0003, lo=0.0, doc="gyro bias rate random walk K: the bias wanders by K·√T in T "
                                  "seconds (0.0003 → 0.003 °/s ≈ 11 °/h in 100 s; Allan K·√(τ/3))", unit="deg/s/√s")
    accel_noise_density: float = param(150e-6, lo=0.0, doc="accelerometer white noise density", unit="g/√Hz")
    accel_bias_sigma: float = param(0.02, lo=0.0, doc="σ of the accelerometer's constant bias per axis", unit="m/s²")
    imu_gaps: list = param([], doc="faults: [[t0, t1], ...] seconds from the start with no IMU messages", unit="s")
    imu_stuck: list = param([], doc="faults: [[t0, t1], ...] seconds with the gyro output frozen at its last value",
                            unit="s")
    gt_rate: float = param(100.0, **_POS, doc="ground-truth pose rate", unit="Hz")
    gt_topic: str = param("/ground_truth/odom", doc="ground-truth topic (frame map → base_link)")
    compression: str = param("zstd", choices=("zstd", "lz4", "none"), doc="MCAP chunk compression")

    def __post_init__(self) -> None:
        super().__post_init__()
        s = self.section
        for name in ("camera_xyz", "camera_rpy_deg", "rear_xyz", "rear_rpy_deg", "laser_xyz", "laser_rpy_deg"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"config [{s}] {name} = {getattr(self, name)!r} must have 3 numbers")
        if self.speed_min > self.speed_max:
            raise ConfigError(f"config [{s}] speed_min = {self.speed_min} must not exceed speed_max = {self.speed_max}")
        if self.depth_max_range <= self.depth_min_range:
            raise ConfigError(f"config [{s}] depth_max_range = {self.depth_max_range} must exceed depth_min_range = "
                              f"{self.depth_min_range}")
        if self.laser_range_max <= self.laser_range_min:
            raise ConfigError(f"config [{s}] laser_range_max = {self.laser_range_max} must exceed laser_range_min = "
                              f"{self.laser_range_min}")
        if self.grazing_end_deg < self.grazing_start_deg:
            raise ConfigError(f"config [{s}] grazing_end_deg = {self.grazing_end_deg} must not be below "
                              f"grazing_start_deg = {self.grazing_start_deg}")
        if self.depth_sigma_4m < self.depth_sigma_1m or (self.depth_sigma_1m == 0) != (self.depth_sigma_4m == 0):
            raise ConfigError(f"config [{s}] depth_sigma_4m = {self.depth_sigma_4m} must be ≥ depth_sigma_1m = "
                              f"{self.depth_sigma_1m} (both 0 for no axial noise)")
        slowest = min(self.depth_rate, self.laser_rate, self.odom_rate, self.imu_rate, self.gt_rate)
        if 0 < self.duration < 2.0 / slowest:  # every stream needs two samples (odometry and truth interpolate)
            raise ConfigError(f"config [{s}] duration = {self.duration:g} s is too short: give 0 (the whole path) or at "
                              f"least {2.0 / slowest:.3g} s (two samples of the slowest stream, {slowest:g} Hz)")
        for name in ("imu_gaps", "imu_stuck"):
            object.__setattr__(self, name, _intervals(s, name, getattr(self, name)))
        for name in ("camera_ns", "rear_ns", "scan_topic", "odom_topic", "gt_topic", "imu_topic"):
            if not getattr(self, name).startswith("/"):
                raise ConfigError(f"config [{s}] {name} = {getattr(self, name)!r} must start with '/'")
        object.__setattr__(self, "extra_cameras", [_extra_camera(s, k, e) for k, e in enumerate(self.extra_cameras)])
        seen: dict[tuple[str, str], str] = {}  # (what, namespace or frame id) → the camera that claimed it
        for ns, frame, _, _, label, _ in self._camera_specs():
            for what, v in (("namespace", ns), ("frame", frame)):
                if (what, v) in seen:
                    raise ConfigError(f"config [{s}] {label}: {what} {v!r} is already used by {seen[what, v]}; "
                                      f"give each camera its own")
                seen[what, v] = label
            if self.laser and frame == self.laser_frame:
                raise ConfigError(f"config [{s}] {label}: frame {frame!r} is the laser's frame; give it its own")

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    # -- the models the simulator uses ------------------------------------------------------------------------------
    def camera_model(self, frame_id: str):
        return kinect_v2_model(frame_id, self.depth_width, self.depth_height, self.fov_h_deg, self.fov_v_deg)

    def _camera_specs(self) -> list[tuple[str, str, list, list, str, str]]:
        """(namespace, frame, xyz, rpy_deg, label, setting of its position) of each depth camera: front, rear,
        then the extras."""
        out = [(self.camera_ns, self.camera_frame, self.camera_xyz, self.camera_rpy_deg,
                "the front camera (camera_ns, camera_frame)", "camera_xyz")]
        if self.rear_camera:
            out.append((self.rear_ns, self.rear_frame, self.rear_xyz, self.rear_rpy_deg,
                        "the rear camera (rear_ns, rear_frame)", "rear_xyz"))
        for k, e in enumerate(self.extra_cameras):
            out.append((e["ns"], e["frame"], e["xyz"], e["rpy_deg"], f"extra_cameras[{k}]", f"extra_cameras[{k}].xyz"))
        return out

    def cameras(self) -> list[tuple[str, object]]:
        """(topic namespace, mount base_link ← optical) of each depth camera: front, rear, then the extras."""
        return [(ns, camera_mount(xyz, [math.radians(v) for v in rpy], frame))
                for ns, frame, xyz, rpy, _, _ in self._camera_specs()]

    def camera_settings(self) -> list[str]:
        """The setting that places each camera of cameras(), in the same order (for error messages)."""
        return [key for *_, key in self._camera_specs()]

    def laser_mount(self):
        return laser_mount(self.laser_xyz, [math.radians(v) for v in self.laser_rpy_deg], self.laser_frame)

    def laser_model(self) -> LaserModel:
        return LaserModel(self.laser_beams, self.laser_fov_deg, self.laser_range_min, self.laser_range_max,
                          self.laser_scan_time)

    def depth_noise(self) -> DepthNoise:
        return DepthNoise(self.depth_sigma_1m, self.depth_sigma_4m, self.depth_sigma_angle, self.depth_min_range,
                          self.depth_max_range, self.depth_dropout, self.grazing_start_deg, self.grazing_end_deg,
                          self.flying_prob, self.flying_edge, self.corner_radius)

    def laser_noise(self) -> LaserNoise:
        return LaserNoise(self.laser_sigma, self.laser_sigma_far, 10.0, self.laser_dropout)

    def odometry_noise(self) -> OdometryNoise:
        return OdometryNoise(self.odom_scale_error, self.odom_rot_scale_error, self.odom_heading_bias_deg_per_m,
                             self.odom_trans_noise, self.odom_rot_noise_deg, self.odom_rot_noise_per_m_deg,
                             self.odom_scale_error_left, self.odom_scale_error_right, self.odom_wheel_base)

    def imu_noise(self) -> ImuNoise:
        return ImuNoise(self.imu_rate, self.gyro_noise_density, self.gyro_bias_sigma, self.gyro_bias_walk,
                        self.accel_noise_density, self.accel_bias_sigma)


_EXTRA_KEYS = ("ns", "frame", "xyz", "rpy_deg")


def _intervals(section: str, name: str, value) -> list[list[float]]:
    """A checked list of [t0, t1] intervals (seconds, t0 < t1), as floats."""
    where = f"config [{section}] {name} = {value!r}"
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where} must be a list of [t0, t1] intervals in seconds, e.g. [[10, 12.5]]")
    out = []
    for iv in value:
        if (not isinstance(iv, (list, tuple)) or len(iv) != 2
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in iv)):
            raise ConfigError(f"{where}: each interval must be [t0, t1] in seconds, e.g. [[10, 12.5]]")
        t0, t1 = float(iv[0]), float(iv[1])
        if not 0.0 <= t0 < t1:
            raise ConfigError(f"{where}: interval [{t0}, {t1}] must have 0 ≤ t0 < t1")
        out.append([t0, t1])
    return out


def default_frame(ns: str) -> str:
    """The optical frame id kinect2_bridge would give a namespace: /kinect2_left/sd → kinect2_left_ir_optical_frame."""
    parts = [p for p in ns.strip("/").split("/") if p]
    if len(parts) > 1 and parts[-1] in ("sd", "hd", "qhd"):
        parts = parts[:-1]
    return "_".join(parts) + "_ir_optical_frame"


def _extra_camera(section: str, k: int, entry) -> dict:
    """One checked extra_cameras entry as {ns, frame, xyz, rpy_deg} (floats; frame and rpy_deg filled in)."""
    where = f"config [{section}] extra_cameras[{k}] = {entry!r}"
    if not isinstance(entry, dict):
        raise ConfigError(f"{where} must be a table like {{ns = \"/kinect2_left/sd\", xyz = [0, 0.1, 1.0], "
                          f"rpy_deg = [0, 0, 90]}}")
    unknown = sorted(set(entry) - set(_EXTRA_KEYS))
    if unknown:
        raise ConfigError(f"{where} has unknown key {unknown[0]!r}; known: {', '.join(_EXTRA_KEYS)}")
    for key in ("ns", "xyz"):
        if key not in entry:
            raise ConfigError(f"{where} is missing {key!r}; each camera needs ns and xyz (frame, rpy_deg optional)")
    ns = entry["ns"]
    if not isinstance(ns, str) or not ns.startswith("/") or not ns.strip("/") or ns.endswith("/"):
        raise ConfigError(f"{where}: ns must be a topic namespace like \"/kinect2_left/sd\" (starts with '/', "
                          f"no trailing '/')")
    frame = entry.get("frame", default_frame(ns))
    if not isinstance(frame, str) or not frame or "/" in frame or " " in frame:
        raise ConfigError(f"{where}: frame must be a frame id like \"kinect2_left_ir_optical_frame\"")
    out = {"ns": ns, "frame": frame}
    for key, unit in (("xyz", "m"), ("rpy_deg", "deg")):
        v = entry.get(key, [0.0, 0.0, 0.0])
        if (not isinstance(v, (list, tuple)) or len(v) != 3
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in v)):
            raise ConfigError(f"{where}: {key} must be 3 numbers ({unit})")
        out[key] = [float(x) for x in v]
    return out
