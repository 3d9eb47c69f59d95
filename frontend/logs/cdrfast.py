"""Direct CDR decoding of the messages a log has most of (sensor_msgs/Imu, nav_msgs/Odometry, sensor_msgs/LaserScan and
depth sensor_msgs/Image) into records, and direct CDR encoding of the scans kosmap writes most, sensor_msgs/LaserScan.

rosbags' generated deserialisers build a message object per message (18–26 µs for these types here, plus
~20 µs to turn the object into a record): on a 10-minute log with a 200 Hz gyro, 50 Hz odometry and 100 Hz
ground truth that is ~9 s of the reading process's CPU in `kosmap build` (docs/bench/pipeline.md); a 40 Hz laser
and a 30 Hz depth camera took ~33 and ~39 µs a message more. These types are fixed layouts around their strings
and arrays, so their fields are read straight from the bytes here, with the same checks rosbags makes
(encapsulation, string length and terminator, array lengths, message size). Anything else, or a message that fails
a check, returns None and goes through rosbags as before (which then raises its own error). ROS 2 CDR only (a ROS
1 bag goes through rosbags).

Writing, the build's Foxglove MCAP holds ~40k LaserScans per 10 minutes (four KOS levels, the laser, the fused
scan): building a rosbags message and serialising it took 14 µs for a 512-beam scan, `laser_scan` writes the
same bytes (tests/frontend/test_cdrfast.py holds it to rosbags') from the record in 3.3 µs; mcap's add_message
(~20 µs) stays.
"""

from __future__ import annotations

import struct

import numpy as np

from kosmap.frontend.logs import topics as T
from kosmap.frontend.records import DepthFrame, Imu, ImuSamples, Odometry, OdometrySamples, Scan, quat_to_yaw

_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: sec int32, nanosec uint32
_U32 = struct.Struct("<I")
_POSE = struct.Struct("<7d")  # position x y z, orientation x y z w
_IMU_DOUBLES = 4 + 9 + 3 + 9 + 3 + 9  # orientation, its covariance, angular velocity, its covariance, linear acc., its cov.
_ODOM_DOUBLES = 7 + 36 + 6 + 36  # pose, its covariance, twist, its covariance


def _string(raw, pos: int) -> tuple[str, int] | None:
    """A CDR string at `pos` (4-aligned: length incl. NUL, bytes, NUL) and the position after it; None if bad."""
    pos = (pos + 3) & ~3
    if pos + 4 > len(raw):
        return None
    (n,) = _U32.unpack_from(raw, pos)
    end = pos + 4 + n
    if n < 1 or end > len(raw) or raw[end - 1] != 0:
        return None
    try:
        return bytes(raw[pos + 4:end - 1]).decode(), end
    except UnicodeDecodeError:  # rosbags says what is wrong (and the reader warns and skips the message)
        return None


def _header(raw) -> tuple[int, str, int] | None:
    """(stamp ns, frame_id, position after it) of a little-endian CDR message's std_msgs/Header; None if bad."""
    if len(raw) < 16 or raw[0] != 0 or raw[1] != 1:  # 0x0001: CDR little endian
        return None
    sec, nsec = _STAMP.unpack_from(raw, 4)
    s = _string(raw, 12)
    if s is None:
        return None
    return sec * 1_000_000_000 + nsec, s[0], s[1]


def _doubles_at(raw, pos: int, n: int) -> int | None:
    """The 8-aligned position (in the payload after the 4-byte encapsulation) of `n` doubles from `pos`, None if
    the message is not exactly that long (rosbags' size check allows up to 3 bytes of padding)."""
    start = 4 + ((pos - 4 + 7) & ~7)
    end = start + 8 * n
    return start if end <= len(raw) < end + 4 else None


def imu(raw, topic: str) -> Imu | None:
    """sensor_msgs/Imu as frontend.logs.convert.imu_record makes it, or None."""
    h = _header(raw)
    if h is None:
        return None
    stamp, frame, pos = h
    start = _doubles_at(raw, pos, _IMU_DOUBLES)
    if start is None:
        return None
    v = np.frombuffer(raw, "<f8", _IMU_DOUBLES, start).astype(np.float64)  # one copy, native order
    return Imu(stamp, v[13:16], v[25:28], v[0:4], v[4:13], v[16:25], v[28:37], frame, topic)


