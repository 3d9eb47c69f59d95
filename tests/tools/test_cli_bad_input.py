"""Every bad input gets one line that says what is wrong and what to do, exit code 2, never a traceback."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kosmap.frontend.logs import convert
from kosmap.frontend.logs.writer import McapWriter
from tests.frontend.synthetic_log import DEPTH, records
from kosmap.tools.cli import main


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, *words: str) -> None:
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("kosmap: error: ")
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], (w, lines[0])


def _write(path, recs=(), raw=()):
    with McapWriter(path) as w:
        for r in recs:
            w.write(r)
        for topic, msgtype, msg, t in raw:
            w.write_msg(topic, msgtype, msg, t)


def _image(ts, encoding: str, width: int, height: int, step: int, nbytes: int):
    return ts.types["sensor_msgs/msg/Image"](header=convert.header(ts, 5, "cam"), height=height, width=width,
                                             encoding=encoding, is_bigendian=0, step=step,
                                             data=np.zeros(nbytes, np.uint8))


def test_missing_file(capsys, tmp_path):
    code, _, err = run(capsys, "info", str(tmp_path / "nope.mcap"))
    assert_one_line_error(code, err, "does not exist")


def test_directory(capsys, tmp_path):
    code, _, err = run(capsys, "info", str(tmp_path))
    assert_one_line_error(code, err, "is a directory")


def test_not_a_log(capsys, tmp_path):
    p = tmp_path / "notes.txt"
    p.write_text("hello, this is not a robot log\n")
    code, _, err = run(capsys, "info", str(p))
    assert_one_line_error(code, err, "not a log")


def test_empty_file(capsys, tmp_path):
    p = tmp_path / "empty.bag"
    p.write_bytes(b"")
    code, _, err = run(capsys, "info", str(p))
    assert_one_line_error(code, err, "is empty")


def test_truncated_mcap_yields_messages_before_the_damage(capsys, tmp_path):
    from kosmap.frontend.logs import open_log

    full = tmp_path / "full.mcap"
    recs = records(n=40, width=128, height=96)
    with McapWriter(full, chunk_size=64 << 10) as w:
        for r in recs:
            w.write(r)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with open_log(cut) as log:
        got = list(log.read())
        assert log.warnings and "truncated" in log.warnings[0]
    assert 0.4 * len(recs) < len(got) < len(recs)
    assert all(a.stamp_ns == b.stamp_ns for a, b in zip(recs, got))  # the messages before the damage, in order
    code, out, _ = run(capsys, "info", str(cut))
    assert code == 0
    assert "truncated" in out


def test_log_without_usable_topic(capsys, tmp_path):
    p = tmp_path / "odom_only.mcap"
    _write(p, [r for r in records(n=2) if r.topic == "/odom"])
    code, _, err = run(capsys, "info", str(p))
    assert_one_line_error(code, err, "no depth images and no laser scans", "/odom")


def test_unsupported_encoding(capsys, tmp_path):
    ts = convert.typestore(2)
    p = tmp_path / "rgb.mcap"
    _write(p, raw=[(DEPTH, "sensor_msgs/msg/Image", _image(ts, "rgb8", 4, 3, 12, 36), 5)])
    code, _, err = run(capsys, "info", str(p))
    assert_one_line_error(code, err, "'rgb8'", "16UC1", "32FC1")


def test_image_data_length_mismatch(capsys, tmp_path):
    ts = convert.typestore(2)
    p = tmp_path / "short.mcap"
    _write(p, raw=[(DEPTH, "sensor_msgs/msg/Image", _image(ts, "16UC1", 64, 48, 128, 100), 5)])
    code, _, err = run(capsys, "info", str(p))
    assert_one_line_error(code, err, "100 bytes", "damaged")


def test_mono16_is_read_as_16uc1(tmp_path):
    from kosmap.frontend.logs import open_log

    ts = convert.typestore(2)
    msg = _image(ts, "mono16", 2, 2, 4, 8)
    msg.data[:] = np.array([1, 0, 2, 0, 3, 0, 0, 1], np.uint8)
    _write(tmp_path / "m.mcap", raw=[(DEPTH, "sensor_msgs/msg/Image", msg, 5)])
    with open_log(tmp_path / "m.mcap") as log:
        (frame,) = list(log.read())
    assert frame.encoding == "16UC1"
    np.testing.assert_array_equal(frame.image, [[1, 2], [3, 256]])


def test_wrong_topic_override_names_the_alternatives(capsys, tmp_path):
    p = tmp_path / "log.mcap"
    _write(p, records(n=1))
    code, _, err = run(capsys, "info", str(p), "--scan-topic", "/base_scan")
    assert_one_line_error(code, err, "/base_scan", "/scan")


def test_nonsense_parameter(capsys, tmp_path):
    p = tmp_path / "log.mcap"
    _write(p, records(n=1))
    code, _, err = run(capsys, "info", str(p), "--set", "fspf.epsilon_m=-0.02")
    assert_one_line_error(code, err, "[fspf] epsilon_m")


def test_info_json_reports_topics_and_intrinsics(capsys, tmp_path):
    p = tmp_path / "log.mcap"
    _write(p, records(n=3))
    code, out, _ = run(capsys, "info", str(p), "--json")
    assert code == 0
    s = json.loads(out)
    assert s["format"] == "MCAP"
    counts = {t["name"]: t["count"] for t in s["topics"]}
    assert counts[DEPTH] == 3 and counts["/scan"] == 3
    assert s["detected"]["depth"][0] == DEPTH
    assert s["detected"]["camera_info"][DEPTH] == "/kinect2/sd/camera_info"
    cam = s["cameras"][DEPTH]
    assert cam["width"] == 64 and cam["fov_h_deg"] == pytest.approx(70.6, abs=1.5)


def test_a_path_the_system_refuses_is_one_line_not_a_traceback(capsys, tmp_path):
    f = tmp_path / "afile.yaml"
    f.write_text("x")
    code = main(["simulate", "room", "--out", str(f / "x.mcap"), "--duration", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0, err
    assert err == f"kosmap: error: {f}: File exists; check the path and its permissions" or "Not a directory" in err
    assert f.read_text() == "x"
    assert main(["simulate", "room", "--out", str(tmp_path / "inf.mcap"), "--duration", "inf"]) == 2
    assert "duration = inf is not a finite number" in capsys.readouterr().err and not (tmp_path / "inf.mcap").exists()
