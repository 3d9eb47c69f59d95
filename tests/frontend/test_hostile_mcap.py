"""Hostile and damaged MCAP containers: no size field allocates more than the file holds, chunk CRCs are checked,
and a damaged chunk is skipped, read or fatal as [topics] on_damage says, with its time range in the warning."""

from __future__ import annotations

import struct

import pytest

from kosmap.frontend.errors import ConfigError, LogError
from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.records import Odometry, Scan
from kosmap.mapping.config import load_config
from kosmap.tools.cli import main
from tests.frontend.hostile import (CHUNK_INDEX_LENGTH_AT, CHUNK_USIZE_AT, MCAP_CHUNK_INDEX, chunk_payload, flip,
                                    lz4_claim, mcap_chunks, mcap_records, put, without_summary)
from tests.frontend.synthetic_log import records


def small_mcap(path, compression: str = "zstd") -> list:
    """Scans and odometry in ~20 chunks of 16 KiB."""
    recs = [r for r in records(n=40) if isinstance(r, (Scan, Odometry))]
    with McapWriter(path, compression=compression, chunk_size=16 << 10) as w:
        for r in recs:
            w.write(r)
    return recs


def chunk_stamps(data: bytes, chunk_pos: int) -> tuple[int, int]:
    """The chunk's message start and end time, from its header."""
    return struct.unpack_from("<QQ", data, chunk_pos + 9)


def read_all(path, on_damage: str = "skip") -> tuple[list, list[str]]:
    with open_log(path, on_damage) as log:
        log.info()
        recs = list(log.read())
    return recs, log.warnings


def lost_in(recs: list, data: bytes, chunk_pos: int) -> int:
    """How many of the written records lie in the chunk's time range."""
    t0, t1 = chunk_stamps(data, chunk_pos)
    return sum(t0 <= r.stamp_ns <= t1 for r in recs)


def _write(tmp_path, data: bytes, name: str = "bad.mcap"):
    p = tmp_path / name
    p.write_bytes(data)
    return p


def _check_skipped(recs, got, warnings, data, pos, why: str, at_byte: bool = True):
    t0, t1 = chunk_stamps(data, pos)
    assert len(got) == len(recs) - lost_in(recs, data, pos) and lost_in(recs, data, pos) > 0
    assert {r.stamp_ns for r in got} == {r.stamp_ns for r in recs if not t0 <= r.stamp_ns <= t1}
    w = [w for w in warnings if "is damaged" in w]
    assert len(w) == 1, warnings
    assert why in w[0] and f"messages from t={t0 * 1e-9:.3f} s to t={t1 * 1e-9:.3f} s" in w[0]
    assert "skipped" in w[0] and "topics.on_damage" in w[0]
    if at_byte:
        assert f"the chunk at byte {pos} " in w[0]


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_chunk_index_length_of_2_60_skips_that_chunk(tmp_path, compression):
    whole = tmp_path / "whole.mcap"
    recs = small_mcap(whole, compression)
    data = whole.read_bytes()
    idx = [p for p, op, _ in mcap_records(data) if op == MCAP_CHUNK_INDEX][3]
    (pos,) = struct.unpack_from("<Q", data, idx + CHUNK_INDEX_LENGTH_AT - 8)
    bad = _write(tmp_path, put(data, idx + CHUNK_INDEX_LENGTH_AT, "<Q", 1 << 60))
    got, warnings = read_all(bad)
    _check_skipped(recs, got, warnings, data, pos, "its index says 1152921504606846976 bytes")


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
@pytest.mark.parametrize("indexed", [True, False])
def test_chunk_claiming_2_40_uncompressed_bytes_is_skipped(tmp_path, compression, indexed):
    """The chunk header's uncompressed size (zstd's output bound) claims 1 TiB: refused before any allocation."""
    whole = tmp_path / "whole.mcap"
    recs = small_mcap(whole, compression)
    data = whole.read_bytes()
    pos = mcap_chunks(data)[2]
    bad = put(data, pos + CHUNK_USIZE_AT, "<Q", 1 << 40)
    got, warnings = read_all(_write(tmp_path, bad if indexed else without_summary(bad)))
    _check_skipped(recs, got, warnings, data, pos, "its header claims 1099511627776 uncompressed bytes", indexed)


