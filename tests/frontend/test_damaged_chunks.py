"""Damaged chunks inside a log: each is skipped with a warning giving where and when, the rest is read; only a log
with nothing readable left is an error (one line)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import BagWriter
from kosmap.frontend.records import Odometry, Scan
from kosmap.tools.cli import main
from tests.conftest import require_data
from tests.frontend.synthetic_log import records


def laser_bag(path, compression: str | None = "bz2", n: int = 40, chunk: int = 32 << 10) -> list:
    recs = [r for r in records(n=n) if isinstance(r, (Scan, Odometry))]
    with BagWriter(path, compression=compression, chunk_bytes=chunk) as w:
        for r in recs:
            w.write(r)
    return recs


def bag_chunks(data: bytes) -> list[tuple[int, int, int]]:
    """(record position, data start, data length) of a whole bag's chunk records."""
    out, pos = [], 13
    while pos < len(data):
        (hl,) = struct.unpack_from("<I", data, pos)
        (dl,) = struct.unpack_from("<I", data, pos + 4 + hl)
        if b"op=\x05" in data[pos + 4:pos + 4 + hl]:
            out.append((pos, pos + 8 + hl, dl))
        pos += 8 + hl + dl
    return out


def flip(data: bytes, at: int) -> bytes:
    d = bytearray(data)
    d[at] ^= 0x40
    return bytes(d)


def chunk_stamps(path, chunk_pos: int) -> list[int]:
    """Stamps of the messages the index places in the chunk at `chunk_pos` (read from the whole bag)."""
    from rosbags.rosbag1 import Reader

    with Reader(path) as r:
        return sorted(e.time for c in r.connections for e in r.indexes[c.id] if e.chunk_pos == chunk_pos)


def drop_index(data: bytes) -> bytes:
    """The bag without its index (a recording that was not closed): index_pos 0, the data up to the old index."""
    at = data.index(b"index_pos=", 13) + len(b"index_pos=")
    (index_pos,) = struct.unpack_from("<Q", data, at)
    d = bytearray(data[:index_pos])
    d[at:at + 8] = bytes(8)
    return bytes(d)


# A ROS 1 chunk has no checksum of its own: bz2 checks each block's CRC, an lz4 frame (as rosbags writes it) only its
# header's, so the lz4 case flips a byte of the frame descriptor.
@pytest.mark.parametrize("compression,where", [("bz2", 0.5), ("lz4", 0.0)])
def test_one_damaged_chunk_is_skipped_with_its_time_range(tmp_path, compression, where):
    whole = tmp_path / "whole.bag"
    recs = laser_bag(whole, compression)
    data = whole.read_bytes()
    chunks = bag_chunks(data)
    assert len(chunks) >= 4
    pos, start, length = chunks[2]
    lost = chunk_stamps(whole, pos)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(flip(data, start + 5 + int(length * where)))
    with open_log(bad) as log:
        got = list(log.read())
    assert len(got) == len(recs) - len(lost) and 0 < len(lost) < len(recs) // 2
    assert {r.stamp_ns for r in got} == {r.stamp_ns for r in recs} - set(lost)  # all the other chunks, whole
    assert len(log.warnings) == 1
    w = log.warnings[0]
    assert f"bad.bag: the chunk at byte {pos} is damaged" in w
    assert f"from t={lost[0] * 1e-9:.3f} s to t={lost[-1] * 1e-9:.3f} s are skipped" in w


