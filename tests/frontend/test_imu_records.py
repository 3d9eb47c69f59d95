"""Imu records (sensor_msgs/Imu): bit-exact round trips through MCAP and ROS 1 bags, topic detection, the
covariance −1 ("not provided") semantics, and unusable samples skipped with one warning."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from kosmap.frontend.errors import TopicError
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.logs.topics import IMU, ODOMETRY, TopicsConfig
from kosmap.frontend.logs.writer import BagWriter, McapWriter, open_writer
from kosmap.frontend.records import Imu, Odometry


def _samples(n: int = 50, seed: int = 3, topic: str = "/imu") -> list[Imu]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        ocov = np.array([-1.0] + [0.0] * 8) if i % 2 else rng.random(9)
        out.append(Imu(1_700_000_000_000_000_000 + i * 5_000_001 + int(rng.integers(0, 1000)),
                       rng.normal(0, 0.3, 3), rng.normal(0, 1.0, 3) + [0, 0, 9.80665], q, ocov,
                       np.diag(rng.random(3) * 1e-6).reshape(9), np.diag(rng.random(3) * 1e-3).reshape(9),
                       "imu_link", topic))
    return out


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype == np.float64 and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
def test_imu_round_trips_bit_exact(tmp_path, suffix):
    recs = _samples()
    path = tmp_path / f"imu{suffix}"
    with open_writer(path) as w:
        for r in recs:
            w.write(r)
    with open_log(path) as log:
        info = log.info()
        got = list(log.read())
        assert log.warnings == []
    assert info.types() == {"/imu": IMU} and info.count("/imu") == len(recs)
    assert len(got) == len(recs)
    for a, b in zip(recs, got):
        assert isinstance(b, Imu)
        assert (a.stamp_ns, a.frame_id, a.topic) == (b.stamp_ns, b.frame_id, b.topic)
        for name in ("angular_velocity", "linear_acceleration", "orientation", "orientation_cov",
                     "angular_velocity_cov", "linear_acceleration_cov"):
            assert _same_bits(getattr(a, name), getattr(b, name)), name
        assert a.has_orientation == b.has_orientation


def test_writer_classes_accept_imu_with_an_explicit_topic_and_rosbags_reads_them(tmp_path):
    rec = _samples(3, topic="")
    for cls, name in ((McapWriter, "a.mcap"), (BagWriter, "a.bag")):
        with cls(tmp_path / name) as w:
            for r in rec:
                w.write(r, "/imu/data_raw")
        with AnyReader([tmp_path / name]) as r:
            msgs = [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages()]
        assert [m.angular_velocity.z for m in msgs] == [x.angular_velocity[2] for x in rec]
        assert msgs[1].orientation_covariance[0] == -1.0


def test_covariance_minus_one_means_not_provided_and_zeros_mean_unknown():
    raw = Imu(0, [0, 0, 0.1], [0, 0, 9.8], [0, 0, 0, 1], [-1] + [0] * 8, np.zeros(9), np.diag([1e-4] * 3).reshape(9))
    assert raw.stamp == 0.0 and raw.angular_velocity[2] == pytest.approx(0.1)
    assert not raw.has_orientation  # orientation_covariance[0] == -1
    assert raw.has_angular_velocity and not raw.has_angular_velocity_cov  # all zeros: covariance unknown
    assert raw.has_linear_acceleration_cov
    fused = Imu(0, [0, 0, 0], [0, 0, 9.8], [0, 0, 0.38268343, 0.92387953], np.eye(3).reshape(9) * 1e-3,
                [-1] + [0] * 8, np.zeros(9))
    assert fused.has_orientation and not fused.has_angular_velocity and not fused.has_angular_velocity_cov
    assert fused.angular_velocity.shape == (3,) and fused.orientation_cov.shape == (9,)


def test_imu_topic_detection_prefers_the_usual_driver_names():
    t = {"/scan": "sensor_msgs/msg/LaserScan", "/odom": ODOMETRY, "/camera/imu": IMU, "/imu/data": IMU,
         "/imu/data_raw": IMU, "/ground_truth/imu": IMU}
    det = detect_topics(t)
    assert det.imu == "/imu/data" and "/imu/data" in det.wanted()
    assert detect_topics({**t, "/imu": IMU}).imu == "/imu"
    assert detect_topics({"/camera/imu": IMU, "/ground_truth/imu": IMU}).imu == "/camera/imu"
    assert detect_topics({"/gt/imu": IMU}).imu is None  # ground truth is never a sensor
    assert detect_topics(t, TopicsConfig(imu="/camera/imu")).imu == "/camera/imu"
    off = detect_topics(t, TopicsConfig(imu="none"))
    assert off.imu is None and not any("imu" in n for n in off.wanted())


def test_wrong_imu_topic_is_refused_in_one_line():
    t = {"/odom": ODOMETRY, "/imu": IMU}
    with pytest.raises(TopicError, match=r"imu topic /odom has type nav_msgs/msg/Odometry, expected sensor_msgs/msg/Imu; check --imu-topic"):
        detect_topics(t, TopicsConfig(imu="/odom"))
    with pytest.raises(TopicError, match=r"imu topic /imu2 is not in the log \(topics of type sensor_msgs/msg/Imu here: /imu\)"):
        detect_topics(t, TopicsConfig(imu="/imu2"))


@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
def test_non_finite_gyro_samples_are_skipped_with_one_warning(tmp_path, suffix):
    recs = _samples(20)
    bad = {4, 9, 10}
    path = tmp_path / f"nan{suffix}"
    with open_writer(path) as w:
        w.write(Odometry(recs[0].stamp_ns, 0.0, 0.0, 0.0, topic="/odom"))
        for i, r in enumerate(recs):
            if i in bad:
                r = Imu(r.stamp_ns, [0.0, np.nan, 0.0], r.linear_acceleration, r.orientation, r.orientation_cov,
                        r.angular_velocity_cov, r.linear_acceleration_cov, r.frame_id, r.topic)
            w.write(r)
    with open_log(path) as log:
        got = list(log.read())
        warnings = list(log.warnings)
    imus = [r for r in got if isinstance(r, Imu)]
    assert [r.stamp_ns for r in imus] == [r.stamp_ns for i, r in enumerate(recs) if i not in bad]
    assert len(warnings) == 1 and "\n" not in warnings[0]
    assert "IMU on /imu has a non-finite angular velocity (first at t=" in warnings[0]


def test_kosmap_info_shows_the_imu_and_refuses_a_wrong_imu_topic(tmp_path, capsys):
    from kosmap.tools.cli import main

    path = tmp_path / "imu.mcap"
    with open_writer(path) as w:
        w.write_scan("/scan", _scan())
        for r in _samples(10):
            w.write(r)
    assert main(["info", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["detected"]["imu"] == "/imu"
    assert main(["info", str(path), "--imu-topic", "/scan"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("kosmap: error: imu topic /scan has type sensor_msgs/msg/LaserScan, expected sensor_msgs/msg/Imu; "
                   "check --imu-topic")


def _scan():
    from kosmap.frontend.records import Scan

    return Scan(1_700_000_000_000_000_000, np.full(10, 2.0, np.float32), -0.5, 0.1, 0.1, 30.0, "laser", "/scan")
