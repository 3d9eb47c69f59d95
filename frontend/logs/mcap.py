"""MCAP adapter: the `mcap` library reads the summary (and the records of an unindexed file), our `_chunk_messages`
the indexed chunks, rosbags decodes CDR (or ROS 1) messages.

mcap_ros2's own decoder walks arrays element by element in Python (~1000× slower on depth images;
docs/dependencies.md), so only the container is read with `mcap`. Every chunk is decompressed here within its stated
size (frontend/logs/inflate.py) and checked against its CRC; a damaged chunk is skipped, read or fatal as [topics]
on_damage says, with a warning giving its time range (docs/damaged_logs.md).
"""

from __future__ import annotations

import dataclasses
import heapq
import io
import os
import struct
from collections.abc import Iterable, Iterator

import zlib

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.serde import SerdeError
from rosbags.typesys import get_types_from_msg
from zstandard import ZstdError

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import topics as _T
from kosmap.frontend.logs.cdrfast import BATCH_DECODERS as _FAST_BATCH
from kosmap.frontend.logs.cdrfast import DECODERS as _FAST
from kosmap.frontend.logs.base import LogInfo, LogReader, TopicInfo, normalize_type, reorder
from kosmap.frontend.logs.convert import to_record, typestore
from kosmap.frontend.logs.inflate import ChunkDamage, inflate
from kosmap.frontend.logs.readahead import read_ahead

_CAMERA_INFO = _T.CAMERA_INFO

# what a damaged file raises inside mcap: bad lengths (OverflowError, struct.error), bad chunks (ZstdError)
_DAMAGE = (McapError, EOFError, ValueError, OSError, KeyError, IndexError, OverflowError, struct.error, ZstdError)