def test_damaged_chunk_of_an_unindexed_bag_is_skipped(tmp_path):
    whole = tmp_path / "whole.bag"
    recs = laser_bag(whole)
    data = whole.read_bytes()
    pos, start, length = bag_chunks(data)[1]
    lost = chunk_stamps(whole, pos)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(drop_index(flip(data, start + length // 3)))
    with open_log(bad) as log:
        got = list(log.read())
    assert {r.stamp_ns for r in got} == {r.stamp_ns for r in recs} - set(lost)
    assert any(f"the chunk at byte {pos} is damaged" in w for w in log.warnings), log.warnings


@pytest.mark.parametrize("indexed", [True, False])
def test_bag_whose_every_chunk_is_damaged_is_one_line(tmp_path, capsys, indexed):
    whole = tmp_path / "whole.bag"
    laser_bag(whole, n=20)
    data = whole.read_bytes()
    for _, start, length in bag_chunks(data):
        data = flip(data, start + length // 2)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(data if indexed else drop_index(data))
    with pytest.raises(LogError, match="bad.bag is damaged: .* no message of the wanted topics is left"):
        with open_log(bad) as log:
            list(log.read())
    code = main(["slam", str(bad), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("kosmap: error: bad.bag is damaged"), err
    assert not (tmp_path / "out").exists()


@pytest.mark.data
def test_real_bag_with_one_flipped_byte_in_a_bz2_chunk(tmp_path):
    """fr079's bag (bz2 chunks): one flipped byte costs that chunk's scans only."""
    src = require_data("laser/fr079/fr079.orig.bag")
    data = src.read_bytes()
    chunks = bag_chunks(data)
    pos, start, length = chunks[len(chunks) // 2]
    bad = tmp_path / "fr079_flipped.bag"
    bad.write_bytes(flip(data, start + length // 2))
    with open_log(src) as log:
        n_whole = sum(isinstance(r, Scan) for r in log.read(["/scan"]))
    with open_log(bad) as log:
        n = sum(isinstance(r, Scan) for r in log.read(["/scan"]))
        assert len(log.warnings) == 1 and f"the chunk at byte {pos} is damaged" in log.warnings[0]
    assert n_whole * (1 - 2 / len(chunks)) < n < n_whole


@pytest.mark.slow
def test_slam_on_a_bag_with_a_damaged_chunk_completes_with_a_warning(tmp_path, capsys):
    """A bz2 chunk with a flipped byte (an `OSError: Invalid data stream` inside bz2) is skipped: the trajectory is built from the
    remaining chunks, bridged over the lost stretch, and scored against the log's ground truth."""
    import json

    from tests.mapping.synthetic_laser import make_log
    from tests.mapping.synthetic_laser import records as ring_records

    log = make_log(seed=2, laps=1)
    whole = tmp_path / "ring.bag"
    with BagWriter(whole, compression="bz2", chunk_bytes=64 << 10) as w:
        for r in ring_records(log):
            w.write(r)
    data = whole.read_bytes()
    chunks = bag_chunks(data)
    assert len(chunks) >= 5
    pos, start, length = chunks[len(chunks) // 2]
    bad = tmp_path / "ring_bad.bag"
    bad.write_bytes(flip(data, start + length // 2))
    out = tmp_path / "out"
    code = main(["slam", str(bad), "--out", str(out), "--set", "graph.submap_nodes=20"])
    stdout, err = capsys.readouterr()
    assert code == 0, err
    assert f"the chunk at byte {pos} is damaged" in stdout + err
    m = json.loads((out / "metrics.json").read_text())
    assert np.isfinite(m["ate"]["rmse"]) and m["ate"]["rmse"] < 0.3


def test_damage_is_counted_once_over_several_reads(tmp_path):
    """info() and read() of an unindexed bag both walk it: seven damaged chunks are counted as seven, not fourteen."""
    whole = tmp_path / "whole.bag"
    laser_bag(whole)
    data = whole.read_bytes()
    chunks = bag_chunks(data)
    assert len(chunks) >= 9
    for _, start, length in chunks[1:8]:  # (the first holds the connection records: without it nothing decodes)
        data = flip(data, start + length // 2)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(drop_index(data))
    with open_log(bad) as log:
        log.info()
        list(log.read())
        list(log.read(["/odom"]))
    per_chunk = [w for w in log.warnings if "is damaged" in w]
    assert len(per_chunk) == 5  # the first five one by one, then one warning counting them all
    assert log.warnings[-1] == "bad.bag: in all, 7 damaged chunks were skipped"


def test_info_check_finds_the_damaged_chunk_the_index_hides(tmp_path, capsys):
    """`kosmap info` reads only the index, which a damaged chunk does not touch; `--check` reads the messages and
    names the chunk, with the count of messages read."""
    import json

    whole = tmp_path / "whole.bag"
    recs = laser_bag(whole)
    data = whole.read_bytes()
    pos, start, length = bag_chunks(data)[2]
    lost = chunk_stamps(whole, pos)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(flip(data, start + length // 2))
    assert main(["info", str(bad), "--json"]) == 0
    assert "check" not in json.loads(capsys.readouterr().out)
    assert main(["info", str(whole), "--check", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["check"] == {"messages_read": len(recs), "messages_indexed": len(recs),
                                                             "problems": []}
    assert main(["info", str(bad), "--check", "--json"]) == 0
    check = json.loads(capsys.readouterr().out)["check"]
    assert check["messages_read"] == len(recs) - len(lost) and check["messages_indexed"] == len(recs)
    assert len(check["problems"]) == 1 and f"the chunk at byte {pos} is damaged" in check["problems"][0]
    assert main(["info", str(bad), "--check"]) == 0
    out = capsys.readouterr().out
    assert f"damaged: {len(recs) - len(lost)} of {len(recs)} indexed messages read" in out
