"""Editing small logs the way damage or a hostile writer would: their records found by the formats' own layouts
(MCAP spec: opcode u8, length u64; ROS 1 bag 2.0: header length, header, data length, data)."""

from __future__ import annotations

import struct

MCAP_CHUNK, MCAP_CHUNK_INDEX, MCAP_DATA_END, MCAP_FOOTER = 0x06, 0x08, 0x0F, 0x02
# Chunk: opcode, length, message start / end time, uncompressed size, uncompressed crc, then compression (u32 +
# text) and the records (u64 + bytes)
CHUNK_USIZE_AT, CHUNK_CRC_AT, CHUNK_COMPRESSION_AT = 25, 33, 37
# ChunkIndex: opcode, length, message start / end time, chunk start offset, chunk length, ...
CHUNK_INDEX_LENGTH_AT = 33


def mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(position, opcode, length) of an MCAP's top-level records, up to its footer."""
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, length))
        pos += 9 + length
        if op == MCAP_FOOTER:
            break
    return out


def mcap_chunks(data: bytes) -> list[int]:
    return [p for p, op, _ in mcap_records(data) if op == MCAP_CHUNK]


def chunk_payload(data: bytes, chunk_pos: int) -> tuple[int, int]:
    """(position, length) of a chunk's compressed records."""
    (n,) = struct.unpack_from("<I", data, chunk_pos + CHUNK_COMPRESSION_AT)
    at = chunk_pos + CHUNK_COMPRESSION_AT + 4 + n
    (length,) = struct.unpack_from("<Q", data, at)
    return at + 8, length


def without_summary(data: bytes) -> bytes:
    """The MCAP cut before its DataEnd record: no summary, no footer (a recording that was not closed)."""
    end = next(p for p, op, _ in mcap_records(data) if op == MCAP_DATA_END)
    return data[:end]


def put(data: bytes, at: int, fmt: str, value) -> bytes:
    d = bytearray(data)
    struct.pack_into(fmt, d, at, value)
    return bytes(d)


def flip(data: bytes, at: int, bit: int = 0x40) -> bytes:
    d = bytearray(data)
    d[at] ^= bit
    return bytes(d)


def xxh32(data: bytes, seed: int = 0) -> int:
    """XXH32 (the lz4 frame format's header checksum), written out here: the xxhash package is not a dependency."""
    p1, p2, p3, p4, p5, m = 2654435761, 2246822519, 3266489917, 668265263, 374761393, 0xFFFFFFFF

    def rotl(x, r):
        return ((x << r) | (x >> (32 - r))) & m

    n, i = len(data), 0
    if n >= 16:
        v = [(seed + p1 + p2) & m, (seed + p2) & m, seed & m, (seed - p1) & m]
        while i + 16 <= n:
            for k in range(4):
                v[k] = (rotl((v[k] + int.from_bytes(data[i:i + 4], "little") * p2) & m, 13) * p1) & m
                i += 4
        h = (rotl(v[0], 1) + rotl(v[1], 7) + rotl(v[2], 12) + rotl(v[3], 18)) & m
    else:
        h = (seed + p5) & m
    h = (h + n) & m
    while i + 4 <= n:
        h = (rotl((h + int.from_bytes(data[i:i + 4], "little") * p3) & m, 17) * p4) & m
        i += 4
    while i < n:
        h = (rotl((h + data[i] * p5) & m, 11) * p1) & m
        i += 1
    h ^= h >> 15
    h = (h * p2) & m
    h ^= h >> 13
    h = (h * p3) & m
    return h ^ (h >> 16)


def lz4_claim(data: bytes, frame_at: int, size: int) -> bytes:
    """The lz4 frame at `frame_at` (written with its content size) now claiming `size` bytes, its header checksum
    made right again, so that only the claim is wrong."""
    d = bytearray(data)
    assert d[frame_at + 4] & 0x08, "the frame has no content size field"
    struct.pack_into("<Q", d, frame_at + 6, size)
    d[frame_at + 14] = (xxh32(bytes(d[frame_at + 4:frame_at + 14])) >> 8) & 0xFF
    return bytes(d)
