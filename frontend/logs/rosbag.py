"""ROS 1 bag adapter: rosbags reads the index and decodes; chunks are read here; a linear chunk scan is the fallback.

The indexed read takes rosbags' parsed index (connections, chunk infos, per-connection entries) and reads each
chunk itself, so that a chunk that does not decompress is skipped with a warning giving its time range instead of
ending the read (rosbags' `messages` raises at the first). The fallback serves bags whose index is missing
(recording cut off) or non-standard (rosbags asserts on the CCNY scan_tools demo bag): it walks the records in
file order (bag format 2.0), skipping damaged chunks the same way. A bag whose data ends early (cut inside a
record, or before the index its header points to) is truncated: a warning says how much was read (the whole
messages of an uncompressed chunk cut by the file's end included), and a LogError says so when not one message
could be. Chunks decompress within their stated size (frontend/logs/inflate.py).
"""

from __future__ import annotations

import heapq
import mmap
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from rosbags.rosbag1 import Reader
from rosbags.serde import SerdeError
from rosbags.typesys import get_types_from_msg

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs.base import LogInfo, LogReader, TopicInfo, normalize_type, reorder
from kosmap.frontend.logs.convert import to_record, typestore
from kosmap.frontend.logs.inflate import ChunkDamage, inflate

_MAGIC = b"#ROSBAG V2.0\n"
_OP_MSG, _OP_HEADER, _OP_CHUNK, _OP_CONN = 0x02, 0x03, 0x05, 0x07


def _fields(buf: bytes) -> dict[str, bytes]:
    out, i = {}, 0
    while i + 4 <= len(buf):
        (n,) = struct.unpack_from("<I", buf, i)
        i += 4
        key, _, val = buf[i:i + n].partition(b"=")
        out[key.decode(errors="replace")] = val
        i += n
    return out


class _CutChunk(EOFError):
    """An uncompressed chunk record whose data the file's end cuts off: `body` is the part that is there."""

    def __init__(self, hdr: dict, body) -> None:
        super().__init__("chunk data cut off")
        self.hdr, self.body = hdr, body


def _record_at(data, pos: int) -> tuple[dict, bytes, int]:
    """(header fields, data, next position) of the record at `pos`; EOFError when it is cut off (_CutChunk for an
    uncompressed chunk that the file's end cuts: its whole messages can still be read)."""
    (hl,) = struct.unpack_from("<I", data, pos)
    if pos + 8 + hl > len(data):
        raise EOFError("record header cut off")
    hdr = _fields(data[pos + 4:pos + 4 + hl])
    (dl,) = struct.unpack_from("<I", data, pos + 4 + hl)
    start = pos + 8 + hl
    if "op" not in hdr:
        raise EOFError("record data cut off")
    if start + dl > len(data):
        if hdr["op"] == bytes([_OP_CHUNK]) and hdr.get("compression") == b"none":
            raise _CutChunk(hdr, data[start:])
        raise EOFError("record data cut off")
    return hdr, data[start:start + dl], start + dl


def _records(data, pos: int = 0) -> Iterator[tuple[dict, bytes]]:
    """(header fields, data) of each record in a buffer; EOFError at the first incomplete record."""
    while pos + 4 <= len(data):
        hdr, body, pos = _record_at(data, pos)
        yield hdr, body


def _next_chunk(data, pos: int) -> int | None:
    """Position of the next chunk record after `pos`, found by its `op=\\x05` header field."""
    while (hit := data.find(b"op=\x05", pos)) >= 0:
        for q in range(hit - 8, max(hit - 512, pos) - 1, -1):
            try:
                hdr, _, _ = _record_at(data, q)
            except (EOFError, struct.error):
                continue
            if hdr.get("op") == b"\x05" and "compression" in hdr:
                return q
        pos = hit + 1
    return None


@dataclass
class _Walk:
    """What a linear walk met: records it stepped over, and the record it stopped at (cut off or unreadable)."""

    skipped: list[int] = field(default_factory=list)
    stopped_at: int | None = None  # None: it reached the file's end at a record boundary