@pytest.mark.parametrize("indexed", [True, False])
def test_lz4_frame_claiming_2_40_bytes_is_skipped(tmp_path, indexed):
    """lz4.frame.decompress allocates a frame's claimed content size (MemoryError at 2^40): the frame is read in
    pieces instead, and ends where its data ends."""
    whole = tmp_path / "whole.mcap"
    recs = small_mcap(whole, "lz4")
    data = whole.read_bytes()
    pos = mcap_chunks(data)[4]
    bad = lz4_claim(data, chunk_payload(data, pos)[0], 1 << 40)
    got, warnings = read_all(_write(tmp_path, bad if indexed else without_summary(bad)))
    _check_skipped(recs, got, warnings, data, pos, "its lz4 data does not decompress", indexed)


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_flipped_byte_fails_the_chunk_crc(tmp_path, compression):
    """One flipped byte inside a compressed chunk would give a different map without a word if read as it is: its CRC
    disagrees, and on_damage says what happens (skip: the other chunks; read: every message; fail: one error)."""
    whole = tmp_path / "whole.mcap"
    recs = small_mcap(whole, compression)
    data = whole.read_bytes()
    pos = mcap_chunks(data)[5]
    at, length = chunk_payload(data, pos)
    bad = _write(tmp_path, flip(data, at + length // 2))
    got, warnings = read_all(bad)
    _check_skipped(recs, got, warnings, data, pos, "its CRC is")
    got, warnings = read_all(bad, "read")
    assert len(got) == len(recs) and "read as they are" in warnings[0]
    with pytest.raises(LogError, match=rf"bad\.mcap: the chunk at byte {pos} \(messages from .*\) is damaged \(its CRC"):
        read_all(bad, "fail")
    got, warnings = read_all(_write(tmp_path, without_summary(flip(data, at + length // 2)), "linear.mcap"))
    _check_skipped(recs, got, warnings, data, pos, "its CRC is", at_byte=False)


def test_lz4_error_on_the_linear_path_skips_the_chunk(tmp_path):
    """A garbled lz4 frame header (lz4 raises RuntimeError) in a log without summary: that chunk is skipped."""
    whole = tmp_path / "whole.mcap"
    recs = small_mcap(whole, "lz4")
    data = whole.read_bytes()
    pos = mcap_chunks(data)[3]
    at, _ = chunk_payload(data, pos)
    got, warnings = read_all(_write(tmp_path, without_summary(flip(data, at + 5))))
    _check_skipped(recs, got, warnings, data, pos, "its lz4 data does not decompress (RuntimeError", at_byte=False)


def test_record_length_of_2_60_on_the_linear_path_is_a_cut(tmp_path):
    whole = tmp_path / "whole.mcap"
    recs = small_mcap(whole)
    data = without_summary(whole.read_bytes())
    pos = mcap_chunks(data)[6]
    got, warnings = read_all(_write(tmp_path, put(data, pos + 1, "<Q", 1 << 60)))
    t0, _ = chunk_stamps(data, pos)
    assert len(got) == sum(r.stamp_ns < t0 for r in recs)
    assert any("is truncated: read" in w for w in warnings)


def test_on_damage_is_validated():
    assert load_config(overrides=["topics.on_damage=read"]).topics.on_damage == "read"
    with pytest.raises(ConfigError, match="on_damage"):
        load_config(overrides=["topics.on_damage=maybe"])


def test_on_damage_fail_from_the_cli_is_one_line(tmp_path, capsys):
    whole = tmp_path / "whole.mcap"
    small_mcap(whole)
    data = whole.read_bytes()
    pos = mcap_chunks(data)[5]
    at, length = chunk_payload(data, pos)
    bad = _write(tmp_path, flip(data, at + length // 2))
    code = main(["slam", str(bad), "--out", str(tmp_path / "out"), "--set", "topics.on_damage=fail"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "is damaged (its CRC" in err[0], err


@pytest.mark.parametrize("indexed", [True, False])
def test_mcap_whose_every_chunk_is_damaged_is_one_line(tmp_path, capsys, indexed):
    whole = tmp_path / "whole.mcap"
    small_mcap(whole)
    data = whole.read_bytes()
    chunks = mcap_chunks(data)
    for pos in chunks:
        at, length = chunk_payload(data, pos)
        data = flip(data, at + length // 2)
    bad = _write(tmp_path, data if indexed else without_summary(data))
    with pytest.raises(LogError, match=rf"bad\.mcap is damaged: {len(chunks)} chunk\(s\) are unreadable .* no message"):
        read_all(bad)
    code = main(["slam", str(bad), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("kosmap: error: bad.mcap is damaged"), err
    assert not (tmp_path / "out").exists()