def odometry(raw, topic: str) -> Odometry | None:
    """nav_msgs/Odometry as frontend.logs.convert.to_record makes it, or None."""
    h = _header(raw)
    if h is None:
        return None
    stamp, frame, pos = h
    s = _string(raw, pos)
    if s is None:
        return None
    child, pos = s
    start = _doubles_at(raw, pos, _ODOM_DOUBLES)
    if start is None:
        return None
    x, y, z, qx, qy, qz, qw = _POSE.unpack_from(raw, start)
    return Odometry(stamp, x, y, quat_to_yaw(qx, qy, qz, qw), frame, child, topic, z)


_SCAN_IN = struct.Struct("<7fI")  # angle min, max, increment, time increment, scan time, range min, max; len(ranges)
_IMAGE_SIZE = struct.Struct("<II")  # height, width
_STEP = struct.Struct("<II")  # step, len(data) (after is_bigendian, 4-aligned)
_DEPTH = {"16UC1": ("<u2", "16UC1"), "mono16": ("<u2", "16UC1"), "32FC1": ("<f4", "32FC1")}


def scan(raw, topic: str) -> Scan | None:
    """sensor_msgs/LaserScan as frontend.logs.convert.to_record makes it (its arrays copied out of the log's chunk),
    or None."""
    h = _header(raw)
    if h is None:
        return None
    stamp, frame, pos = h
    pos = (pos + 3) & ~3
    if pos + _SCAN_IN.size > len(raw):
        return None
    a0, _, inc, t_inc, t_scan, r0, r1, n = _SCAN_IN.unpack_from(raw, pos)
    pos += _SCAN_IN.size
    if pos + 4 * n + 4 > len(raw):
        return None
    (m,) = _U32.unpack_from(raw, pos + 4 * n)
    end = pos + 4 * n + 4 + 4 * m
    if not end <= len(raw) < end + 4:
        return None
    ranges = np.frombuffer(raw, "<f4", n, pos).astype(np.float32)  # (a copy: the chunk is not kept alive)
    return Scan(stamp, ranges, a0, inc, r0, r1, frame, topic, np.frombuffer(raw, "<f4", m, pos + 4 * n + 4).astype(np.float32),
                t_inc, t_scan)


def image(raw, topic: str) -> DepthFrame | None:
    """A depth sensor_msgs/Image (16UC1, mono16 or 32FC1, little endian, rows without padding) as
    frontend.logs.convert.to_record makes it, its pixels a view of `raw`; anything else (other encodings, padded
    rows, damage: what image_array explains in its errors) None."""
    h = _header(raw)
    if h is None:
        return None
    stamp, frame, pos = h
    pos = (pos + 3) & ~3
    if pos + 8 > len(raw):
        return None
    rows, cols = _IMAGE_SIZE.unpack_from(raw, pos)
    s = _string(raw, pos + 8)
    if s is None or s[0] not in _DEPTH:
        return None
    dtype, enc = _DEPTH[s[0]]
    pos = s[1]
    big = raw[pos] if pos < len(raw) else 1
    pos = (pos + 4) & ~3
    if big or pos + 8 > len(raw):
        return None
    step, n = _STEP.unpack_from(raw, pos)
    pos += 8
    end = pos + n
    if rows <= 0 or cols <= 0 or step != cols * (2 if dtype == "<u2" else 4) or n != step * rows \
            or not end <= len(raw) < end + 4:
        return None
    return DepthFrame(stamp, np.frombuffer(raw, dtype, rows * cols, pos).reshape(rows, cols), enc, frame, topic)


DECODERS = {T.IMU: imu, T.ODOMETRY: odometry, T.LASER_SCAN: scan, T.IMAGE: image}


# ---- many messages of one topic at once (LogReader.read_batched) ----------------------------------------------------
# A 200 Hz gyro and 50–100 Hz odometry are most of a log's messages: 210k of the 270k the build reads from 10 minutes
# of the simulated office, where one record each cost ~60 µs from chunk to SLAM. Messages of one topic usually share one layout (the same
# frame ids, so the same length and the same offsets), and then a chunk's worth is one (n × length) byte array
# whose columns are the fields. Anything else returns None: the caller decodes the messages one by one.