class McapLog(LogReader):
    format = "MCAP"

    def __init__(self, path) -> None:
        super().__init__(path)
        self._file = open(self.path, "rb")
        self._summary = None
        self.truncated = False
        self._cut_said = False  # the truncation warning is given once (other warnings may come before it)
        self._damage: Exception | None = None  # what stopped a linear read
        self._bad_chunk_at: set[tuple] = set()  # damaged chunks (CRC, decompression, records), by where and when
        self._hits = 0  # damaged chunks met by all reads (one read that meets any and yields nothing is an error)
        self._first_damage = ""
        try:
            self._summary = make_reader(_Bounded(self._file)).get_summary()
        except _DAMAGE:
            self._summary = None
        if self._summary is None or not self._summary.chunk_indexes and not self._summary.statistics:
            # No summary: the file was cut off before its footer (or written without an index); read it linearly.
            self.truncated = self._summary is None
            self._summary = None
        self._registered: set[tuple[int, str]] = set()
        self._fast: dict[int, object] = {}  # per channel: its direct decoder, or None
        self._infos: dict[str, tuple[bytes, object]] = {}  # per topic: the last CameraInfo's bytes after its stamp, its record
        self._ahead: list = []  # the read-ahead threads of open reads: stopped before the file closes

    def close(self) -> None:
        try:
            for ahead in list(self._ahead):
                ahead.close()
        finally:
            self._ahead.clear()
            self._file.close()

    # -- decoding --------------------------------------------------------------------------------------------------
    def _decode(self, schema, channel, message):
        fast = self._fast.get(channel.id, False)
        if fast is False:  # the channel's direct decoder (frontend/logs/cdrfast.py), found once: its type's checks
            # below would pass for it (a ROS 2 type rosbags knows, cdr)
            fast = self._fast[channel.id] = _FAST.get(normalize_type(schema.name)) \
                if schema is not None and channel.message_encoding == "cdr" else None
        if fast is not None:
            rec = fast(message.data, channel.topic)
            if rec is not None:
                return rec
        if schema is None:
            return None
        msgtype = normalize_type(schema.name)
        enc = channel.message_encoding
        if enc not in ("cdr", "ros1"):
            raise LogError(f"topic {channel.topic} in {self.path.name} is encoded as '{enc}'; kosmap reads ROS messages "
                           f"(cdr or ros1 encoding): convert the log with the ROS tools")
        ts = typestore(2 if enc == "cdr" else 1)
        if msgtype not in ts.fielddefs and (schema.id, enc) not in self._registered:
            try:
                ts.register(get_types_from_msg(schema.data.decode(), msgtype))
            except Exception:  # a schema rosbags cannot parse: the message type is then skipped
                pass
            self._registered.add((schema.id, enc))
        if msgtype not in ts.fielddefs:
            return None
        data = message.data
        # A CameraInfo whose bytes after the stamp equal the topic's previous one is that record again at its own
        # stamp: a driver sends the same calibration with every frame (18000 decodes of ~47 µs in 10 minutes of a
        # 30 Hz Kinect). Little-endian CDR only; the stamp follows the 4-byte encapsulation.
        info = bytes(data[12:]) if msgtype == _CAMERA_INFO and enc == "cdr" and bytes(data[:2]) == b"\x00\x01" else None
        if info is not None:
            last = self._infos.get(channel.topic)
            if last is not None and last[0] == info:
                sec, nsec = struct.unpack_from("<iI", data, 4)
                return dataclasses.replace(last[1], stamp_ns=sec * 1_000_000_000 + nsec)
        # A depth image comes as a view into its chunk (_chunk_messages): rosbags slices the CDR header off, which
        # from bytes copied the image (~2 s per 10 minutes of a 30 Hz Kinect); a view's slice does not. Its arrays view it.
        try:
            msg = ts.deserialize_cdr(data, msgtype) if enc == "cdr" else ts.deserialize_ros1(data, msgtype)
        except (SerdeError, struct.error, IndexError, ValueError) as e:
            self._undecodable(channel.topic, message.log_time, e)
            return None
        rec = to_record(msg, msgtype, channel.topic)
        if info is not None and rec is not None:
            self._infos[channel.topic] = (info, rec)
        return rec

    def _linear(self, topics) -> Iterator[tuple]:
        """Messages in file order from a stream without an index; a damaged chunk is handled as `on_damage` says,
        damage between chunks stops the read with a warning. The file is read through `_Bounded`, and chunks are
        decompressed here (`_chunk_data`), so that no length or size field allocates more than the file holds."""
        self._file.seek(0)
        n = 0
        last = 0
        wanted = None if topics is None else set(topics)
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        # mcap's own log_time_order here would load the whole file: sort with a bounded window instead.
        try:
            for record in StreamReader(_Bounded(self._file), emit_chunks=True).records:
                if isinstance(record, Chunk):
                    inner = self._linear_chunk(record)
                else:
                    inner = [record]
                for r in inner:
                    if isinstance(r, Schema):
                        schemas[r.id] = r
                    elif isinstance(r, Channel):
                        channels[r.id] = r
                    elif isinstance(r, Message):
                        ch = channels.get(r.channel_id)
                        if ch is None or (wanted is not None and ch.topic not in wanted):
                            continue
                        n += 1
                        last = max(last, r.log_time)
                        yield r.log_time, n, (schemas.get(ch.schema_id), ch, r)
        except (*_DAMAGE, RuntimeError) as e:  # (lz4 raises RuntimeError)
            self.truncated = True
            self._damage = e
        if self.truncated and not self._cut_said:
            self._cut_said = True
            self._warn(f"{self.path.name} is truncated: read {n} messages up to t={last * 1e-9:.3f} s before "
                                 f"the damage; re-record or repair it (`mcap recover`) to get the rest")

    def _linear_chunk(self, chunk: Chunk) -> list:
        """A chunk's records (mcap's breakup_chunk on the data `_chunk_data` checked), or [] when damaged and skipped."""
        def records(verify: bool) -> list:
            data = _chunk_data(chunk.compression, chunk.data, chunk.uncompressed_size,
                               chunk.uncompressed_crc if verify else 0)
            return breakup_chunk(dataclasses.replace(chunk, compression="", data=data))

        try:
            return records(True)
        except _ChunkFault as e:
            if not self._chunk_damage(None, chunk.message_start_time, chunk.message_end_time, e):
                return []
            try:
                return records(False)
            except (_ChunkFault, *_DAMAGE):
                return []
        except _DAMAGE as e:  # a record inside the chunk that does not parse
            self._chunk_damage(None, chunk.message_start_time, chunk.message_end_time, _ChunkFault(str(e), False))
            return []

    @property
    def _bad_chunks(self) -> int:
        return len(self._bad_chunk_at)

    def _nothing_left(self) -> None:
        """LogError when damaged chunks left not one message of the wanted topics."""
        raise LogError(f"{self.path.name} is damaged: {self._bad_chunks} chunk(s) are unreadable ({self._first_damage}) "
                       f"and no message of the wanted topics is left; re-copy or re-record it")

    def _chunk_damage(self, pos: int | None, start_ns: int, end_ns: int, fault: _ChunkFault) -> bool:
        """A damaged chunk, as `on_damage` says: "fail" raises LogError, else one warning with its time range each
        (the first few) and True when it is to be read as it is ("read"; a CRC mismatch only: a chunk that does not
        decompress or parse has nothing to read)."""
        self._hits += 1
        at = f" at byte {pos}" if pos is not None else ""
        span = f"messages from t={start_ns * 1e-9:.3f} s to t={end_ns * 1e-9:.3f} s"
        what = f"the chunk{at} ({span}) is damaged ({fault})"
        if not self._bad_chunk_at:
            self._first_damage = f"the first: {what[4:]}"
        if self.on_damage == "fail":
            raise LogError(f"{self.path.name}: {what}; --set topics.on_damage=skip maps without it, =read reads it "
                           f"as it is")
        read = self.on_damage == "read" and fault.crc
        if (start_ns, end_ns, str(fault)) in self._bad_chunk_at:  # (met again by another read: warned once)
            return read
        self._bad_chunk_at.add((start_ns, end_ns, str(fault)))
        if self._bad_chunks <= 5:
            self._warn(f"{self.path.name}: {what}; its messages are {'read as they are' if read else 'skipped'} "
                       f"(--set topics.on_damage=skip|read|fail): re-copy the log, or check it with `mcap doctor`")
        else:
            self.warnings[:] = [w for w in self.warnings if not w.startswith(f"{self.path.name}: in all, ")]
            self._warn(f"{self.path.name}: in all, {self._bad_chunks} damaged chunks")
        return read

    def _messages(self, topics=None, batch: bool = False) -> Iterator[tuple]:
        if self._summary is None:
            yield from reorder(self._linear(topics), window_ns=2_000_000_000)
            return
        batched = frozenset()
        if batch and _chunks_in_sequence(self._summary.chunk_indexes):  # the channels _decode_batch turns into columns
            sch = self._summary.schemas
            batched = frozenset(cid for cid, ch in self._summary.channels.items() if ch.message_encoding == "cdr"
                                and ch.schema_id in sch and normalize_type(sch[ch.schema_id].name) in _FAST_BATCH)
            topics_of = [self._summary.channels[c].topic for c in batched]
            if len(set(topics_of)) < len(topics_of):  # one topic on two channels: their batches would not interleave
                batched = frozenset()
        # Chunks are read and decompressed on a thread (frontend/logs/readahead.py): ≤ 2 queued batches of ~0.5 MB of
        # messages beside mcap's current chunk. The thread seeks, so each read has its own file handle. Not
        # log_time_order=False: mcap's file-order queue reads every chunk before the first message (all in memory).
        fh = open(self.path, "rb")
        ahead = read_ahead(_in_log_time_order(fh, self._summary, topics, batched, self._chunk_damage), size=_nbytes,
                           batch=512 << 10, depth=2)
        self._ahead.append(ahead)
        n, hits = 0, self._hits
        try:
            for item in ahead:
                n += 1
                yield item
            if not n and self._hits > hits:
                self._nothing_left()
        except _DAMAGE as e:
            raise LogError(f"{self.path.name} is damaged inside ({type(e).__name__}: {e}); run `mcap doctor` on it") from e
        finally:
            try:
                ahead.close()
            finally:
                fh.close()
                if ahead in self._ahead:
                    self._ahead.remove(ahead)

    # -- interface -------------------------------------------------------------------------------------------------
    def info(self) -> LogInfo:
        if self._summary is not None and self._summary.statistics is not None:
            st = self._summary.statistics
            counts = st.channel_message_counts
            topics = [TopicInfo(ch.topic, normalize_type(self._summary.schemas[ch.schema_id].name)
                                if ch.schema_id in self._summary.schemas else "(no schema)", counts.get(cid, 0))
                      for cid, ch in sorted(self._summary.channels.items())]
            return LogInfo(self.path, self.format, st.message_start_time, st.message_end_time, _merge(topics))
        counts: dict[str, TopicInfo] = {}
        start = end = None
        for schema, channel, message in self._messages():
            ti = counts.setdefault(channel.topic, TopicInfo(channel.topic, normalize_type(schema.name) if schema else "(no schema)", 0))
            ti.count += 1
            start = message.log_time if start is None else min(start, message.log_time)
            end = message.log_time if end is None else max(end, message.log_time)
        if (self.truncated or self._bad_chunks) and not counts:  # damage, not topic names, is why nothing is left
            if self._bad_chunks:
                self._nothing_left()
            raise LogError(_nothing_read(self._file, self.path.name, self._damage))
        notes = ["truncated: the file ends before its summary; counts are of the messages before the damage"] if self.truncated else []
        return LogInfo(self.path, self.format, start or 0, end or 0, list(counts.values()), self.truncated, notes)

    def read(self, topics: Iterable[str] | None = None) -> Iterator:
        wanted = None if topics is None else list(topics)
        for schema, channel, message in self._messages(wanted):
            rec = self._usable(self._decode(schema, channel, message))
            if rec is not None:
                yield rec

    def read_batched(self, topics: Iterable[str] | None = None) -> Iterator:
        """`read`, with each chunk's Imu and Odometry messages of a topic as one ImuSamples / OdometrySamples, in
        the place of the first of them (an indexed MCAP whose chunks follow one another in time; a chunk holds a
        fraction of a second to a few seconds of a log)."""
        wanted = None if topics is None else list(topics)
        for schema, channel, message in self._messages(wanted, batch=True):
            if isinstance(message, _Batch):
                yield from self._decode_batch(schema, channel, message)
                continue
            rec = self._usable(self._decode(schema, channel, message))
            if rec is not None:
                yield rec

    def _decode_batch(self, schema, channel, batch: _Batch) -> Iterator:
        """The batch's columns (frontend/logs/cdrfast.py), or, when its messages do not share one layout, its
        records one by one as `read` gives them."""
        rec = _FAST_BATCH[normalize_type(schema.name)]([m.data for m in batch.messages], channel.topic)
        if rec is not None:
            rec = self._usable(rec)
            if rec is not None:
                yield rec
            return
        for message in batch.messages:
            rec = self._usable(self._decode(schema, channel, message))
            if rec is not None:
                yield rec


