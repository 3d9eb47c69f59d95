"""ROS messages ↔ kosmap records: the one place that knows the fields of ROS message types.

Works with rosbags' message classes for ROS 1 (Noetic) and ROS 2 (Humble); the few differences
(Header.seq, CameraInfo K/k) are handled here.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import topics as T
from kosmap.frontend.records import (CameraModel, DepthFrame, Imu, Odometry, Scan, Transform, Transforms, quat_to_yaw,
                              yaw_to_quat)

_TF_MSGDEF = "geometry_msgs/TransformStamped[] transforms"


@lru_cache(maxsize=None)
def typestore(ros_version: int):
    """The rosbags typestore for ROS 1 (Noetic, plus tf2_msgs which it lacks) or ROS 2 (Humble)."""
    if ros_version == 1:
        ts = get_typestore(Stores.ROS1_NOETIC)
        ts.register(get_types_from_msg(_TF_MSGDEF, T.TF))
        return ts
    return get_typestore(Stores.ROS2_HUMBLE)


def stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _where(topic: str, stamp: int) -> str:
    return f"{topic} at t={stamp * 1e-9:.3f} s"


def image_array(msg, topic: str) -> tuple[np.ndarray, str]:
    """The pixels of a depth sensor_msgs/Image as uint16 (16UC1, mono16) or float32 (32FC1)."""
    enc = msg.encoding
    t = stamp_ns(msg.header.stamp)
    if enc in ("16UC1", "mono16"):
        dtype, enc = np.dtype(np.uint16), "16UC1"
    elif enc == "32FC1":
        dtype = np.dtype(np.float32)
    else:
        raise LogError(f"depth image on {_where(topic, t)} has encoding '{enc}'; kosmap reads 16UC1 or mono16 (mm) "
                       f"and 32FC1 (m): convert the depth stream, or pick another topic with --depth-topic")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0:
        raise LogError(f"depth image on {_where(topic, t)} is empty ({w}×{h}); the log is damaged or the driver wrote no pixels")
    if step < w * dtype.itemsize or data.size != step * h:
        raise LogError(f"depth image on {_where(topic, t)} has {data.size} bytes but {w}×{h} {enc} needs "
                       f"{h}×step={h * step} with step ≥ {w * dtype.itemsize}; the log is damaged")
    rows = data.reshape(h, step)[:, : w * dtype.itemsize]
    img = np.ascontiguousarray(rows).view(dtype.newbyteorder(">" if msg.is_bigendian else "<")).reshape(h, w)
    return img.astype(dtype, copy=False), enc


def to_record(msg, msgtype: str, topic: str):
    """The record for a deserialized message, or None for types kosmap does not use."""
    if msgtype == T.IMAGE:
        img, enc = image_array(msg, topic)
        return DepthFrame(stamp_ns(msg.header.stamp), img, enc, msg.header.frame_id, topic)
    if msgtype == T.LASER_SCAN:
        return Scan(stamp_ns(msg.header.stamp), np.asarray(msg.ranges, dtype=np.float32), float(msg.angle_min),
                    float(msg.angle_increment), float(msg.range_min), float(msg.range_max), msg.header.frame_id, topic,
                    np.asarray(msg.intensities, dtype=np.float32), float(msg.time_increment), float(msg.scan_time))
    if msgtype == T.ODOMETRY:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        return Odometry(stamp_ns(msg.header.stamp), float(p.x), float(p.y), quat_to_yaw(q.x, q.y, q.z, q.w),
                        msg.header.frame_id, msg.child_frame_id, topic, float(p.z))
    if msgtype == T.CAMERA_INFO:
        K = np.asarray(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K, dtype=float).reshape(3, 3)
        D = np.asarray(getattr(msg, "d", None) if hasattr(msg, "d") else msg.D, dtype=float)
        t = stamp_ns(msg.header.stamp)  # (unusable intrinsics are skipped with a warning: logs/validate.py)
        return CameraModel(int(msg.width), int(msg.height), K, D, msg.distortion_model, msg.header.frame_id, topic, t)
    if msgtype == T.TF:
        tfs = tuple(Transform(m.header.frame_id.lstrip("/"), m.child_frame_id.lstrip("/"),
                              np.array([m.transform.translation.x, m.transform.translation.y, m.transform.translation.z]),
                              np.array([m.transform.rotation.x, m.transform.rotation.y, m.transform.rotation.z,
                                        m.transform.rotation.w]), stamp_ns(m.header.stamp)) for m in msg.transforms)
        t = max((tf.stamp_ns for tf in tfs), default=0)
        return Transforms(t, tfs, topic == "/tf_static" or "static" in topic, topic)
    if msgtype == T.IMU:
        return imu_record(msg, topic)
    return None


def imu_record(msg, topic: str) -> Imu:
    """sensor_msgs/Imu → Imu, values as they came (the readers drop unusable samples: `imu_problem`)."""
    w, a, q = msg.angular_velocity, msg.linear_acceleration, msg.orientation
    return Imu(stamp_ns(msg.header.stamp), np.array([w.x, w.y, w.z], dtype=np.float64),
               np.array([a.x, a.y, a.z], dtype=np.float64), np.array([q.x, q.y, q.z, q.w], dtype=np.float64),
               np.asarray(msg.orientation_covariance, dtype=np.float64),
               np.asarray(msg.angular_velocity_covariance, dtype=np.float64),
               np.asarray(msg.linear_acceleration_covariance, dtype=np.float64), msg.header.frame_id, topic)


def imu_problem(rec: Imu) -> str | None:
    """Why an IMU sample is unusable (a provided rate or acceleration that is not finite), else None."""
    # math.isfinite on the three numbers: np.isfinite(...).all() on a 3-vector cost ~3 µs, 200 times a second
    if rec.has_angular_velocity and not all(map(math.isfinite, rec.angular_velocity.tolist())):
        return "a non-finite angular velocity"
    if rec.has_linear_acceleration and not all(map(math.isfinite, rec.linear_acceleration.tolist())):
        return "a non-finite linear acceleration"
    return None


def imu_samples_problems(rec) -> np.ndarray | None:
    """`imu_problem` of each sample of an ImuSamples ("" where usable), or None when every sample is usable."""
    gyro = rec.has_angular_velocity & ~np.isfinite(rec.angular_velocity).all(axis=1)
    acc = rec.has_linear_acceleration & ~np.isfinite(rec.linear_acceleration).all(axis=1)
    if not (gyro.any() or acc.any()):
        return None
    return np.where(gyro, "a non-finite angular velocity", np.where(acc, "a non-finite linear acceleration", ""))


# ---- records → messages (for the writers) --------------------------------------------------------------------------

def _time(ts, t_ns: int):
    return ts.types["builtin_interfaces/msg/Time"](sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def header(ts, t_ns: int, frame_id: str, seq: int = 0):
    H = ts.types["std_msgs/msg/Header"]
    if "seq" in dict(ts.fielddefs["std_msgs/msg/Header"][1]):
        return H(seq=seq, stamp=_time(ts, t_ns), frame_id=frame_id)
    return H(stamp=_time(ts, t_ns), frame_id=frame_id)


def _vec3(ts, v):
    return ts.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quat(ts, q):
    return ts.types["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def _pose(ts, xyz, q):
    P = ts.types["geometry_msgs/msg/Pose"]
    pt = ts.types["geometry_msgs/msg/Point"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))
    return P(position=pt, orientation=_quat(ts, q))


def scan_msg(ts, s: Scan):
    return ts.types[T.LASER_SCAN](
        header=header(ts, s.stamp_ns, s.frame_id), angle_min=float(s.angle_min), angle_max=float(s.angle_max),
        angle_increment=float(s.angle_increment), time_increment=float(s.time_increment), scan_time=float(s.scan_time),
        range_min=float(s.range_min), range_max=float(s.range_max), ranges=np.asarray(s.ranges, dtype=np.float32),
        intensities=np.asarray(s.intensities, dtype=np.float32))


def image_msg(ts, f: DepthFrame):
    img = np.ascontiguousarray(f.image)
    h, w = img.shape
    return ts.types[T.IMAGE](header=header(ts, f.stamp_ns, f.frame_id), height=h, width=w, encoding=f.encoding,
                             is_bigendian=0, step=w * img.dtype.itemsize, data=img.view(np.uint8).reshape(-1))


def camera_info_msg(ts, c: CameraModel):
    fields = dict(ts.fielddefs[T.CAMERA_INFO][1])
    k, d, r, p = ("k", "d", "r", "p") if "k" in fields else ("K", "D", "R", "P")
    P = np.zeros((3, 4))
    P[:3, :3] = c.K
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    kw = {k: np.asarray(c.K, float).reshape(9), d: np.asarray(c.D, float), r: np.eye(3).reshape(9), p: P.reshape(12)}
    return ts.types[T.CAMERA_INFO](header=header(ts, c.stamp_ns, c.frame_id), height=c.height, width=c.width,
                                   distortion_model=c.distortion_model, binning_x=0, binning_y=0, roi=roi, **kw)


def odometry_msg(ts, o: Odometry, covariance: np.ndarray | None = None):
    cov = np.zeros(36) if covariance is None else np.asarray(covariance, float).reshape(36)
    PwC = ts.types["geometry_msgs/msg/PoseWithCovariance"]
    TwC = ts.types["geometry_msgs/msg/TwistWithCovariance"]
    twist = ts.types["geometry_msgs/msg/Twist"](linear=_vec3(ts, (0, 0, 0)), angular=_vec3(ts, (0, 0, 0)))
    return ts.types[T.ODOMETRY](header=header(ts, o.stamp_ns, o.frame_id), child_frame_id=o.child_frame_id,
                                pose=PwC(pose=_pose(ts, (o.x, o.y, o.z), yaw_to_quat(o.yaw)), covariance=cov),
                                twist=TwC(twist=twist, covariance=np.zeros(36)))


def imu_msg(ts, m: Imu):
    """sensor_msgs/Imu from an Imu record (covariances as given, −1 markers included)."""
    return ts.types[T.IMU](header=header(ts, m.stamp_ns, m.frame_id), orientation=_quat(ts, m.orientation),
                           orientation_covariance=np.asarray(m.orientation_cov, dtype=np.float64).reshape(9),
                           angular_velocity=_vec3(ts, m.angular_velocity),
                           angular_velocity_covariance=np.asarray(m.angular_velocity_cov, dtype=np.float64).reshape(9),
                           linear_acceleration=_vec3(ts, m.linear_acceleration),
                           linear_acceleration_covariance=np.asarray(m.linear_acceleration_cov, dtype=np.float64).reshape(9))


def tf_msg(ts, tfs: Transforms):
    TS = ts.types["geometry_msgs/msg/TransformStamped"]
    Tr = ts.types["geometry_msgs/msg/Transform"]
    items = [TS(header=header(ts, tf.stamp_ns, tf.parent), child_frame_id=tf.child,
                transform=Tr(translation=_vec3(ts, tf.translation), rotation=_quat(ts, tf.rotation)))
             for tf in tfs.transforms]
    return ts.types[T.TF](transforms=items)


def pose_stamped_msg(ts, t_ns: int, frame_id: str, x: float, y: float, yaw: float):
    return ts.types["geometry_msgs/msg/PoseStamped"](header=header(ts, t_ns, frame_id),
                                                     pose=_pose(ts, (x, y, 0.0), yaw_to_quat(yaw)))


def pose_array_msg(ts, t_ns: int, frame_id: str, positions: np.ndarray, quats: np.ndarray):
    """geometry_msgs/PoseArray from N×3 positions and N×4 quaternions (x, y, z, w), e.g. plane normals as arrows."""
    items = [_pose(ts, p, q) for p, q in zip(np.asarray(positions, float), np.asarray(quats, float))]
    return ts.types["geometry_msgs/msg/PoseArray"](header=header(ts, t_ns, frame_id), poses=items)


def path_msg(ts, t_ns: int, frame_id: str, poses: np.ndarray, stamps_ns: np.ndarray):
    """nav_msgs/Path from N×3 (x, y, yaw) poses."""
    items = [pose_stamped_msg(ts, int(s), frame_id, *p) for s, p in zip(stamps_ns, np.asarray(poses, float))]
    return ts.types["nav_msgs/msg/Path"](header=header(ts, t_ns, frame_id), poses=items)


def pointcloud_msg(ts, t_ns: int, frame_id: str, points: np.ndarray, extra: dict[str, np.ndarray] | None = None):
    """sensor_msgs/PointCloud2 with float32 x, y, z and optional float32 per-point fields (e.g. plane index)."""
    PF = ts.types["sensor_msgs/msg/PointField"]
    cols = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2], **(extra or {})}
    n = len(points)
    arr = np.empty((n, len(cols)), dtype=np.float32)
    for i, v in enumerate(cols.values()):
        arr[:, i] = v
    fields = [PF(name=name, offset=4 * i, datatype=7, count=1) for i, name in enumerate(cols)]  # 7 = FLOAT32
    step = 4 * len(cols)
    return ts.types["sensor_msgs/msg/PointCloud2"](header=header(ts, t_ns, frame_id), height=1, width=n, fields=fields,
                                                   is_bigendian=False, point_step=step, row_step=step * n,
                                                   data=arr.view(np.uint8).reshape(-1), is_dense=True)


def occupancy_grid_msg(ts, t_ns: int, frame_id: str, data: np.ndarray, resolution: float, origin_xy_yaw):
    """nav_msgs/OccupancyGrid from an H×W int8 array (row 0 = the map's bottom, −1 unknown, 0..100)."""
    h, w = data.shape
    meta = ts.types["nav_msgs/msg/MapMetaData"](
        map_load_time=_time(ts, t_ns), resolution=float(resolution), width=w, height=h,
        origin=_pose(ts, (origin_xy_yaw[0], origin_xy_yaw[1], 0.0), yaw_to_quat(origin_xy_yaw[2])))
    return ts.types["nav_msgs/msg/OccupancyGrid"](header=header(ts, t_ns, frame_id), info=meta,
                                                  data=np.ascontiguousarray(data, dtype=np.int8).reshape(-1))


def record_msg(ts, rec) -> tuple[str, object]:
    """(msgtype, message) for a record."""
    if isinstance(rec, Scan):
        return T.LASER_SCAN, scan_msg(ts, rec)
    if isinstance(rec, DepthFrame):
        return T.IMAGE, image_msg(ts, rec)
    if isinstance(rec, CameraModel):
        return T.CAMERA_INFO, camera_info_msg(ts, rec)
    if isinstance(rec, Odometry):
        return T.ODOMETRY, odometry_msg(ts, rec)
    if isinstance(rec, Transforms):
        return T.TF, tf_msg(ts, rec)
    if isinstance(rec, Imu):
        return T.IMU, imu_msg(ts, rec)
    raise TypeError(f"no ROS message for {type(rec).__name__}")