def _top_records(data, pos: int, walk: _Walk) -> Iterator[tuple[int, dict, bytes]]:
    """(position, header fields, data) of the top-level records. A record whose length fields are wrong (a
    non-standard index) is stepped over by resuming at the next chunk record after the last good record's start."""
    last = pos
    while pos + 4 <= len(data):
        try:
            hdr, body, nxt = _record_at(data, pos)
        except _CutChunk as cut:  # the file ends inside an uncompressed chunk: its whole records are read
            walk.stopped_at = pos
            yield pos, cut.hdr, cut.body
            return
        except (EOFError, struct.error):
            nxt = _next_chunk(data, last + 1)
            if nxt is None or nxt <= last:
                walk.stopped_at = pos
                return
            walk.skipped.append(pos)
            pos = last = nxt
            continue
        yield pos, hdr, body
        last, pos = pos, nxt
    if pos < len(data):  # a few bytes of a record's length field
        walk.stopped_at = pos


def _cut(size: int, index_pos: int | None, stopped_at: int | None, chunks: int) -> str | None:
    """Where a bag's data ends early, in words; None when it is whole. A walk that stops inside the index (after
    all the data, e.g. the demo bag's non-standard one) is no cut: every message before it was read."""
    if index_pos is None:  # (a garbled header before readable chunks is no cut)
        where = "inside" if stopped_at is not None else "before"
        return None if chunks else f"it ends after {size} bytes, {where} its header record"
    if stopped_at is not None and (index_pos == 0 or stopped_at < index_pos):
        where = f"the record at byte {stopped_at}" if chunks else "its first chunk"
        return f"it ends after {size} bytes, inside {where}"
    if index_pos > size:
        return f"it ends after {size} bytes, before its index at byte {index_pos}"
    return None


def _index_trouble(err: Exception, size: int, index_pos: int | None) -> str:
    """Why rosbags could not read the index, for a user: what the linear walk learnt, else rosbags' own text when
    it has any (an AssertionError has none)."""
    if index_pos == 0:
        return "the bag has no index: its recording was not closed; `rosbag reindex` adds one if its data is whole"
    if index_pos is not None and index_pos > size:
        return f"the file ends before its index at byte {index_pos}"
    text = str(err).strip()
    inner = err.__context__  # rosbags wraps its first error in "Bag index looks damaged: (args,)"
    if inner is not None and str(inner) and text.startswith("Bag index looks damaged"):
        text = f"it looks damaged: {str(inner).strip()}"
    return text.rstrip(".") or "it is not laid out as rosbags expects"


class _Damage(Exception):
    """A chunk or record that cannot be read (does not decompress, is not what the index says), in words."""


_CHUNK_WARNINGS = 5  # damaged chunks warned one by one; past these, one warning counts them


@dataclass
class _Tally:
    """What a linear read has yielded: chunks met, messages in all and of the wanted topics, the last one's time."""

    chunks: int = 0
    total: int = 0
    n: int = 0
    last: int = 0


class _Inner:
    """A chunk's (header fields, data) records up to the first that does not parse; `garbled` says why it stopped
    early (None: the chunk's data ended at a record boundary)."""

    def __init__(self, buf) -> None:
        self.buf, self.garbled = buf, None

    def __iter__(self) -> Iterator[tuple[dict, bytes]]:
        try:
            yield from _records(self.buf)
        except (EOFError, struct.error) as e:
            self.garbled = str(e) or type(e).__name__


def _message_at(buf, offset: int) -> tuple[int, int, bytes]:
    """(time ns, connection id, data) of the message record at `offset` of a chunk's records, stepping over
    connection records before it (as rosbags' `messages` does)."""
    while True:
        hdr, body, offset = _record_at(buf, offset)
        op = hdr["op"][:1]
        if op == bytes([_OP_MSG]):
            sec, nsec = struct.unpack("<II", hdr["time"])
            return sec * 1_000_000_000 + nsec, struct.unpack("<I", hdr["conn"])[0], body
        if op != bytes([_OP_CONN]):
            raise _Damage("the index points at a record that is not a message")