class _Batch:
    """A chunk's messages on one channel (`_in_log_time_order` with `batched`), in log-time order."""

    __slots__ = ("messages", "nbytes")

    def __init__(self, messages: list[Message]) -> None:
        self.messages = messages
        self.nbytes = sum(len(m.data) for m in messages)  # (what read-ahead counts against its budget)


def _nbytes(item: tuple) -> int:
    """Bytes of a (schema, channel, message or _Batch) item: what read-ahead counts against its budget."""
    m = item[2]
    return m.nbytes if isinstance(m, _Batch) else len(m.data)


def _chunks_in_sequence(chunk_indexes) -> bool:
    """No chunk starts before the one before it ends (one writer recording in time): a chunk's batch then holds all
    of its channel's messages between the batches before and after it, and read_batched gives every channel's samples
    in log-time order, as `read` does. Chunks overlapping in time (merged recordings) are read message by message."""
    end = None
    for ci in sorted(chunk_indexes, key=lambda c: (c.message_start_time, c.chunk_start_offset)):
        if end is not None and ci.message_start_time < end:
            return False
        end = ci.message_end_time if end is None else max(end, ci.message_end_time)
    return True


def _in_log_time_order(fh, summary, topics, batched: frozenset = frozenset(), on_damage=None) -> Iterator[tuple]:
    """(schema, channel, message) of an indexed MCAP's chunks in log-time order, as mcap's
    `iter_messages(topics, log_time_order=True)` yields them (ties: chunk offset, then position in the chunk).
    A chunk's messages on a channel in `batched` come as one `_Batch`, in log-time order, in the place of the first.
    A damaged chunk (beyond the file's end, CRC mismatch, does not decompress or parse) goes to
    `on_damage(pos, start_ns, end_ns, fault)`, which says whether to read it anyway (default: skipped).

    The same heap of chunks and messages, keyed by plain tuples: mcap's wraps each message in an object compared
    by Python methods. Reading the 1-minute office log (27002 messages, zstd included) took 3.80 CPU s through mcap's
    and 2.85 s through this one, in the same order."""
    on_damage = on_damage or (lambda *_: False)
    wanted = None if topics is None else set(topics)
    size = os.fstat(fh.fileno()).st_size
    heap = []
    for ci in summary.chunk_indexes:  # chunks that may hold a wanted topic (mcap's _chunks_matching_topics)
        if wanted is None or not ci.message_index_offsets or any(
                summary.channels[c].topic in wanted for c in ci.message_index_offsets):
            heap.append((ci.message_start_time, ci.chunk_start_offset, -1, ci))  # -1: the chunk itself, not yet read
    heapq.heapify(heap)
    take = {cid: (None if ch.schema_id == 0 else summary.schemas[ch.schema_id], ch)  # (KeyError: damage, as mcap's)
            for cid, ch in summary.channels.items() if wanted is None or ch.topic in wanted}
    while heap:
        log_time, offset, index, item = heapq.heappop(heap)
        if index >= 0:
            yield item
            continue
        batches: dict[int, list[tuple[int, int, Message]]] = {}
        for i, rec in _checked_chunk(fh, size, item, summary.channels, take, on_damage):
            if rec.channel_id in batched:
                batches.setdefault(rec.channel_id, []).append((rec.log_time, i, rec))
                continue
            heapq.heappush(heap, (rec.log_time, offset, i, (*take[rec.channel_id], rec)))
        for cid, msgs in batches.items():
            msgs.sort(key=lambda m: m[:2])  # log time, then position in the chunk: the order the heap gives
            heapq.heappush(heap, (msgs[0][0], offset, msgs[0][1], (*take[cid], _Batch([m for _, _, m in msgs]))))


