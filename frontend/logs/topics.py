"""Which topics hold depth, camera info, scans, odometry, IMU and tf: found by message type, or given."""

from __future__ import annotations

from dataclasses import dataclass, field

from kosmap.frontend.errors import TopicError
from kosmap.frontend.params import StageConfig, param

IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"
IMU = "sensor_msgs/msg/Imu"

# IMU topic names preferred when several exist: the usual driver outputs (imu_filter_madgwick reads
# /imu/data_raw and publishes /imu/data; both carry the raw gyro rates).
_IMU_NAMES = ("/imu", "/imu/data", "/imu/data_raw", "/imu_data", "/mobile_base/sensors/imu_data")
_OFF = ("none", "off", "-")  # [topics] imu = "none": ignore the log's IMU (e.g. to compare with and without it)

# Names that mark a topic as ground truth or as our own output rather than the robot's sensors.
_NOT_SENSOR = ("ground_truth", "groundtruth", "/gt", "truth", "kinect_scan", "kosmap")


@dataclass
class TopicsConfig(StageConfig):
    """[topics]: empty means "find by message type" (defaults are what kinect2_bridge and hokuyo_node publish)."""

    section = "topics"
    depth: list = param([], doc="depth image topics, one per camera (sensor_msgs/Image)")
    info: list = param([], doc="camera info topics, in the order of `depth`")
    scan: str = param("", doc="laser scan topic (sensor_msgs/LaserScan)")
    odom: str = param("", doc="wheel odometry topic (nav_msgs/Odometry)")
    imu: str = param("", doc="IMU topic (sensor_msgs/Imu); \"none\" ignores the log's IMU")
    ground_truth: str = param("", doc="ground-truth pose topic (nav_msgs/Odometry), for scoring only")
    on_damage: str = param("skip", choices=("skip", "read", "fail"),
                           doc="a damaged chunk of the log (CRC mismatch, does not decompress): skip it with a warning, "
                               "read it as it is, or fail")


@dataclass
class DetectedTopics:
    """The topics a run will read, after detection and overrides."""

    depth: list[str] = field(default_factory=list)
    info: dict[str, str | None] = field(default_factory=dict)  # depth topic -> camera info topic
    scan: str | None = None
    odom: str | None = None
    imu: str | None = None
    ground_truth: str | None = None
    tf: str | None = None
    tf_static: str | None = None

    def wanted(self) -> list[str]:
        """Every topic to read, in one pass."""
        names = list(self.depth) + [v for v in self.info.values() if v]
        names += [t for t in (self.scan, self.odom, self.imu, self.ground_truth, self.tf, self.tf_static) if t]
        return list(dict.fromkeys(names))

    def as_dict(self) -> dict:
        return {"depth": self.depth, "camera_info": self.info, "scan": self.scan, "odom": self.odom,
                "imu": self.imu, "ground_truth": self.ground_truth, "tf": self.tf, "tf_static": self.tf_static}


def _namespace(topic: str) -> str:
    return topic.rsplit("/", 1)[0]


def _pick(candidates: list[str], preferred: tuple[str, ...]) -> str | None:
    sensors = [t for t in candidates if not any(k in t.lower() for k in _NOT_SENSOR)]
    for name in preferred:
        if name in sensors:
            return name
    return sensors[0] if sensors else None


def _require(topic: str, kind: str, types: dict[str, str], want: str) -> str:
    if topic not in types:
        have = [t for t, ty in types.items() if ty == want]
        hint = f"topics of type {want} here: {', '.join(have)}" if have else f"this log has no {want} topic"
        raise TopicError(f"{kind} topic {topic} is not in the log ({hint}); check --{kind}-topic")
    if types[topic] != want:
        raise TopicError(f"{kind} topic {topic} has type {types[topic]}, expected {want}; check --{kind}-topic")
    return topic


def detect_topics(types: dict[str, str], cfg: TopicsConfig | None = None) -> DetectedTopics:
    """Choose topics from {topic: type}: given names are checked, missing ones found by type."""
    cfg = cfg or TopicsConfig()
    by_type: dict[str, list[str]] = {}
    for t, ty in sorted(types.items()):
        by_type.setdefault(ty, []).append(t)
    out = DetectedTopics()

    if cfg.depth:
        out.depth = [_require(t, "depth", types, IMAGE) for t in cfg.depth]
    else:
        images = [t for t in by_type.get(IMAGE, []) if "depth" in t.lower() and not any(k in t.lower() for k in _NOT_SENSOR)]
        out.depth = sorted(images, key=lambda t: (t != "/kinect2/sd/image_depth_rect", t))
    infos = by_type.get(CAMERA_INFO, [])
    if cfg.info:
        if len(cfg.info) != len(out.depth):
            raise TopicError(f"{len(cfg.info)} info topics given for {len(out.depth)} depth topics; give one per depth topic")
        out.info = {d: _require(i, "info", types, CAMERA_INFO) for d, i in zip(out.depth, cfg.info)}
    else:
        for d in out.depth:
            same_ns = [i for i in infos if _namespace(i) == _namespace(d)]
            # a lone camera info serves a lone depth topic; with several cameras only a namespace match counts
            out.info[d] = same_ns[0] if same_ns else (infos[0] if len(infos) == 1 and len(out.depth) == 1 else None)

    out.scan = _require(cfg.scan, "scan", types, LASER_SCAN) if cfg.scan else _pick(by_type.get(LASER_SCAN, []), ("/scan",))
    out.odom = _require(cfg.odom, "odom", types, ODOMETRY) if cfg.odom else _pick(by_type.get(ODOMETRY, []), ("/odom",))
    if cfg.imu.lower() in _OFF:
        out.imu = None
    elif cfg.imu:
        out.imu = _require(cfg.imu, "imu", types, IMU)
    else:
        out.imu = _pick(by_type.get(IMU, []), _IMU_NAMES)
    if cfg.ground_truth:
        out.ground_truth = _require(cfg.ground_truth, "ground-truth", types, ODOMETRY)
    else:
        gts = [t for t in by_type.get(ODOMETRY, []) if "truth" in t.lower()]
        out.ground_truth = gts[0] if gts else None
    tfs = by_type.get(TF, [])
    out.tf_static = "/tf_static" if "/tf_static" in tfs else None
    out.tf = "/tf" if "/tf" in tfs else None
    return out
