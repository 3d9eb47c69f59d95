"""Records written by our writers read back exactly, through our readers and through rosbags."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from kosmap.frontend.logs import convert, open_log
from kosmap.frontend.logs.writer import BagWriter, McapWriter, open_writer
from kosmap.frontend.records import CameraModel, DepthFrame, Odometry, Scan, Transforms
from tests.frontend.synthetic_log import records


def assert_same(a, b) -> None:
    assert type(a) is type(b)
    assert a.stamp_ns == b.stamp_ns and a.topic == b.topic
    if isinstance(a, DepthFrame):
        assert a.encoding == b.encoding and a.frame_id == b.frame_id
        assert a.image.dtype == b.image.dtype
        np.testing.assert_array_equal(a.image.view(np.uint8), b.image.view(np.uint8))  # bit-exact, NaN included
    elif isinstance(a, Scan):
        np.testing.assert_array_equal(a.ranges, b.ranges)
        np.testing.assert_array_equal(a.intensities, b.intensities)
        assert np.float32(a.angle_min) == np.float32(b.angle_min)
        assert np.float32(a.angle_increment) == np.float32(b.angle_increment)
        assert (a.range_min, a.range_max, a.frame_id) == (pytest.approx(b.range_min), pytest.approx(b.range_max), b.frame_id)
    elif isinstance(a, Odometry):
        assert (a.x, a.y, a.frame_id, a.child_frame_id) == (b.x, b.y, b.frame_id, b.child_frame_id)
        assert a.yaw == pytest.approx(b.yaw, abs=1e-12)
    elif isinstance(a, CameraModel):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.D, b.D)
        assert (a.width, a.height, a.frame_id) == (b.width, b.height, b.frame_id)
    elif isinstance(a, Transforms):
        assert a.static == b.static
        for x, y in zip(a.transforms, b.transforms):
            assert (x.parent, x.child, x.stamp_ns) == (y.parent, y.child, y.stamp_ns)
            np.testing.assert_array_equal(x.translation, y.translation)
            np.testing.assert_allclose(x.rotation, y.rotation, atol=1e-15)


@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
def test_every_record_type_round_trips(tmp_path, suffix):
    recs = records()
    path = tmp_path / f"log{suffix}"
    with open_writer(path) as w:
        for r in recs:
            w.write(r)
    assert not list(tmp_path.glob("*.partial"))
    with open_log(path) as log:
        info = log.info()
        got = list(log.read())
    assert len(got) == len(recs)
    for a, b in zip(recs, got):
        assert_same(a, b)
    assert info.count("/kinect2/sd/image_depth_rect") == 5
    assert info.format == ("MCAP" if suffix == ".mcap" else "ROS 1 bag")


@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
def test_rosbags_anyreader_opens_our_files(tmp_path, suffix):
    """Other tools can read what we write (rosbags stands in for Foxglove / ROS here)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = tmp_path / f"log{suffix}"
    recs = records(n=2)
    with open_writer(path) as w:
        for r in recs:
            w.write(r)
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        conns = [c for c in reader.connections if c.topic == "/scan"]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    np.testing.assert_array_equal(msgs[0].ranges, recs[4].ranges)


def test_writer_leaves_nothing_when_interrupted(tmp_path):
    path = tmp_path / "out.mcap"
    with pytest.raises(RuntimeError):
        with McapWriter(path) as w:
            w.write(records(n=1)[2])
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError):
        with BagWriter(tmp_path / "out.bag") as w:
            w.write(records(n=1)[2])
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_grid_pointcloud_and_path_messages_are_readable(tmp_path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    rng = np.random.default_rng(3)
    grid = rng.choice(np.array([-1, 0, 100], np.int8), (20, 30))
    pts = rng.random((50, 3)).astype(np.float32)
    with McapWriter(tmp_path / "m.mcap") as w:
        w.write_grid("/map", 5, "map", grid, 0.05, (1.0, 2.0, 0.0))
        w.write_pointcloud("/planes", 6, "cam", pts, {"plane": np.arange(50, dtype=np.float32)})
        w.write_path("/path", 7, "map", np.array([[0, 0, 0], [1, 2, 0.5]]), np.array([1, 2]))
    with AnyReader([tmp_path / "m.mcap"], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
        got = {c.topic: r.deserialize(raw, c.msgtype) for c, _, raw in r.messages()}
    np.testing.assert_array_equal(got["/map"].data.reshape(20, 30), grid)
    assert got["/map"].info.resolution == pytest.approx(0.05)
    cloud = got["/planes"].data.view(np.float32).reshape(50, 4)
    np.testing.assert_array_equal(cloud[:, :3], pts)
    assert got["/path"].poses[1].pose.position.y == 2.0


@settings(max_examples=40, deadline=None)
@given(ranges=arrays(np.float32, st.integers(0, 400), elements=st.floats(0, 100, width=32) | st.just(np.inf)),
       angle_min=st.floats(-3.0, 0, width=32), inc=st.floats(0.0001220703125, 0.125, width=32),
       stamp=st.integers(0, (2**31 - 1) * 1_000_000_000))  # ROS time: int32 (ROS 2) / uint32 (ROS 1) seconds
def test_scan_cdr_and_ros1_round_trip_any_values(ranges, angle_min, inc, stamp):
    """Property: any scan survives serialisation for ROS 2 (CDR) and ROS 1, bit for bit."""
    s = Scan(stamp, ranges, float(angle_min), float(inc), 0.1, 30.0, "laser", "/scan")
    for version in (1, 2):
        ts = convert.typestore(version)
        msgtype, msg = convert.record_msg(ts, s)
        raw = ts.serialize_cdr(msg, msgtype) if version == 2 else ts.serialize_ros1(msg, msgtype)
        back = ts.deserialize_cdr(raw, msgtype) if version == 2 else ts.deserialize_ros1(raw, msgtype)
        r = convert.to_record(back, msgtype, "/scan")
        assert r.stamp_ns == stamp
        np.testing.assert_array_equal(r.ranges, ranges)


def test_repeated_camera_infos_read_back_at_their_own_stamps(tmp_path):
    """The MCAP reader reuses a CameraInfo record when only the stamp changed (frontend/logs/mcap.py
    McapLog._decode): each record still has its own stamp, and a changed calibration or frame is decoded anew."""
    from dataclasses import replace

    base = CameraModel.from_fov(512, 424, np.radians(70.6), np.radians(60.0), "kinect2_ir_optical_frame")
    base = replace(base, topic="/kinect2/sd/camera_info")
    other = replace(base, K=base.K * np.array([[1.01], [1.0], [1.0]]))
    sent = [replace(c, stamp_ns=1_000_000_000 + 33_333_333 * i)
            for i, c in enumerate([base, base, base, other, other, base, replace(base, frame_id="cam2"), base])]
    path = tmp_path / "infos.mcap"
    with open_writer(path) as w:
        for c in sent:
            w.write(c)
    with open_log(path) as log:
        got = list(log.read())
    assert len(got) == len(sent)
    for a, b in zip(sent, got):
        assert_same(a, b)
        assert a.stamp_ns == b.stamp_ns
    # repeats reuse the record before them (its arrays); a changed calibration or frame is a new record
    assert got[1].K is got[0].K and got[2].K is got[0].K and got[4].K is got[3].K
    assert got[3].K is not got[2].K and got[5].K is not got[4].K and got[6].K is not got[5].K