def _checked_chunk(fh, size: int, ci, channels: dict, take: dict, on_damage) -> list[tuple[int, Message]]:
    """The messages of the chunk a ChunkIndex points at; a damaged chunk as `on_damage` says (skipped: [])."""
    pos = ci.chunk_start_offset
    if not 0 < pos < size or ci.chunk_length > size - pos:  # (a damaged index may claim 2^60 bytes: never read)
        on_damage(pos, ci.message_start_time, ci.message_end_time,
                  _ChunkFault(f"its index says {ci.chunk_length} bytes at byte {pos}, the file has {size}", False))
        return []
    fh.seek(pos, io.SEEK_SET)
    buf = fh.read(ci.chunk_length)
    out: list[tuple[int, Message]] = []
    try:
        out.extend(_chunk_messages(buf, channels, take))
        return out
    except _ChunkFault as e:
        fault = e
    except (McapError, struct.error, UnicodeDecodeError) as e:
        fault = _ChunkFault(str(e), False)
    if not on_damage(pos, ci.message_start_time, ci.message_end_time, fault):
        return []
    out.clear()  # read as it is (a CRC mismatch): every message that parses
    try:
        out.extend(_chunk_messages(buf, channels, take, verify=False))
    except (_ChunkFault, McapError, struct.error, UnicodeDecodeError):
        pass
    return out


