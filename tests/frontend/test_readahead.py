"""Reading ahead on a thread gives the same items in the same order, raises what the source raised where it raised
it, and leaves no thread behind however the reader stops."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.readahead import read_ahead
from kosmap.frontend.logs.writer import McapWriter
from tests.frontend.synthetic_log import records


def _threads() -> int:
    return sum(t.name == "kosmap-read-ahead" for t in threading.enumerate())


def test_same_items_in_order_across_batches():
    src = list(range(10_000))
    assert list(read_ahead(iter(src), size=lambda x: 7, batch=100, depth=2)) == src
    assert list(read_ahead(iter([]))) == []
    assert _threads() == 0


def test_an_error_comes_after_the_items_before_it():
    def gen():
        yield from range(5)
        raise ValueError("damaged at 5")

    got = []
    with pytest.raises(ValueError, match="damaged at 5"):
        for x in read_ahead(gen(), batch=2):
            got.append(x)
    assert got == [0, 1, 2, 3, 4]
    assert _threads() == 0


def test_closing_early_stops_the_thread_and_closes_the_source():
    closed = []

    def endless():
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.append(True)

    g = read_ahead(endless(), batch=10, depth=2)
    assert [next(g) for _ in range(25)] == list(range(25))
    g.close()
    assert closed == [True]  # closed on the thread that ran it, before close() returned
    assert _threads() == 0


def test_the_source_runs_ahead_of_a_slow_reader_but_no_further_than_the_queue():
    made = []

    def src():
        for i in range(40):
            made.append(i)
            yield i

    g = read_ahead(src(), batch=1, depth=8)
    assert next(g) == 0
    deadline = time.monotonic() + 30.0
    while len(made) < 9 and time.monotonic() < deadline:  # made while this reader waits (generous: a loaded machine)
        time.sleep(0.01)
    time.sleep(0.2)
    # the item read, the 8 queued and the one the thread holds waiting for room: ahead, and bounded
    assert 9 <= len(made) <= 10
    assert list(g) == list(range(1, 40))


def test_mcap_read_matches_and_closing_the_log_mid_read_leaves_no_thread(tmp_path):
    recs = records(n=30, width=64, height=48)
    p = tmp_path / "log.mcap"
    with McapWriter(p, chunk_size=16 << 10) as w:
        for r in recs:
            w.write(r)
    with open_log(p) as log:
        got = list(log.read())
    assert [(r.topic, r.stamp_ns) for r in got] == [(r.topic, r.stamp_ns) for r in recs]
    log = open_log(p)
    it = log.read()
    next(it)  # a read abandoned half-way (an exception in the caller's loop) ...
    log.close()  # ... is stopped when the log closes, before its file does
    assert _threads() == 0


def test_two_reads_of_one_log_at_once(tmp_path):
    recs = records(n=100, width=256, height=192)  # ~30 MB: more than the read-ahead holds
    p = tmp_path / "log.mcap"
    with McapWriter(p, chunk_size=256 << 10) as w:
        for r in recs:
            w.write(r)
    with open_log(p) as log:  # two reads taken in turn, both threads reading ahead: each seeks its own handle
        a, b = log.read(), log.read()
        got_a, got_b = [], []
        for ra, rb in zip(a, b):
            got_a.append((ra.topic, ra.stamp_ns))
            got_b.append((rb.topic, rb.stamp_ns))
    want = [(r.topic, r.stamp_ns) for r in recs]
    assert got_a == want and got_b == want
    assert _threads() == 0


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_damage_is_a_log_error_or_a_warning(tmp_path, compression):
    p = tmp_path / "log.mcap"
    with McapWriter(p, compression=compression, chunk_size=16 << 10) as w:
        for r in records(n=30, width=64, height=48):
            w.write(r)
    data = bytearray(p.read_bytes())
    errors, warned, skipped = set(), 0, 0
    for k in range(2, 38):  # bytes overwritten across the file: each read ends normally or with a LogError
        d = bytearray(data)
        at = len(d) * k // 40
        d[at:at + 64] = bytes(range(64))
        q = tmp_path / f"d{k}.mcap"
        q.write_bytes(d)
        try:
            with open_log(q) as log:
                list(log.read())
                warned += any("does not decode" in w for w in log.warnings)  # a message's bytes: it is skipped
                skipped += any("is damaged" in w and "skipped" in w for w in log.warnings)  # a chunk: skipped
        except LogError as e:  # the file's structure
            errors.add(str(e).split("(")[0])
    # the chunks' CRCs (McapWriter writes them) catch overwritten bytes in any chunk, compressed or not: the chunk is
    # skipped with a warning and the rest read; only damage outside the chunks can end a read, with a LogError
    assert skipped >= 30, (skipped, warned, errors)  # (36 of 36 land in chunks of this file)
    assert all("damaged" in e or "truncated" in e for e in errors), errors
    assert _threads() == 0


@pytest.mark.parametrize("late_s", [0.4, 5.0])
def test_mcap_order_is_log_time_order_when_written_out_of_order(tmp_path, late_s):
    from mcap.reader import make_reader

    from kosmap.frontend.logs import convert

    rng = np.random.default_rng(3)
    recs = records(n=60, width=32, height=24)
    ts = convert.typestore(2)
    t0 = recs[0].stamp_ns
    # log times out of order: every fifth message late by up to late_s, written where it arrived
    log_t = [t0 + i * 10_000_000 + (int(rng.uniform(0, late_s) * 1e9) if i % 5 == 3 else 0) for i in range(len(recs))]
    write_order = sorted(range(len(recs)), key=lambda i: (t0 + i * 10_000_000, i))  # the order of arrival
    p = tmp_path / "late.mcap"
    with McapWriter(p, chunk_size=8 << 10) as w:
        for i in write_order:
            mt, msg = convert.record_msg(ts, recs[i])
            w.write_msg(recs[i].topic, mt, msg, log_t[i])
    with open(p, "rb") as fh:
        summary = make_reader(fh).get_summary()
        assert len(summary.chunk_indexes) > 10
        expect = [(c.topic, m.log_time) for _, c, m in make_reader(fh).iter_messages(log_time_order=True)]
    assert expect != [(recs[i].topic, log_t[i]) for i in write_order]  # the file is out of order
    assert [t for _, t in expect] == sorted(log_t)
    by_stamp = {(r.topic, r.stamp_ns): log_t[i] for i, r in enumerate(recs)}
    with open_log(p) as log:
        got = [(r.topic, by_stamp[(r.topic, r.stamp_ns)]) for r in log.read()]
    assert got == expect


@pytest.mark.parametrize("topics,compression", [(None, "ZSTD"), (["/scan"], "ZSTD"), (["/odom", "/scan"], "ZSTD"),
                                                (["/nothing"], "ZSTD"), (None, "LZ4"), (["/odom", "/scan"], "NONE")])
def test_log_time_order_equals_mcaps(tmp_path, topics, compression):
    """frontend/logs/mcap.py's own chunk reading and ordering of an indexed MCAP is mcap's
    iter_messages(log_time_order=True) message for message, bytes for bytes: out-of-order chunks, equal log times
    across and within chunks (ties by chunk, then position), messages large enough to come as views (a depth
    image), zstd, lz4 and uncompressed chunks."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    from kosmap.frontend.logs.mcap import _in_log_time_order

    rng = np.random.default_rng(8)
    p = tmp_path / "ties.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=2048, compression=getattr(CompressionType, compression))
        w.start()
        sid = w.register_schema("x", "raw", b"")
        chans = [w.register_channel(t, "raw", sid) for t in ("/scan", "/odom", "/imu")]
        for i in range(600):
            t = 1_000 + 10 * (i // 3) + (int(rng.integers(-40, 40)) if i % 7 == 0 else 0)  # triples share a time
            n = 70_000 + i if i % 50 == 1 else int(rng.integers(1, 200))
            w.add_message(chans[i % 3], log_time=t, data=rng.bytes(n), publish_time=t, sequence=i)
        w.finish()
    with open(p, "rb") as fh:
        summary = make_reader(fh).get_summary()
        assert len(summary.chunk_indexes) > 20
        expect = [(c.id, m.log_time, m.sequence, m.data) for _, c, m in
                  make_reader(fh).iter_messages(topics=topics, log_time_order=True)]
        got = [(c.id, m.log_time, m.sequence, bytes(m.data)) for _, c, m in _in_log_time_order(fh, summary, topics)]
    assert got == expect
    assert len(got) == (600 if topics is None else 200 * sum(t in ("/scan", "/odom", "/imu") for t in topics))


def test_a_chunk_that_does_not_parse_is_an_mcap_error():
    """frontend/logs/mcap.py _chunk_messages: an unknown compression, a damaged lz4 frame, a zstd frame whose size
    disagrees with the chunk header, a record running past the chunk and a channel the summary lacks are McapError
    (the reader's 'damaged inside' LogError), never a traceback of another kind or a huge allocation."""
    import struct

    import lz4.frame
    import zstandard
    from mcap.exceptions import McapError

    from kosmap.frontend.logs.mcap import _chunk_messages

    def chunk(records: bytes, compression: str = "", packed: bytes | None = None, size: int | None = None) -> bytes:
        body = records if packed is None else packed
        c = compression.encode()
        payload = struct.pack("<QQQII", 0, 0, len(records) if size is None else size, 0, len(c)) + c + \
            struct.pack("<Q", len(body)) + body
        return struct.pack("<BQ", 0x06, len(payload)) + payload

    def message(cid: int, data: bytes) -> bytes:
        return struct.pack("<BQHIQQ", 0x05, 22 + len(data), cid, 0, 5, 5) + data

    chans, take, unz = {1: object()}, {1: None}, zstandard.ZstdDecompressor()
    recs = message(1, b"abc") + message(1, b"x" * 70_000)
    ok = [(i, bytes(m.data)) for i, m in _chunk_messages(chunk(recs), chans, take, unz)]
    assert ok == [(0, b"abc"), (1, b"x" * 70_000)]
    for c, packed in (("zstd", zstandard.ZstdCompressor().compress(recs)), ("lz4", lz4.frame.compress(recs))):
        assert [(i, bytes(m.data)) for i, m in _chunk_messages(chunk(recs, c, packed), chans, take, unz)] == ok
    bad = [chunk(recs, "bz2", b"whatever"), chunk(recs, "lz4", b"\x04\x22\x4d\x18garbage"),
           chunk(recs, "zstd", zstandard.ZstdCompressor().compress(recs), size=len(recs) + 1),
           chunk(recs[:-10]), chunk(message(7, b"abc"))]
    for b in bad:
        with pytest.raises(McapError):
            list(_chunk_messages(b, chans, take, unz))