class Ros1Bag(LogReader):
    format = "ROS 1 bag"

    def __init__(self, path) -> None:
        super().__init__(path)
        self._ts = typestore(1)
        self._reader = None
        self.truncated = False
        self._index_error: Exception | None = None
        self._index_pos: int | None = None  # from the bag header, once the linear read has seen it
        self._cut_said = False  # the truncation warning is given once, by the first read
        self._bad_chunk_at: set[int] = set()  # chunks skipped as damaged (do not decompress, not where the index says)
        self._bad_record_at: set[str] = set()  # records inside chunks skipped as garbled
        self._hits = 0  # damage met by all reads (one read that meets any and yields nothing is an error)
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as e:  # noqa: BLE001 - rosbags raises assorted errors on damaged or odd indices
            self._reader = None
            self._index_error = e
        if self._reader is not None:
            for c in self._reader.connections:
                self._register(c.msgtype, c.msgdef.data)

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()

    def _register(self, msgtype: str, msgdef: str) -> None:
        if msgtype not in self._ts.fielddefs:
            try:
                self._ts.register(get_types_from_msg(msgdef, msgtype))
            except Exception:  # noqa: BLE001 - an unparsable definition: that type is skipped
                pass

    # -- damage ----------------------------------------------------------------------------------------------------
    @property
    def _bad_chunks(self) -> int:
        return len(self._bad_chunk_at)

    def _damaged_chunk(self, pos: int, span: tuple[int, int] | None, detail: str) -> None:
        """A chunk that is skipped: one warning each (with its time range where the index gives it) for the first
        few, then one that counts them."""
        self._hits += 1
        self.truncated = True  # (the summary's flag: what was read is not the whole log)
        when = f"messages from t={span[0] * 1e-9:.3f} s to t={span[1] * 1e-9:.3f} s" if span else "its messages"
        if self.on_damage == "fail":  # ("read": a bag's chunk has no CRC of its own, so damage is what cannot be read)
            raise LogError(f"{self.path.name}: the chunk at byte {pos} ({when}) is damaged ({detail}); "
                           f"--set topics.on_damage=skip maps without it")
        if pos in self._bad_chunk_at:  # (met again by another read: warned and counted once)
            return
        self._bad_chunk_at.add(pos)
        if self._bad_chunks <= _CHUNK_WARNINGS:
            self._warn(f"{self.path.name}: the chunk at byte {pos} is damaged ({detail}); {when} are skipped and the "
                       f"rest is read: re-copy the bag, or check it with `rosbag check`")
        else:
            self.warnings[:] = [w for w in self.warnings if not w.startswith(f"{self.path.name}: in all, ")]
            self._warn(f"{self.path.name}: in all, {self._bad_chunks} damaged chunks were skipped")

    def _damaged_record(self, where: str) -> None:
        """A record inside a chunk that does not parse (the chunk's data is garbled there): counted, one warning."""
        self._hits += 1
        self.truncated = True
        self._bad_record_at.add(where)
        if len(self._bad_record_at) == 1:
            self._warn(f"{self.path.name}: {where} is garbled; such records are skipped (the bag is damaged there: "
                       f"re-copy it, or check it with `rosbag check`)")

    def _nothing_left(self) -> None:
        """LogError when damage left not one message of the wanted topics."""
        raise LogError(f"{self.path.name} is damaged: {self._bad_chunks} chunk(s) and {len(self._bad_record_at)} "
                       f"record(s) are unreadable and no message of the wanted topics is left; re-copy or re-record it")

    # -- indexed read ------------------------------------------------------------------------------------------------
    def _indexed(self, topics) -> Iterator[tuple[int, str, str, bytes]]:
        """(time ns, topic, msgtype, raw) in time order from rosbags' parsed index (its `indexes`, `chunk_infos`);
        each chunk is read here rather than by rosbags' `messages`, which raises at the first damaged chunk and
        ends the read: a chunk that does not decompress is skipped with a warning giving its time range."""
        r = self._reader
        with open(self.path, "rb") as fh:
            data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        connmap = {c.id: c for c in r.connections}
        spans = {ci.pos: (ci.start_time, ci.end_time) for ci in r.chunk_infos}
        conns = [c for c in r.connections if topics is None or c.topic in topics]
        current, buf, bad, n, hits = None, b"", set(), 0, self._hits
        for e in heapq.merge(*(r.indexes[c.id] for c in conns)):
            if e.chunk_pos in bad:
                continue
            if e.chunk_pos != current:
                try:
                    buf = self._chunk_at(data, e.chunk_pos)
                except _Damage as err:
                    bad.add(e.chunk_pos)
                    self._damaged_chunk(e.chunk_pos, spans.get(e.chunk_pos), str(err))
                    continue
                current = e.chunk_pos
            try:
                t, cid, raw = _message_at(buf, e.offset)
            except (_Damage, EOFError, KeyError, struct.error) as err:
                self._damaged_record(f"the message record at offset {e.offset} of the chunk at byte {e.chunk_pos} "
                                     f"({err or type(err).__name__})")
                continue
            c = connmap.get(cid)
            if c is None or t != e.time:
                self._damaged_record(f"the message record at offset {e.offset} of the chunk at byte {e.chunk_pos} "
                                     f"(its connection or time disagrees with the index)")
                continue
            n += 1
            yield t, c.topic, c.msgtype, raw
        if not n and self._hits > hits:
            self._nothing_left()

    def _chunk_at(self, data, pos: int) -> bytes:
        """The records of the chunk record at `pos`; _Damage when it is not one or does not decompress."""
        try:
            hdr, body, _ = _record_at(data, pos)
        except (EOFError, struct.error) as e:
            raise _Damage(f"its record is cut off or garbled ({e})") from e
        if hdr.get("op") != bytes([_OP_CHUNK]):
            raise _Damage("the index points at a record that is not a chunk")
        return self._decompress(hdr, body)

    # -- linear fallback ---------------------------------------------------------------------------------------------
    def _scan(self, topics: set[str] | None) -> Iterator[tuple[int, str, str, bytes]]:
        """(time ns, topic, msgtype, raw) in file order, without the index. A damaged chunk or record is skipped with
        a warning; a cut file sets `truncated` and warns with what was read; LogError when not one message could be."""
        with open(self.path, "rb") as fh:
            data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)  # paged in as read: memory stays flat
        conns: dict[int, tuple[str, str]] = {}
        walk = _Walk()
        st = _Tally()
        hits = self._hits
        for pos, hdr, body in _top_records(data, len(_MAGIC), walk):
            op = hdr.get("op", b"\0")[:1]
            if op == bytes([_OP_HEADER]):
                try:
                    self._index_pos = struct.unpack("<Q", hdr["index_pos"])[0]
                except (KeyError, struct.error):
                    self._damaged_record(f"the bag header at byte {pos}")
                continue
            if op != bytes([_OP_CHUNK]):
                yield from self._inner([(hdr, body)], pos, conns, topics, st)
                continue
            st.chunks += 1
            try:
                buf = self._decompress(hdr, body)
            except _Damage as e:
                self._damaged_chunk(pos, None, str(e))
                continue
            inner = _Inner(buf)
            yield from self._inner(inner, pos, conns, topics, st)
            if inner.garbled is not None and walk.stopped_at != pos:  # (in a cut chunk, the cut: said below)
                self._damaged_record(f"a record inside the chunk at byte {pos} ({inner.garbled})")
        if not st.total and self._hits > hits:
            self._nothing_left()
        cut = _cut(len(data), self._index_pos, walk.stopped_at, st.chunks)
        if cut is not None:
            self._stopped("truncated", cut, st.n, st.total, st.last)

    def _inner(self, records, pos: int, conns: dict, topics, st: _Tally) -> Iterator[tuple[int, str, str, bytes]]:
        """The messages among a chunk's (or top-level) connection and message records; garbled ones skipped."""
        for h, b in records:
            o = h.get("op", b"\0")[:1]
            try:
                if o == bytes([_OP_CONN]):
                    cid = struct.unpack("<I", h["conn"])[0]
                    f = _fields(b)
                    msgtype = normalize_type(f["type"].decode())
                    conns[cid] = (h["topic"].decode(), msgtype)
                    self._register(msgtype, f.get("message_definition", b"").decode(errors="replace"))
                    continue
                if o != bytes([_OP_MSG]):
                    continue
                cid = struct.unpack("<I", h["conn"])[0]
                sec, nsec = struct.unpack("<II", h["time"])
            except (KeyError, struct.error, UnicodeDecodeError) as e:
                self._damaged_record(f"a record at or after byte {pos} ({type(e).__name__}: {e})")
                continue
            if cid not in conns:
                self._damaged_record(f"a message at or after byte {pos} on connection {cid}, which no record defines,")
                continue
            topic, msgtype = conns[cid]
            st.total += 1
            if topics is None or topic in topics:
                st.n += 1
                st.last = max(st.last, sec * 1_000_000_000 + nsec)
                yield sec * 1_000_000_000 + nsec, topic, msgtype, b

    def _decompress(self, hdr: dict, body) -> bytes:
        """A chunk's records, decompressed within its stated size (frontend/logs/inflate.py); _Damage when they do
        not decompress."""
        comp = hdr.get("compression", b"none").decode(errors="replace")
        if comp not in ("none", "bz2", "lz4"):
            raise _Damage(f"its compression '{comp}' is not one a ROS 1 bag uses")
        size = hdr.get("size")
        try:
            return inflate(comp, body, struct.unpack("<I", size)[0] if size is not None and len(size) == 4 else None)
        except ChunkDamage as e:
            raise _Damage(str(e)) from e

    def _stopped(self, kind: str, detail: str, n: int, total: int, last_ns: int) -> None:
        """Mark a read that ended early ("truncated"): LogError when the file gave no message at all, else one
        warning saying how much was read."""
        self.truncated = True
        if not total:
            raise LogError(f"{self.path.name} is {kind}: {detail}, so no message can be read; re-copy or re-record it")
        if not self._cut_said:
            self._cut_said = True
            self._warn(f"{self.path.name} is {kind} ({detail}): read {n} messages up to t={last_ns * 1e-9:.3f} s "
                       f"before the cut; re-copy or re-record it to get the rest")

    def _raw(self, topics: Iterable[str] | None) -> Iterator[tuple[int, str, str, bytes]]:
        if self._reader is not None:
            yield from self._indexed(topics)
            return
        wanted = None if topics is None else set(topics)
        items = ((item[0], i, item) for i, item in enumerate(self._scan(wanted)))
        yield from reorder(items, window_ns=2_000_000_000)

    # -- interface -------------------------------------------------------------------------------------------------
    def info(self) -> LogInfo:
        if self._reader is not None:
            r = self._reader
            by_topic: dict[str, TopicInfo] = {}
            for c in r.connections:
                ti = by_topic.setdefault(c.topic, TopicInfo(c.topic, c.msgtype, 0))
                ti.count += c.msgcount
            return LogInfo(self.path, self.format, r.start_time, r.end_time, list(by_topic.values()))
        counts: dict[str, TopicInfo] = {}
        start = end = None
        for t, topic, mt, _ in self._scan(None):
            counts.setdefault(topic, TopicInfo(topic, mt, 0)).count += 1
            start = t if start is None else min(start, t)
            end = t if end is None else max(end, t)
        why = _index_trouble(self._index_error, self.path.stat().st_size, self._index_pos)
        notes = [f"the bag's index could not be read ({why}); read it from start to end instead"]
        if self.truncated:
            notes.append("truncated: counts are of the messages before the damage")
        return LogInfo(self.path, self.format, start or 0, end or 0, list(counts.values()), self.truncated, notes)

    def read(self, topics: Iterable[str] | None = None) -> Iterator:
        for t, topic, msgtype, raw in self._raw(topics):
            if msgtype not in self._ts.fielddefs:
                continue
            try:
                msg = self._ts.deserialize_ros1(raw, msgtype)
            except (SerdeError, struct.error, IndexError, ValueError, UnicodeDecodeError) as e:
                self._undecodable(topic, t, e)
                continue
            rec = self._usable(to_record(msg, msgtype, topic))
            if rec is not None:
                yield rec
