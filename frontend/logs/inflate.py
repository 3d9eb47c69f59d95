"""Decompressing a log's chunk with its output bounded by the size its header states.

A damaged or hostile chunk may claim any size in its frame header (a zstd frame without content size, an lz4 frame
claiming 2^40 bytes): the libraries' one-shot calls allocate what is claimed. Here output is produced in pieces of
at most 1 MiB, so memory follows the bytes really decompressed, and never exceeds the chunk header's stated size,
itself checked against a limit first.
"""

from __future__ import annotations

import bz2
from collections.abc import Iterator

import lz4.frame
import zstandard

# A chunk's uncompressed size beyond this is damage: writers cut chunks at 1 MiB (rosbag) to 4 MiB (mcap CLI);
# one uncompressed 4K depth image is 30 MB. 1 GiB leaves room for any real recorder and refuses 2^40-byte claims.
MAX_CHUNK_BYTES = 1 << 30
_PIECE = 1 << 20


class ChunkDamage(Exception):
    """A chunk whose data does not decompress to its stated size; the text says why."""


def _pieces_bz2_lz4(d, raw) -> Iterator[bytes]:
    out = d.decompress(raw, max_length=_PIECE)
    while out:
        yield out
        if d.eof:
            return
        out = d.decompress(b"", max_length=_PIECE)


def _pieces_zstd(raw) -> Iterator[bytes]:
    with zstandard.ZstdDecompressor().stream_reader(raw, read_across_frames=False) as r:
        while piece := r.read(_PIECE):
            yield piece


def inflate(compression: str, raw, size: int | None) -> bytes:
    """The chunk's data: `size` bytes when the header states it (None: no statement, bounded by MAX_CHUNK_BYTES).

    ChunkDamage when it does not decompress, holds more or fewer bytes than stated, or its header states more than
    MAX_CHUNK_BYTES. Compression "" or "none" returns `raw` itself."""
    if compression in ("", "none"):
        return raw
    bound = MAX_CHUNK_BYTES if size is None else size
    if bound > MAX_CHUNK_BYTES:
        raise ChunkDamage(f"its header claims {bound} uncompressed bytes, more than any recorder writes in one chunk")
    if compression == "bz2":
        d = bz2.BZ2Decompressor()
        pieces = _pieces_bz2_lz4(d, raw)
    elif compression == "lz4":
        d = lz4.frame.LZ4FrameDecompressor()
        pieces = _pieces_bz2_lz4(d, raw)
    elif compression == "zstd":
        d, pieces = None, _pieces_zstd(raw)
    else:
        raise ChunkDamage(f"its compression '{compression}' is not one kosmap reads (bz2, lz4, zstd or none)")
    out, n = [], 0
    try:
        for piece in pieces:
            n += len(piece)
            if n > bound:
                raise ChunkDamage(f"its {compression} data holds more than the {bound} bytes its header states")
            out.append(piece)
    except (OSError, ValueError, RuntimeError, EOFError, MemoryError, zstandard.ZstdError) as e:
        raise ChunkDamage(f"its {compression} data does not decompress ({type(e).__name__}: {e})") from e
    if d is not None and not d.eof:
        raise ChunkDamage(f"its {compression} data ends early, after {n} bytes")
    if size is not None and n != size:
        raise ChunkDamage(f"its {compression} data holds {n} bytes, its header says {size}")
    return b"".join(out)
