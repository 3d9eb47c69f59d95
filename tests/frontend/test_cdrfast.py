"""frontend/logs/cdrfast.py: Imu and Odometry read straight from CDR bytes give exactly the records rosbags +
convert.to_record give (every frame_id length, so every padding before the doubles; NaN and signed values), and
a message they cannot vouch for (truncated, padded, big endian, no string terminator) is left to rosbags."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kosmap.frontend.logs import topics as T
from kosmap.frontend.logs.cdrfast import imu, odometry
from kosmap.frontend.logs.convert import imu_msg, odometry_msg, to_record, typestore
from kosmap.frontend.records import Imu, Odometry


def _same(a, b) -> None:
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if isinstance(vb, np.ndarray):
            assert va.dtype == vb.dtype and va.shape == vb.shape and va.tobytes() == vb.tobytes(), f.name
        else:
            assert type(va) is type(vb) and (va == vb or (va != va and vb != vb)), (f.name, va, vb)


def _cdr(msg, msgtype: str) -> bytes:
    return bytes(typestore(2).serialize_cdr(msg, msgtype, little_endian=True))


def _reference(raw: bytes, msgtype: str, topic: str):
    return to_record(typestore(2).deserialize_cdr(raw, msgtype), msgtype, topic)


def _imu(rng, frame: str) -> Imu:
    q = rng.normal(size=4)
    return Imu(int(rng.integers(0, 2**60)), rng.normal(0, 0.3, 3), rng.normal(0, 1.0, 3), q / np.linalg.norm(q),
               np.array([-1.0] + [0.0] * 8), rng.random(9), np.r_[np.nan, rng.random(8)], frame, "/imu")


@pytest.mark.parametrize("frame", ["", "a", "ab", "abc", "imu", "imu_", "imu_l", "imu_link", "gyro/frame", "kamera_ß"])
def test_imu_equals_rosbags(frame):
    rng = np.random.default_rng(len(frame))
    for _ in range(20):
        raw = _cdr(imu_msg(typestore(2), _imu(rng, frame)), T.IMU)
        _same(imu(raw, "/imu"), _reference(raw, T.IMU, "/imu"))


@pytest.mark.parametrize("frame,child", [("", ""), ("odom", "base_link"), ("o", "bas"), ("map", "base_footprint_x")])
def test_odometry_equals_rosbags(frame, child):
    rng = np.random.default_rng(len(frame) + 7 * len(child))
    for _ in range(20):
        o = Odometry(int(rng.integers(0, 2**60)), *rng.normal(0, 50, 2), float(rng.uniform(-3.2, 3.2)), frame, child,
                     "/odom", float(rng.normal()))
        raw = _cdr(odometry_msg(typestore(2), o, np.diag(rng.random(6)).reshape(36)), T.ODOMETRY)
        rec = odometry(raw, "/odom")
        _same(rec, _reference(raw, T.ODOMETRY, "/odom"))
        assert rec.x == o.x and rec.child_frame_id == child


def test_what_it_cannot_vouch_for_goes_to_rosbags():
    rng = np.random.default_rng(1)
    raw = _cdr(imu_msg(typestore(2), _imu(rng, "imu_link")), T.IMU)
    assert imu(raw[:-8], "/imu") is None  # truncated
    assert imu(raw + b"\0" * 8, "/imu") is None  # longer than the message (rosbags: size mismatch)
    assert imu(b"\x00\x00" + raw[2:], "/imu") is None  # big endian
    assert imu(raw[:4], "/imu") is None
    bad = bytearray(raw)
    bad[12:16] = (200).to_bytes(4, "little")  # a frame_id longer than the message
    assert imu(bytes(bad), "/imu") is None
    bad = bytearray(raw)
    bad[16 + 8] = ord("x")  # "imu_link" loses its terminator (16: the string after its length)
    assert imu(bytes(bad), "/imu") is None
    o = _cdr(odometry_msg(typestore(2), Odometry(5, 1.0, 2.0, 0.5, "odom", "base_link", "/odom")), T.ODOMETRY)
    assert odometry(o[:-1], "/odom") is None and odometry(o, "/odom") is not None


def test_mcap_reader_uses_it(tmp_path):
    """A log through McapLog: the same records either way (the reader's fast path is this module)."""
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.writer import McapWriter

    rng = np.random.default_rng(2)
    recs = [_imu(rng, "imu_link") for _ in range(30)]
    recs = [dataclasses.replace(r, stamp_ns=1_000_000 * (i + 1)) for i, r in enumerate(recs)]
    with McapWriter(tmp_path / "a.mcap") as w:
        for r in recs:
            w.write(r, "/imu")
    with open_log(tmp_path / "a.mcap") as lg:
        got = list(lg.read(["/imu"]))
    assert len(got) == 30
    for a, b in zip(got, recs):
        ref = _reference(_cdr(imu_msg(typestore(2), b), T.IMU), T.IMU, "/imu")
        _same(a, ref)


def test_laser_scan_bytes_are_rosbags_bytes():
    """cdrfast.laser_scan writes the bytes rosbags serialises for convert.scan_msg: every frame_id length (so every
    padding before the floats), empty and long scans, intensities or none, ±inf and NaN ranges, a stamp before
    1970; and McapWriter writes them, read back as the same Scan."""
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.cdrfast import laser_scan
    from kosmap.frontend.logs.convert import scan_msg
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import Scan

    rng = np.random.default_rng(11)
    scans = []
    for k in range(24):
        n = [0, 1, 7, 1081][k % 4]
        r = rng.uniform(0.1, 30.0, n).astype(np.float32)
        if n > 3:
            r[:3] = (np.inf, -np.inf, np.nan)
        inten = rng.uniform(0, 4000, n).astype(np.float32) if k % 3 == 0 else np.zeros(0, np.float32)
        stamp = int(rng.integers(0, 2**31 * 10**9)) if k != 5 else -1_500_000_001
        scans.append(Scan(stamp, r, float(rng.uniform(-3.2, 0)), float(rng.uniform(1e-4, 0.01)), 0.02,
                          float(np.inf) if k % 5 == 0 else 30.0, "laser"[: k % 6] + "x" * (k // 6), "/scan", inten,
                          float(rng.uniform(0, 1e-4)), 0.025))
    ts = typestore(2)
    for s in scans:
        assert laser_scan(s) == _cdr(scan_msg(ts, s), T.LASER_SCAN), s.frame_id
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "s.mcap"
        with McapWriter(path) as w:
            for s in scans[:12]:
                if s.stamp_ns >= 0:
                    w.write(s)
        with open_log(path) as lg:
            back = list(lg.read(["/scan"]))
    want = sorted((s for s in scans[:12] if s.stamp_ns >= 0), key=lambda s: s.stamp_ns)
    assert len(back) == len(want) == 11
    for a, b in zip(back, want):
        assert a.stamp_ns == b.stamp_ns and a.frame_id == b.frame_id and a.ranges.tobytes() == b.ranges.tobytes()
        assert a.intensities.tobytes() == b.intensities.tobytes() and a.angle_min == np.float32(b.angle_min)


@pytest.mark.parametrize("frame", ["", "a", "ab", "abc", "laser", "laser_l", "base_scan", "kamera_ß"])
def test_laser_scan_and_depth_image_equal_rosbags(frame):
    """LaserScan and depth Image decoded from the bytes give the records rosbags + to_record give, for every
    padding after the frame id and (Image) after the encoding; rosbags' own bytes in, so every field and length
    is as a ROS driver writes it."""
    from kosmap.frontend.logs.cdrfast import image, scan
    from kosmap.frontend.logs.convert import image_msg, scan_msg
    from kosmap.frontend.records import DepthFrame, Scan

    rng = np.random.default_rng(len(frame) + 11)
    for n, m in ((0, 0), (1, 0), (541, 541), (1081, 0), (7, 7)):
        ranges = rng.uniform(0.1, 30, n).astype(np.float32)
        ranges[rng.random(n) < 0.1] = np.inf
        s = Scan(int(rng.integers(0, 2**60)), ranges, float(rng.uniform(-3, 0)), float(rng.uniform(1e-3, 0.1)),
                 0.1, 30.0, frame, "/scan", rng.random(m).astype(np.float32), 1e-5, 0.025)
        raw = _cdr(scan_msg(typestore(2), s), T.LASER_SCAN)
        got = scan(raw, "/scan")
        _same(got, _reference(raw, T.LASER_SCAN, "/scan"))
        assert got.ranges.base is None or got.ranges.base is not raw  # not a view into the log's chunk
    for enc, dtype in (("16UC1", np.uint16), ("mono16", np.uint16), ("32FC1", np.float32)):
        for h, w in ((1, 1), (3, 5), (42, 51)):
            img = (rng.random((h, w)) * 5000).astype(dtype)
            f = DepthFrame(int(rng.integers(0, 2**60)), img, "16UC1" if dtype == np.uint16 else "32FC1", frame, "/depth")
            msg = image_msg(typestore(2), f)
            msg.encoding = enc
            raw = _cdr(msg, T.IMAGE)
            got = image(raw, "/depth")
            _same(got, _reference(raw, T.IMAGE, "/depth"))
            assert got.encoding == ("32FC1" if enc == "32FC1" else "16UC1")


def test_scans_and_images_it_cannot_vouch_for_go_to_rosbags():
    from kosmap.frontend.logs.cdrfast import image, scan
    from kosmap.frontend.logs.convert import image_msg, scan_msg
    from kosmap.frontend.records import DepthFrame, Scan

    s = Scan(5, np.ones(10, np.float32), -1.0, 0.1, 0.1, 10.0, "laser", "/scan")
    raw = _cdr(scan_msg(typestore(2), s), T.LASER_SCAN)
    assert scan(raw, "/scan") is not None
    assert scan(raw[:-4], "/scan") is None  # truncated
    assert scan(raw + b"\0" * 8, "/scan") is None  # trailing bytes
    ts = typestore(2)
    msg = image_msg(ts, DepthFrame(5, np.ones((4, 6), np.uint16), "16UC1", "cam", "/depth"))
    assert image(_cdr(msg, T.IMAGE), "/depth") is not None
    for change in ({"encoding": "rgb8"}, {"is_bigendian": 1}, {"step": 14, "data": np.zeros(56, np.uint8)},
                   {"height": 5}):
        bad = ts.types[T.IMAGE](**{**{k: getattr(msg, k) for k in ("header", "height", "width", "encoding",
                                                                    "is_bigendian", "step", "data")}, **change})
        assert image(_cdr(bad, T.IMAGE), "/depth") is None, change
