"""ROS 1 bag adapter: rosbags reads the index and decodes; a linear chunk scan is the fallback.

The fallback serves bags whose index is missing (recording cut off) or non-standard (rosbags asserts on
the CCNY scan_tools demo bag): it walks the records in file order (bag format 2.0) and yields
what it can decode, stopping with a warning at damage.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from collections.abc import Iterable, Iterator

from rosbags.rosbag1 import Reader
from rosbags.typesys import get_types_from_msg

from frontend.errors import LogError
from frontend.logs.base import LogInfo, LogReader, TopicInfo, normalize_type, reorder
from frontend.logs.convert import to_record, typestore

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


def _top_records(data, pos: int, skipped: list[int]) -> Iterator[tuple[dict, bytes]]:
    """Top-level records. A record whose length fields are wrong (a non-standard index) is stepped over by
    resuming at the next chunk record after the last good record's start."""
    last = pos
    while pos + 4 <= len(data):
        try:
            hdr, body, nxt = _record_at(data, pos)
        except (EOFError, struct.error):
            nxt = _next_chunk(data, last + 1)
            if nxt is None or nxt <= last:
                return
            skipped.append(pos)
            pos = last = nxt
            continue
        yield hdr, body
        last, pos = pos, nxt


class Ros1Bag(LogReader):
    format = "ROS 1 bag"

    def __init__(self, path) -> None:
        super().__init__(path)
        self._ts = typestore(1)
        self._reader = None
        self.truncated = False
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as e:  # noqa: BLE001 - rosbags raises assorted errors on damaged or odd indices
            self._reader = None
            self._why = f"{type(e).__name__}: {e}".strip(": ")
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
        """(time ns, topic, msgtype, raw) in file order, without the index."""
        with open(self.path, "rb") as fh:
            data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)  # paged in as read: memory stays flat
        conns: dict[int, tuple[str, str]] = {}
        skipped: list[int] = []
        n = 0
        try:
            for hdr, body in _top_records(data, len(_MAGIC), skipped):
                op = hdr.get("op", b"\0")[0]
                if op == _OP_CHUNK:
                    comp = hdr.get("compression", b"none").decode()
                    if comp == "bz2":
                        body = bz2.decompress(body)
                    elif comp == "lz4":
                        import lz4.frame

                        body = lz4.frame.decompress(body)
                    elif comp != "none":
                        raise LogError(f"{self.path.name} uses chunk compression '{comp}', which kosmap cannot read")
                    inner = _records(body)
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
                        topic, msgtype = conns[cid]
                        if topics is None or topic in topics:
                            n += 1
                            yield sec * 1_000_000_000 + nsec, topic, msgtype, b
        except (EOFError, KeyError, struct.error, OSError, ValueError) as e:
            self.truncated = True
            self._warn(f"{self.path.name} is damaged or truncated ({e}): read {n} messages before it; "
                       f"`rosbag reindex` may recover the rest")

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
        notes = [f"index unreadable ({self._why}); read linearly"]
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
