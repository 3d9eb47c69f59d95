"""Small logs of three formats and the mutations a damaged copy or a hostile writer makes to them, for the fuzz
suite (tests/frontend/test_fuzz_logs.py): byte flips, truncations and edits of the formats' length fields."""

from __future__ import annotations

import contextlib
import io
import signal
import struct
from dataclasses import dataclass
from pathlib import Path

from kosmap.frontend.logs.writer import BagWriter, McapWriter
from kosmap.tools.cli import main
from tests.frontend.hostile import mcap_records
from tests.frontend.synthetic_log import carmen_lines
from tests.frontend.synthetic_log import records as depth_records
from tests.mapping.synthetic_laser import make_log
from tests.mapping.synthetic_laser import records as laser_records

N_SCANS = 30  # 6 s of the ring corridor at 5 Hz: enough for slam to build a graph, short enough for many cases


def laser_logs(folder: Path) -> dict[str, Path]:
    """The first N_SCANS scans of the ring corridor with odometry, as an MCAP (zstd chunks of 16 KiB), a ROS 1 bag
    (bz2 chunks of 16 KiB) and a CARMEN log; and a small depth MCAP (5 frames of 64×48, camera info, scans)."""
    log = make_log(seed=4, laps=1, mount=(0.0, 0.0, 0.0))
    recs = laser_records(log)[:1 + 3 * N_SCANS]
    out = {"mcap": folder / "laser.mcap", "bag": folder / "laser.bag", "clf": folder / "laser.clf",
           "depth": folder / "depth.mcap"}
    with McapWriter(out["mcap"], chunk_size=16 << 10) as w:
        for r in recs:
            w.write(r)
    with BagWriter(out["bag"], compression="bz2", chunk_bytes=16 << 10) as w:
        for r in recs:
            w.write(r)
    out["clf"].write_text("\n".join(carmen_lines(log.scans[:N_SCANS], log.odom[:N_SCANS])) + "\n")
    with McapWriter(out["depth"], chunk_size=16 << 10) as w:
        for r in depth_records(n=5):
            w.write(r)
    return out


# -- the length fields of each format (positions of the bytes that say how long something is) -------------------------
def mcap_length_fields(data: bytes) -> list[tuple[int, str]]:
    """(position, struct format) of every top-level record's length and, in chunks, the uncompressed size and the
    records' length (MCAP spec)."""
    out = []
    for pos, op, _ in mcap_records(data):
        out.append((pos + 1, "<Q"))
        if op == 0x06 and pos + 41 <= len(data):
            out.append((pos + 25, "<Q"))
            (n,) = struct.unpack_from("<I", data, pos + 37)
            out.append((pos + 41 + n, "<Q"))
    return out


def bag_length_fields(data: bytes) -> list[tuple[int, str]]:
    """(position, struct format) of every top-level record's header and data length (bag format 2.0)."""
    out, pos = [], 13
    while pos + 8 <= len(data):
        (hl,) = struct.unpack_from("<I", data, pos)
        if pos + 8 + hl > len(data):
            break
        (dl,) = struct.unpack_from("<I", data, pos + 4 + hl)
        out += [(pos, "<I"), (pos + 4 + hl, "<I")]
        pos += 8 + hl + dl
    return out


def carmen_numbers(text: str) -> list[tuple[int, int]]:
    """(start, end) character spans of the first 12 fields of every line: counts, poses and times."""
    spans, at = [], 0
    for line in text.splitlines(keepends=True):
        col = 0
        for k, f in enumerate(line.split(" ")):
            if k in (1, 2, 3) or k >= len(line.split(" ")) - 3:
                spans.append((at + col, at + col + len(f.rstrip())))
            col += len(f) + 1
        at += len(line)
    return spans


HOSTILE_LENGTHS = (0, 1, 7, 1 << 31, (1 << 32) - 1, 1 << 40, 1 << 60, (1 << 64) - 1)
HOSTILE_NUMBERS = ("nan", "inf", "-inf", "1e300", "-1", "0", "99999999999", "x")


@dataclass(frozen=True)
class Mutation:
    kind: str  # "flip", "cut" or "length" (a length field, or in a CARMEN log a number, set to `value`)
    where: float  # 0..1: the byte, the cut or which field
    value: int = 0

    def apply(self, data: bytes, fmt: str) -> bytes:
        if self.kind == "cut":
            return data[:int(len(data) * self.where)]
        if self.kind == "flip":
            d = bytearray(data)
            d[min(len(d) - 1, int(len(d) * self.where))] ^= 1 << (self.value % 8)
            return bytes(d)
        if fmt == "clf":
            spans = carmen_numbers(data.decode("latin-1"))  # (one character a byte, whatever the bytes)
            if not spans:
                return data
            a, b = spans[min(len(spans) - 1, int(len(spans) * self.where))]
            return data[:a] + HOSTILE_NUMBERS[self.value % len(HOSTILE_NUMBERS)].encode() + data[b:]
        fields = (bag_length_fields if fmt == "bag" else mcap_length_fields)(data)
        if not fields:  # (an earlier edit left no whole record)
            return data
        at, f = fields[min(len(fields) - 1, int(len(fields) * self.where))]
        v = HOSTILE_LENGTHS[self.value % len(HOSTILE_LENGTHS)]
        d = bytearray(data)
        struct.pack_into(f, d, at, v % (1 << (8 * struct.calcsize(f))))
        return bytes(d)


class Hang(BaseException):
    """A case that ran past its time bound (a BaseException: the CLI's error handling must not catch it)."""


@dataclass
class Outcome:
    code: int
    out: str
    err: str


def run_cli(argv: list[str], seconds: int) -> Outcome:
    """`kosmap ARGV` in this process, its output captured; Hang if it runs past `seconds`."""
    def alarm(*_):
        raise Hang(f"kosmap {' '.join(argv)} ran past {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(argv)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    return Outcome(code, out.getvalue(), err.getvalue())


def check_outcome(o: Outcome, argv: list[str]) -> None:
    """Success, or one line of error with exit 2; never a traceback."""
    assert "Traceback" not in o.out + o.err, (argv, o.err[-2000:])
    assert o.code in (0, 2), (argv, o.code, o.err[-2000:])
    if o.code == 2:
        lines = [ln for ln in o.err.strip().splitlines() if not ln.startswith("warning:")]
        assert len(lines) == 1 and lines[0].startswith("kosmap: error: "), (argv, o.err[-2000:])