class _ChunkFault(McapError):
    """A damaged chunk, in words; `crc`: only its CRC disagrees (its data decompress and may be read)."""

    def __init__(self, text: str, crc: bool) -> None:
        super().__init__(text)
        self.crc = crc


class _Bounded:
    """A file whose read(n) never asks for more than the bytes left: a damaged length field (2^60) then reads
    short, which mcap reports as the file's end, instead of allocating what the field claims."""

    def __init__(self, fh) -> None:
        self._fh = fh
        self._size = os.fstat(fh.fileno()).st_size

    def read(self, n: int = -1) -> bytes:
        left = max(0, self._size - self._fh.tell())
        return self._fh.read(left if n is None or n < 0 else min(n, left))

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        return self._fh.seek(offset, whence)

    def tell(self) -> int:
        return self._fh.tell()

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True


_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, record length, message start / end time, uncompressed size, crc, len(compression)
_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_VIEW_OVER = 65536  # a message larger than this (a depth image) is a view into its chunk, not a copy


def _chunk_data(compression: str, raw, size: int, crc: int) -> bytes:
    """A chunk's records, decompressed within its stated size (frontend/logs/inflate.py) and checked against its
    CRC-32 (mcap spec: uncompressed_crc, 0 when not written); _ChunkFault when either fails."""
    if compression not in ("", "zstd", "lz4"):
        raise _ChunkFault(f"its compression {compression!r} is not one of MCAP's (zstd, lz4 or none)", False)
    try:
        data = inflate(compression, raw, size)
    except ChunkDamage as e:
        raise _ChunkFault(str(e), False) from e
    if len(data) != size:
        raise _ChunkFault(f"it holds {len(data)} bytes, its header says {size}", False)
    if crc and zlib.crc32(data) != crc:
        raise _ChunkFault(f"its CRC is {zlib.crc32(data):08x}, its header says {crc:08x}", True)
    return data


