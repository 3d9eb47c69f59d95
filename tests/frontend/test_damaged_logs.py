"""Cut and damaged logs: the readers say the file is truncated or damaged and what was read; never blame topics."""

from __future__ import annotations

import json
import struct

import pytest

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import BagWriter, McapWriter
from kosmap.frontend.records import Odometry, Scan
from tests.conftest import require_data
from tests.frontend.synthetic_log import records
from kosmap.tools.cli import main


def _laser_bag(path, n: int = 40, chunk: int = 32 << 10):
    """A bag of scans and odometry in chunks of ~`chunk` bytes (rosbags' default is 1 MiB: one chunk here)."""
    recs = [r for r in records(n=n) if isinstance(r, (Scan, Odometry))]
    w = BagWriter(path)
    w._w.chunk_threshold = chunk
    with w:
        for r in recs:
            w.write(r)
    return recs


def _cut(src, dst, size: int):
    dst.write_bytes(src.read_bytes()[:size])
    return dst


def _index_pos(path) -> int:
    """The bag header's index_pos field (the header record follows the 13-byte magic)."""
    data = path.read_bytes()
    at = data.index(b"index_pos=", 13) + len(b"index_pos=")
    return struct.unpack_from("<Q", data, at)[0]


def _top_level(data: bytes):
    """(position, header bytes) of a whole bag's top-level records: header length, header, data length, data."""
    pos = 13
    while pos < len(data):
        (hl,) = struct.unpack_from("<I", data, pos)
        (dl,) = struct.unpack_from("<I", data, pos + 4 + hl)
        yield pos, data[pos + 4:pos + 4 + hl]
        pos += 8 + hl + dl