def _rows(bodies: list, head_end: int) -> np.ndarray | None:
    """The messages as an n × L byte array when all are L bytes long and agree with the first outside the stamp
    up to `head_end` (encapsulation and frame ids: one layout); else None."""
    n = len(bodies[0])
    if any(len(b) != n for b in bodies):
        return None
    a = np.frombuffer(b"".join(bodies), np.uint8).reshape(len(bodies), n)
    if not ((a[:, :4] == a[0, :4]).all() and (a[:, 12:head_end] == a[0, 12:head_end]).all()):
        return None
    return a


def _stamps(a: np.ndarray) -> np.ndarray:
    """int64 ns of each row's header stamp (sec int32, nanosec uint32 after the encapsulation)."""
    sec = np.ascontiguousarray(a[:, 4:8]).view("<i4")[:, 0].astype(np.int64)
    return sec * 1_000_000_000 + np.ascontiguousarray(a[:, 8:12]).view("<u4")[:, 0].astype(np.int64)


def _doubles(a: np.ndarray, start: int, n: int) -> np.ndarray:
    return np.ascontiguousarray(a[:, start:start + 8 * n]).view("<f8").astype(np.float64)


def imu_batch(bodies: list, topic: str) -> ImuSamples | None:
    """sensor_msgs/Imu messages of one layout as the columns of the records `imu` makes, or None."""
    h = _header(bodies[0])
    if h is None:
        return None
    _, frame, pos = h
    start = _doubles_at(bodies[0], pos, _IMU_DOUBLES)
    a = None if start is None else _rows(bodies, pos)
    if a is None:
        return None
    v = _doubles(a, start, _IMU_DOUBLES)
    return ImuSamples(_stamps(a), v[:, 13:16], v[:, 25:28], v[:, 0:4], v[:, 4:13], v[:, 16:25], v[:, 28:37], frame, topic)


def odometry_batch(bodies: list, topic: str) -> OdometrySamples | None:
    """nav_msgs/Odometry messages of one layout as the columns of the records `odometry` makes, or None."""
    h = _header(bodies[0])
    if h is None:
        return None
    _, frame, pos = h
    s = _string(bodies[0], pos)
    if s is None:
        return None
    child, pos = s
    start = _doubles_at(bodies[0], pos, _ODOM_DOUBLES)
    a = None if start is None else _rows(bodies, pos)
    if a is None:
        return None
    x, y, z, qx, qy, qz, qw = _doubles(a, start, 7).T
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))  # quat_to_yaw, element-wise
    return OdometrySamples(_stamps(a), x.copy(), y.copy(), yaw, z.copy(), frame, child, topic)


BATCH_DECODERS = {T.IMU: imu_batch, T.ODOMETRY: odometry_batch}


_SCAN_FLOATS = struct.Struct("<7f")  # angle min, max, increment, time increment, scan time, range min, max


def laser_scan(scan: Scan) -> bytes:
    """The sensor_msgs/LaserScan of a Scan in little-endian ROS 2 CDR: the bytes rosbags' serialize_cdr gives for
    frontend.logs.convert.scan_msg (zero padding, lengths as uint32)."""
    sec, nsec = divmod(int(scan.stamp_ns), 1_000_000_000)
    fid = scan.frame_id.encode()
    n = len(fid) + 1
    pad = -(8 + 4 + n) % 4  # the floats are 4-aligned in the payload after the 4-byte encapsulation
    r = np.ascontiguousarray(scan.ranges, dtype="<f4")
    i = np.ascontiguousarray(scan.intensities, dtype="<f4")
    return b"".join((b"\x00\x01\x00\x00", _STAMP.pack(sec, nsec), _U32.pack(n), fid, b"\x00" * (1 + pad),
                     _SCAN_FLOATS.pack(float(scan.angle_min), float(scan.angle_max), float(scan.angle_increment),
                                       float(scan.time_increment), float(scan.scan_time), float(scan.range_min),
                                       float(scan.range_max)),
                     _U32.pack(len(r)), r.tobytes(), _U32.pack(len(i)), i.tobytes()))