def _chunk_messages(buf: bytes, channels: dict, take: dict, verify: bool = True) -> Iterator[tuple[int, Message]]:
    """(position in the chunk, Message) of one Chunk record's messages on the channels in `take` (of the summary's
    `channels`: a message on any other is damage). McapError for a chunk that does not parse, _ChunkFault for one
    that does not decompress or (`verify`) whose CRC disagrees.

    Written here instead of mcap's Chunk.read + breakup_chunk, which read through a BytesIO field by field and
    copy every message's bytes: on a 30 Hz Kinect log that was 7.8 GB of copies per 10 minutes and, beside zstd,
    most of the reading thread's time (mcap spec: Chunk 0x06 holds Message 0x05 records)."""
    op, _, _, _, size, crc, n = _CHUNK_HEAD.unpack_from(buf, 0)
    if op != 0x06:
        raise McapError(f"expected a chunk record (opcode 0x06), found 0x{op:02x}")
    pos = _CHUNK_HEAD.size
    compression = bytes(buf[pos:pos + n]).decode()
    (rlen,) = struct.unpack_from("<Q", buf, pos + n)
    pos += n + 8
    raw = memoryview(buf)[pos:pos + rlen]
    if len(raw) != rlen:
        raise McapError(f"chunk ends after {len(raw)} of its {rlen} bytes")
    data = _chunk_data(compression, raw, size, crc if verify else 0)
    view = memoryview(data)
    pos, end, i = 0, len(data), 0
    while pos < end:
        op, length = _RECORD.unpack_from(data, pos)
        pos += 9
        if pos + length > end:
            raise McapError(f"a record in a chunk claims {length} bytes, {end - pos} are left")
        if op == 0x05 and length >= 22:
            cid, seq, log_time, pub_time = _MESSAGE.unpack_from(data, pos)
            if cid not in channels:
                raise McapError(f"a message on channel {cid}, which the file's summary does not list")
            if cid in take:
                body = view[pos + 22:pos + length]
                yield i, Message(cid, log_time, body if length > _VIEW_OVER else bytes(body), pub_time, seq)
        pos += length
        i += 1


def _nothing_read(fh, name: str, err: Exception | None) -> str:
    """Why a damaged MCAP gave not one message, for a user: where its top-level records stop being whole (a record
    running past the file's end, or one no writer makes), else the error the read stopped at."""
    size, pos = os.fstat(fh.fileno()).st_size, 8  # after the magic
    while pos < size:
        fh.seek(pos)
        head = fh.read(_RECORD.size)
        op, length = _RECORD.unpack(head) if len(head) == _RECORD.size else (1, size)
        if length >= 1 << 32 or not (0x01 <= op <= 0x0F or op >= 0x80):  # mcap's length limit; the spec's opcodes
            return (f"{name} is damaged: the record at byte {pos} (opcode 0x{op:02x}, {length} bytes) is not an MCAP "
                    f"record, so no message can be read; re-copy or re-record it")
        if pos + _RECORD.size + length > size:
            return (f"{name} is truncated: it ends after {size} bytes, inside the record at byte {pos}, so no message "
                    f"can be read; re-copy or re-record it")
        if op == 0x02:  # the footer: every record is whole
            return f"{name} is damaged ({err}), so no message can be read; re-copy or re-record it"
        pos += _RECORD.size + length
    return (f"{name} is truncated: it ends after {size} bytes, before its footer, with no message; "
            f"re-copy or re-record it")


def _merge(topics: list[TopicInfo]) -> list[TopicInfo]:
    """One entry per topic name (an MCAP may hold several channels on one topic)."""
    out: dict[str, TopicInfo] = {}
    for t in topics:
        if t.name in out:
            out[t.name].count += t.count
        else:
            out[t.name] = TopicInfo(t.name, t.type, t.count)
    return list(out.values())