def _cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(code: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("kosmap: error: "), err
    assert "--scan-topic" not in lines[0] and "Traceback" not in err
    return lines[0]


# -- 1. a truncated bag says so, with how much was read ----------------------------------------------------------------
def test_truncated_bag_is_marked_and_warns_with_what_was_read(tmp_path, capsys):
    recs = _laser_bag(tmp_path / "full.bag")
    full = tmp_path / "full.bag"
    cut = _cut(full, tmp_path / "half.bag", full.stat().st_size // 2)
    with open_log(cut) as log:
        info = log.info()
        assert info.truncated
        assert 0 < info.message_count < len(recs)
        assert len(log.warnings) == 1
        w = log.warnings[0]
        assert w.startswith("half.bag is truncated (it ends after ") and f"read {info.message_count} messages" in w
        assert "re-copy or re-record it" in w
        assert any("index could not be read" in n and "ends before its index" in n for n in info.notes)
    with open_log(cut) as log:  # a build reads with a reader of its own: its read warns too
        got = list(log.read())
        assert 0 < len(got) < len(recs)
        assert len(log.warnings) == 1 and "is truncated" in log.warnings[0]
    code, out, _ = _cli(capsys, "info", "--json", str(cut))
    s = json.loads(out)
    assert code == 0 and s["truncated"] is True
    assert any("is truncated" in w for w in s["warnings"])


def test_bag_cut_at_a_record_boundary_is_truncated(tmp_path):
    """Cut exactly between two chunks: no record is incomplete, but the index the header points to is gone."""
    _laser_bag(tmp_path / "full.bag")
    full = tmp_path / "full.bag"
    chunks = [pos for pos, head in _top_level(full.read_bytes()) if b"op=\x05" in head]
    assert len(chunks) >= 3
    cut = _cut(full, tmp_path / "cut.bag", chunks[2])
    with open_log(cut) as log:
        info = log.info()
    assert info.truncated and info.message_count > 0
    assert "before its index at byte" in log.warnings[0]


def test_unindexed_bag_with_whole_data_is_not_truncated(tmp_path):
    """A recording that was not closed (index_pos 0, no index) but whose chunks are whole: read in full, no warning;
    the note says `rosbag reindex` adds the index."""
    recs = _laser_bag(tmp_path / "full.bag")
    full = tmp_path / "full.bag"
    data = bytearray(full.read_bytes()[:_index_pos(full)])
    at = data.index(b"index_pos=", 13) + len(b"index_pos=")
    data[at:at + 8] = bytes(8)
    p = tmp_path / "unindexed.bag"
    p.write_bytes(bytes(data))
    with open_log(p) as log:
        info = log.info()
        got = list(log.read())
    assert not info.truncated and log.warnings == []
    assert len(got) == len(recs)
    assert any("no index" in n and "rosbag reindex" in n for n in info.notes)


# -- 2. a log damaged before its first message is a LogError, not a topic problem --------------------------------------
def test_bag_cut_inside_its_only_uncompressed_chunk_reads_its_whole_messages(tmp_path, capsys):
    """An uncompressed chunk cut at half its bytes still holds whole messages: they are read, with the cut's warning."""
    recs = _laser_bag(tmp_path / "full.bag", n=10, chunk=1 << 20)
    full = tmp_path / "full.bag"
    cut = _cut(full, tmp_path / "half.bag", full.stat().st_size // 2)
    with open_log(cut) as log:
        got = list(log.read())
        assert len(log.warnings) == 1 and "half.bag is truncated (it ends after" in log.warnings[0]
    # every message whose bytes lie wholly before the cut: ~half of them, identical to those written
    assert len(recs) * 0.3 < len(got) < len(recs) * 0.6
    for a, b in zip(got, recs[:len(got)], strict=False):
        assert a.stamp_ns == b.stamp_ns and type(a) is type(b)
    code, out, _ = _cli(capsys, "info", "--json", str(cut))
    assert code == 0 and json.loads(out)["truncated"] is True


def test_bag_cut_inside_its_only_compressed_chunk_is_a_log_error(tmp_path, capsys):
    recs = [r for r in records(n=10) if isinstance(r, (Scan, Odometry))]
    full = tmp_path / "full.bag"
    with BagWriter(full, compression="bz2") as w:
        for r in recs:
            w.write(r)
    cut = _cut(full, tmp_path / "half.bag", full.stat().st_size // 2)
    with pytest.raises(LogError, match=r"half\.bag is truncated: it ends after \d+ bytes, inside its first chunk"):
        with open_log(cut) as log:
            log.info()
    line = _one_line_error(*_cli(capsys, "info", str(cut))[::2])
    assert "re-copy or re-record it" in line


@pytest.mark.parametrize("size,where", [(13, "before its header record"), (100, "inside its header record")])
def test_bag_cut_to_its_header_is_a_log_error(tmp_path, capsys, size, where):
    _laser_bag(tmp_path / "full.bag", n=3)
    cut = _cut(tmp_path / "full.bag", tmp_path / "hdr.bag", size)
    line = _one_line_error(*_cli(capsys, "info", str(cut))[::2])
    assert f"hdr.bag is truncated: it ends after {size} bytes, {where}" in line


def _small_mcap(path):
    with McapWriter(path) as w:
        for r in records(n=3):
            w.write(r)
    return path


def test_mcap_cut_after_100_bytes_is_a_log_error(tmp_path, capsys):
    full = _small_mcap(tmp_path / "full.mcap")
    cut = _cut(full, tmp_path / "tiny.mcap", 100)
    line = _one_line_error(*_cli(capsys, "info", str(cut))[::2])
    assert "tiny.mcap is truncated: it ends after 100 bytes, inside the record at byte" in line
    assert "re-copy or re-record it" in line


def test_mcap_magic_then_garbage_is_a_log_error(tmp_path, capsys):
    p = tmp_path / "garbage.mcap"
    p.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    with pytest.raises(LogError, match=r"garbage\.mcap is damaged: the record at byte 8 .* is not an MCAP record"):
        with open_log(p) as log:
            log.info()
    _one_line_error(*_cli(capsys, "build", str(p), "--out", str(tmp_path / "out"))[::2])


def test_whole_logs_without_depth_or_laser_keep_the_topic_message(tmp_path, capsys):
    for p in (tmp_path / "odom.bag", tmp_path / "odom.mcap"):
        w = BagWriter(p) if p.suffix == ".bag" else McapWriter(p)
        with w:
            for r in records(n=2):
                if isinstance(r, Odometry):
                    w.write(r)
        code, _, err = _cli(capsys, "info", str(p))
        assert code == 2 and "no depth images and no laser scans" in err and "/odom" in err


# -- 3. the index note is worded for a user ----------------------------------------------------------------------------
@pytest.mark.data
def test_demo_bag_index_note_names_no_bare_exception():
    """rosbags asserts on the demo bag's index: the note says so in words; the bag is whole, so no truncation."""
    with open_log(require_data("depth/scan_tools_demo_bag/demo.bag")) as log:
        info = log.info()
    assert info.notes == ["the bag's index could not be read (it is not laid out as rosbags expects); "
                          "read it from start to end instead"]
    assert not info.truncated and log.warnings == []


@pytest.mark.data
def test_real_bag_cut_in_half_warns(tmp_path):
    full = require_data("laser/intel/intel.orig.bag")
    cut = tmp_path / "intel_half.bag"
    with open(full, "rb") as f:
        cut.write_bytes(f.read(full.stat().st_size // 2))
    with open_log(cut) as log:
        n = sum(1 for r in log.read(["/scan"]) if isinstance(r, Scan))
        assert 0 < n < 13631
        assert len(log.warnings) == 1 and f"read {n} messages" in log.warnings[0]


def test_a_cut_mcap_says_so_even_after_another_warning(tmp_path):
    from kosmap.frontend.records import Imu

    import numpy as np

    recs = [r for r in records(n=40) if isinstance(r, (Scan, Odometry))]
    t0 = recs[0].stamp_ns
    bad = Imu(t0, np.array([np.nan, 0.0, 0.0]), np.array([0.0, 0.0, 9.81]), topic="/imu")  # warned first
    whole = tmp_path / "whole.mcap"
    with McapWriter(whole, chunk_size=4096) as w:
        w.write(bad, "/imu")
        for r in recs:
            w.write(r, r.topic)
    cut = _cut(whole, tmp_path / "cut.mcap", whole.stat().st_size * 2 // 3)
    with open_log(cut) as lg:  # read before info(): the IMU's warning comes first
        n = sum(1 for _ in lg.read(["/imu", recs[0].topic, recs[1].topic]))
        assert 0 < n < len(recs) + 1
        assert any("IMU on /imu" in w for w in lg.warnings)
        assert any("cut.mcap is truncated" in w for w in lg.warnings), lg.warnings
