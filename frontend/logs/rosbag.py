"""ROS 1 bag adapter: rosbags reads the index and decodes; a linear chunk scan is the fallback.

The fallback serves bags whose index is missing (recording cut off) or non-standard (rosbags asserts on
the CCNY scan_tools demo bag): it walks the records in file order (bag format 2.0) and yields
what it can decode, stopping with a warning at damage. A bag whose data ends early (cut inside a record, or
before the index its header points to) is truncated: a warning says how much was read, and a LogError says so
when not one message could be.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from rosbags.rosbag1 import Reader
from rosbags.typesys import get_types_from_msg

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs.base import LogInfo, LogReader, TopicInfo, normalize_type, reorder
from kosmap.frontend.logs.convert import to_record, typestore

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


def _record_at(data, pos: int) -> tuple[dict, bytes, int]:
    """(header fields, data, next position) of the record at `pos`; EOFError when it is cut off."""
    (hl,) = struct.unpack_from("<I", data, pos)
    if pos + 8 + hl > len(data):
        raise EOFError("record header cut off")
    hdr = _fields(data[pos + 4:pos + 4 + hl])
    (dl,) = struct.unpack_from("<I", data, pos + 4 + hl)
    start = pos + 8 + hl
    if start + dl > len(data) or "op" not in hdr:
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
    """Damage the linear read met (a chunk that does not decompress, a message without its connection), in words."""


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

    # -- linear fallback -------------------------------------------------------------------------------------------
    def _scan(self, topics: set[str] | None) -> Iterator[tuple[int, str, str, bytes]]:
        """(time ns, topic, msgtype, raw) in file order, without the index. A cut or damaged file sets `truncated`
        and warns with what was read; LogError when not one message could be."""
        with open(self.path, "rb") as fh:
            data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)  # paged in as read: memory stays flat
        conns: dict[int, tuple[str, str]] = {}
        walk = _Walk()
        n = total = chunks = last = 0
        pos, op = len(_MAGIC), 0
        try:
            for pos, hdr, body in _top_records(data, len(_MAGIC), walk):
                op = hdr.get("op", b"\0")[0]
                if op == _OP_HEADER:
                    self._index_pos = struct.unpack("<Q", hdr["index_pos"])[0]
                    continue
                if op == _OP_CHUNK:
                    chunks += 1
                    inner = _records(self._decompress(hdr, body, pos))
                else:
                    inner = iter([(hdr, body)])
                for h, b in inner:
                    o = h.get("op", b"\0")[0]
                    if o == _OP_CONN:
                        cid = struct.unpack("<I", h["conn"])[0]
                        f = _fields(b)
                        msgtype = normalize_type(f["type"].decode())
                        conns[cid] = (h["topic"].decode(), msgtype)
                        self._register(msgtype, f.get("message_definition", b"").decode())
                    elif o == _OP_MSG:
                        cid = struct.unpack("<I", h["conn"])[0]
                        sec, nsec = struct.unpack("<II", h["time"])
                        if cid not in conns:
                            raise _Damage(f"a message at byte {pos} is on connection {cid}, which no record defines")
                        topic, msgtype = conns[cid]
                        total += 1
                        if topics is None or topic in topics:
                            n += 1
                            last = max(last, sec * 1_000_000_000 + nsec)
                            yield sec * 1_000_000_000 + nsec, topic, msgtype, b
        except (_Damage, EOFError, KeyError, struct.error, ValueError) as e:
            where = "a record inside the chunk" if op == _OP_CHUNK else "the record"
            detail = str(e) if isinstance(e, _Damage) else f"{where} at byte {pos} is cut off or garbled"
            self._stopped("damaged", detail, n, total, last)
            return
        cut = _cut(len(data), self._index_pos, walk.stopped_at, chunks)
        if cut is not None:
            self._stopped("truncated", cut, n, total, last)

    def _decompress(self, hdr: dict, body: bytes, pos: int) -> bytes:
        """A chunk's records; _Damage when they do not decompress."""
        comp = hdr.get("compression", b"none").decode(errors="replace")
        try:
            if comp == "bz2":
                return bz2.decompress(body)
            if comp == "lz4":
                import lz4.frame

                return lz4.frame.decompress(body)
        except (OSError, ValueError, RuntimeError, EOFError) as e:  # (lz4 raises RuntimeError)
            raise _Damage(f"the {comp} chunk at byte {pos} does not decompress ({e})") from e
        if comp != "none":
            raise LogError(f"{self.path.name} uses chunk compression '{comp}', which kosmap cannot read")
        return body

    def _stopped(self, kind: str, detail: str, n: int, total: int, last_ns: int) -> None:
        """Mark a read that ended early ("truncated" or "damaged"): LogError when the file gave no message at all,
        else one warning saying how much was read."""
        self.truncated = True
        if not total:
            raise LogError(f"{self.path.name} is {kind}: {detail}, so no message can be read; re-copy or re-record it")
        if not self._cut_said:
            self._cut_said = True
            where = "the cut" if kind == "truncated" else "the damage"
            self._warn(f"{self.path.name} is {kind} ({detail}): read {n} messages up to t={last_ns * 1e-9:.3f} s "
                       f"before {where}; re-copy or re-record it to get the rest")

    def _raw(self, topics: Iterable[str] | None) -> Iterator[tuple[int, str, str, bytes]]:
        if self._reader is not None:
            conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
            for c, t, raw in self._reader.messages(connections=conns):
                yield t, c.topic, c.msgtype, raw
            return
        wanted = None if topics is None else set(topics)
        items = ((t, i, (topic, mt, raw)) for i, (t, topic, mt, raw) in enumerate(self._scan(wanted)))
        for topic, mt, raw in reorder(items, window_ns=2_000_000_000):
            yield 0, topic, mt, raw

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
        for _, topic, msgtype, raw in self._raw(topics):
            if msgtype not in self._ts.fielddefs:
                continue
            rec = self._usable(to_record(self._ts.deserialize_ros1(raw, msgtype), msgtype, topic))
            if rec is not None:
                yield rec
