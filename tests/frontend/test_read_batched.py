"""LogReader.read_batched: an MCAP's Imu and Odometry messages come as ImuSamples / OdometrySamples whose samples are
exactly the records `read` gives (bit for bit, in order, with the same warnings for unusable IMU samples), the
other records unchanged; messages of another layout in a chunk fall back to records; other formats give `read`'s.
The batch decoders equal the per-message ones on every frame-id padding."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from mcap.writer import Writer

from kosmap.frontend.logs import open_log
from kosmap.frontend.logs import topics as T
from kosmap.frontend.logs.cdrfast import imu, imu_batch, odometry, odometry_batch
from kosmap.frontend.logs.convert import imu_msg, odometry_msg, scan_msg, typestore
from kosmap.frontend.logs.writer import McapWriter, open_writer
from kosmap.frontend.records import Imu, ImuSamples, Odometry, OdometrySamples, Scan
from tests.frontend.test_cdrfast import _same

T0 = 1_700_000_000_000_000_000


def _imu(rng, i: int, frame: str = "imu_link", topic: str = "/imu") -> Imu:
    q = rng.normal(size=4)
    return Imu(T0 + i * 5_000_000 + int(rng.integers(0, 1000)), rng.normal(0, 0.3, 3), rng.normal(0, 1, 3) + [0, 0, 9.8],
               q / np.linalg.norm(q), np.array([-1.0] + [0.0] * 8) if i % 3 else rng.random(9), rng.random(9),
               rng.random(9), frame, topic)


def _odom(rng, i: int, topic: str = "/odom", child: str = "base_link") -> Odometry:
    return Odometry(T0 + i * 20_000_000 + int(rng.integers(0, 1000)), *rng.normal(0, 0.1, 2), float(rng.uniform(-3.2, 3.2)),
                    "odom", child, topic, float(rng.normal()))


def _expand(recs) -> list:
    out = []
    for r in recs:
        out.extend(r.records() if isinstance(r, (ImuSamples, OdometrySamples)) else [r])
    return out


@pytest.mark.parametrize("frame", ["", "a", "ab", "abc", "imu", "imu_link", "gyro/frame", "kamera_ß"])
def test_batch_decoders_equal_the_per_message_ones(frame):
    rng = np.random.default_rng(len(frame))
    ts = typestore(2)
    raws = [bytes(ts.serialize_cdr(imu_msg(ts, _imu(rng, i, frame)), T.IMU)) for i in range(17)]
    got = imu_batch(raws, "/imu").records()
    assert len(got) == 17
    for g, raw in zip(got, raws):
        _same(g, imu(raw, "/imu"))
    raws = [bytes(ts.serialize_cdr(odometry_msg(ts, _odom(rng, i, child=frame), np.diag(rng.random(6)).reshape(36)),
                                   T.ODOMETRY)) for i in range(17)]
    got = odometry_batch(raws, "/odom").records()
    for g, raw in zip(got, raws):
        _same(g, odometry(raw, "/odom"))


def test_batch_decoders_refuse_mixed_layouts():
    rng = np.random.default_rng(1)
    ts = typestore(2)
    a = [bytes(ts.serialize_cdr(imu_msg(ts, _imu(rng, i, "imu_a")), T.IMU)) for i in range(3)]
    b = bytes(ts.serialize_cdr(imu_msg(ts, _imu(rng, 3, "imu_b")), T.IMU))  # same length, another frame id
    assert len(b) == len(a[0])
    assert imu_batch(a + [b], "/imu") is None
    assert imu_batch(a + [a[0][:-8]], "/imu") is None  # a short one
    assert imu_batch([a[0][:-8]], "/imu") is None  # not an Imu's length
    assert imu_batch(a, "/imu") is not None


def _write_log(path, rng, n: int = 400, bad_gyro: set[int] = frozenset(), switch_frame_at: int | None = None,
               chunk_size: int = 4 << 20):
    recs = []
    for i in range(n):
        frame = "imu_b" if switch_frame_at is not None and i >= switch_frame_at else "imu_link"
        r = _imu(rng, i, frame)
        if i in bad_gyro:
            r = dataclasses.replace(r, angular_velocity=np.array([np.nan, 0.0, 0.0]))
        recs.append(r)
        if i % 4 == 0:
            recs.append(_odom(rng, i // 4))
            recs.append(_odom(rng, i // 4, "/ground_truth/odom", "base_link_gt"))
        if i % 8 == 0:
            recs.append(Scan(T0 + i * 5_000_000, rng.random(30).astype(np.float32), -1.0, 0.07, 0.1, 10.0, "laser",
                             "/scan"))
    recs.sort(key=lambda r: r.stamp_ns)  # recorded in time: the chunks follow one another
    with McapWriter(path, chunk_size=chunk_size) as w:
        for r in recs:
            w.write(r)
    return recs


@pytest.mark.parametrize("chunk_size", [4 << 20, 4096])
def test_read_batched_is_read_in_columns(tmp_path, chunk_size):
    path = tmp_path / "log.mcap"
    _write_log(path, np.random.default_rng(2), chunk_size=chunk_size)
    with open_log(path) as log:
        plain = list(log.read())
        batched = list(log.read_batched())
    kinds = {type(r) for r in batched}
    assert ImuSamples in kinds and OdometrySamples in kinds and Scan in kinds
    assert not kinds & {Imu, Odometry}
    if chunk_size == 4096:  # many chunks: a batch per chunk and topic
        assert sum(isinstance(r, ImuSamples) for r in batched) > 5
    assert len(plain) == 400 + 200 + 50
    got = _expand(batched)
    for topic in ("/imu", "/odom", "/ground_truth/odom", "/scan"):  # each topic's records, in order, bit for bit
        a, b = [r for r in plain if r.topic == topic], [r for r in got if r.topic == topic]
        assert len(a) == len(b) > 0
        for x, y in zip(a, b):
            _same(y, x)
    # a batch stands where its first sample stands
    firsts = [r.stamp_ns for r in batched]
    assert firsts == sorted(firsts)
    assert all(r.end_ns == int(r.stamps_ns.max()) for r in batched if isinstance(r, (ImuSamples, OdometrySamples)))


def test_unusable_gyro_samples_and_a_changed_layout(tmp_path):
    path = tmp_path / "log.mcap"
    bad = {7, 8, 150}
    _write_log(path, np.random.default_rng(3), bad_gyro=bad, switch_frame_at=203, chunk_size=4096)
    with open_log(path) as log:
        plain = list(log.read())
        w_plain = list(log.warnings)
    with open_log(path) as log:
        batched = list(log.read_batched())
        w_batched = list(log.warnings)
        n_bad = dict(log._bad_imu)
    assert w_batched == w_plain and len(w_plain) == 1 and "non-finite angular velocity" in w_plain[0]
    assert n_bad == {"/imu": 3}
    imus = [r for r in _expand(batched) if isinstance(r, Imu)]
    assert len(imus) == 400 - 3
    for x, y in zip([r for r in plain if isinstance(r, Imu)], imus):
        _same(y, x)
    assert {r.frame_id for r in imus} == {"imu_link", "imu_b"}
    # the chunk with both frame ids came as records, the others as columns
    assert any(isinstance(r, Imu) for r in batched) and any(isinstance(r, ImuSamples) for r in batched)


def test_other_formats_read_as_read(tmp_path):
    path = tmp_path / "log.bag"
    rng = np.random.default_rng(4)
    with open_writer(path) as w:
        for i in range(20):
            w.write(_imu(rng, i))
            w.write(_odom(rng, i))
    with open_log(path) as log:
        a, b = list(log.read()), list(log.read_batched())
    assert len(a) == len(b) == 40
    for x, y in zip(a, b):
        _same(y, x)


def _write_out_of_order(path, rng, late_s: float, chunk_size: int) -> None:
    """IMU and odometry samples written in arrival order, every fifth one's log time late by up to `late_s`."""
    recs = []
    for i in range(300):
        recs.append(_imu(rng, i))
        if i % 3 == 0:
            recs.append(_odom(rng, i // 3))
    ts = typestore(2)
    from kosmap.frontend.logs import convert

    with McapWriter(path, chunk_size=chunk_size) as w:
        for k, r in enumerate(recs):
            mt, msg = convert.record_msg(ts, r)
            w.write_msg(r.topic, mt, msg, T0 + k * 3_000_000 + (int(rng.uniform(0, late_s) * 1e9) if k % 5 == 3 else 0))


@pytest.mark.parametrize("late_s,chunk_size,batches", [(0.3, 4 << 20, True), (0.3, 4096, False), (0.0, 4096, True)])
def test_samples_come_in_log_time_order_like_read(tmp_path, late_s, chunk_size, batches):
    """Messages written out of log-time order: inside one chunk a batch is sorted by log time; chunks that overlap in
    time (late messages written where they arrived) are read message by message. Either way each topic's samples come
    in the order `read` gives them."""
    path = tmp_path / "late.mcap"
    _write_out_of_order(path, np.random.default_rng(7), late_s, chunk_size)
    with open_log(path) as log:
        plain = list(log.read())
        batched = list(log.read_batched())
    assert any(isinstance(r, (ImuSamples, OdometrySamples)) for r in batched) == batches
    got = _expand(batched)
    for topic in ("/imu", "/odom"):
        a, b = [r for r in plain if r.topic == topic], [r for r in got if r.topic == topic]
        assert len(a) == len(b) > 50
        for x, y in zip(a, b):
            _same(y, x)


def test_chunks_in_sequence():
    from types import SimpleNamespace as C

    from kosmap.frontend.logs.mcap import _chunks_in_sequence

    def ci(a, b, off):
        return C(message_start_time=a, message_end_time=b, chunk_start_offset=off)

    assert _chunks_in_sequence([ci(0, 10, 0), ci(10, 20, 100), ci(25, 30, 200)])
    assert _chunks_in_sequence([ci(25, 30, 200), ci(0, 10, 0)])  # the index's order does not matter
    assert not _chunks_in_sequence([ci(0, 10, 0), ci(9, 20, 100)])
    assert not _chunks_in_sequence([ci(0, 100, 0), ci(10, 20, 100), ci(30, 40, 200)])  # inside a long one
    assert _chunks_in_sequence([])


def test_one_topic_on_two_channels_is_read_record_by_record(tmp_path):
    """A topic recorded on two channels (two publishers, or QoS changed mid-run): batches per channel would not
    interleave, so such a log is read message by message, in `read`'s order."""
    ts = typestore(2)
    text, _ = ts.generate_msgdef(T.IMU, ros_version=2)
    path = tmp_path / "two.mcap"
    rng = np.random.default_rng(8)
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2")
        sid = w.register_schema(T.IMU, "ros2msg", text.encode())
        chans = [w.register_channel("/imu", "cdr", sid), w.register_channel("/imu", "cdr", sid, metadata={"q": "2"})]
        for i in range(20):
            r = _imu(rng, i)
            w.add_message(chans[i % 2], log_time=r.stamp_ns, data=bytes(ts.serialize_cdr(imu_msg(ts, r), T.IMU)),
                          publish_time=r.stamp_ns)
        w.finish()
    with open_log(path) as log:
        plain, batched = list(log.read()), list(log.read_batched())
    assert not any(isinstance(r, ImuSamples) for r in batched)
    assert [r.stamp_ns for r in batched] == [r.stamp_ns for r in plain] == sorted(r.stamp_ns for r in plain)


def test_a_frame_id_that_is_not_utf8_is_left_to_rosbags(tmp_path):
    """Bytes that are not UTF-8 in a frame id: the direct decoders decline, and the reader warns and skips the message
    as it does for anything rosbags cannot decode (it ended the read with a UnicodeDecodeError)."""
    from kosmap.frontend.logs.cdrfast import scan

    s = Scan(T0, np.ones(10, np.float32), -1.0, 0.1, 0.1, 10.0, "laser", "/scan")
    ts = typestore(2)
    raw = bytearray(ts.serialize_cdr(scan_msg(ts, s), T.LASER_SCAN))
    raw[16] = 0xFF  # the frame id's first byte
    assert scan(bytes(raw), "/scan") is None
    text, _ = ts.generate_msgdef(T.LASER_SCAN, ros_version=2)
    path = tmp_path / "utf.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2")
        cid = w.register_channel("/scan", "cdr", w.register_schema(T.LASER_SCAN, "ros2msg", text.encode()))
        good = bytes(ts.serialize_cdr(scan_msg(ts, s), T.LASER_SCAN))
        for k, data in enumerate((good, bytes(raw), good)):
            w.add_message(cid, log_time=T0 + k, data=data, publish_time=T0 + k)
        w.finish()
    with open_log(path) as log:
        got = list(log.read_batched())
        assert len(got) == 2 and len(log.warnings) == 1 and "does not decode" in log.warnings[0]
