"""CARMEN text logs (.clf): FLASER, ROBOTLASER1 and ODOM lines become Scan and Odometry records.

Times are CARMEN's ipc_timestamp (the benchmark relations use it). Beam angles of the old FLASER
format are not in the log: −90° to +90° evenly, as INESC TEC's converter assumes (SOURCES.md).
Ranges ≥ 80 m mean "no return"; range_max is set to 80 m so that they fall outside it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator

import numpy as np

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import topics as T
from kosmap.frontend.logs.base import LogInfo, LogReader, TopicInfo, reorder
from kosmap.frontend.records import Odometry, Scan

SCAN_TOPIC, ODOM_TOPIC = "/scan", "/odom"
NO_RETURN = 80.0
_KEYWORDS = (b"FLASER", b"ROBOTLASER1", b"ODOM")


def looks_like_carmen(head: bytes) -> bool:
    """True when the first lines are CARMEN comments or messages."""
    lines = [ln for ln in head.splitlines()[:20] if ln.strip()]
    return bool(lines) and all(ln.startswith(b"#") or ln.split(b" ", 1)[0].isupper() for ln in lines[:-1]) and any(
        ln.split(b" ", 1)[0] in _KEYWORDS + (b"PARAM", b"SYNC", b"RAWLASER1", b"ROBOTLASER0") for ln in lines)


def _ns(t: str) -> int:
    return int(round(float(t) * 1e9))


class CarmenLog(LogReader):
    format = "CARMEN log"

    def __init__(self, path) -> None:
        super().__init__(path)
        counts = {k: 0 for k in _KEYWORDS}
        with open(self.path, "rb") as f:
            for line in f:
                key = line.split(b" ", 1)[0]
                if key in counts:
                    counts[key] += 1
        self._counts = counts
        # Without ODOM lines (save_odom: true), the odometry pose stored in each laser line is the odometry.
        self._odom_from_laser = counts[b"ODOM"] == 0
        if not any(counts.values()):
            raise LogError(f"{self.path.name} has no FLASER, ROBOTLASER1 or ODOM lines; it is not a CARMEN laser log")

    def _parse(self, line: str, lineno: int) -> list[tuple[int, int, object]]:
        f = line.split()
        kind = f[0]
        if kind == "FLASER":
            n = int(f[1])
            r = np.array(f[2:2 + n], dtype=np.float32)
            ox, oy, oth = (float(v) for v in f[5 + n:8 + n])
            t = _ns(f[8 + n])
            inc = math.pi / (n - 1) if n > 1 else 0.0
            out = [(t, 0, Scan(t, r, -math.pi / 2, inc, 0.1, NO_RETURN, "base_link", SCAN_TOPIC))]
            if self._odom_from_laser:
                out.append((t, 1, Odometry(t, ox, oy, oth, "odom", "base_link", ODOM_TOPIC)))
            return out
        if kind == "ROBOTLASER1":
            start, _fov, res, maxr = (float(v) for v in f[2:6])
            n = int(f[8])
            r = np.array(f[9:9 + n], dtype=np.float32)
            m = int(f[9 + n])
            rest = f[10 + n + m:]
            rx, ry, rth = (float(v) for v in rest[3:6])
            t = _ns(rest[11])
            out = [(t, 0, Scan(t, r, start, res, 0.0, min(maxr, NO_RETURN), "base_link", SCAN_TOPIC))]
            if self._odom_from_laser:
                out.append((t, 1, Odometry(t, rx, ry, rth, "odom", "base_link", ODOM_TOPIC)))
            return out
        if kind == "ODOM":
            x, y, th = (float(v) for v in f[1:4])
            t = _ns(f[7])
            return [(t, 1, Odometry(t, x, y, th, "odom", "base_link", ODOM_TOPIC))]
        return []

    def _lines(self, topics: set[str] | None) -> Iterator[tuple[int, int, object]]:
        bad = 0
        seq = 0
        with open(self.path, encoding="ascii", errors="replace") as f:
            for lineno, line in enumerate(f, 1):
                if not line.startswith(("FLASER", "ROBOTLASER1", "ODOM")):
                    continue
                try:
                    items = self._parse(line, lineno)
                except (ValueError, IndexError):
                    bad += 1
                    if bad == 1:
                        first_bad = lineno
                    continue
                for t, _, rec in items:
                    if topics is None or rec.topic in topics:
                        seq += 1
                        yield t, seq, rec
        if bad:
            self._warn(f"{self.path.name}: skipped {bad} malformed line(s), the first at line {first_bad}; "
                                 f"the log may be truncated or edited")

    def info(self) -> LogInfo:
        c = self._counts
        topics = []
        if c[b"FLASER"] + c[b"ROBOTLASER1"]:
            topics.append(TopicInfo(SCAN_TOPIC, T.LASER_SCAN, c[b"FLASER"] + c[b"ROBOTLASER1"]))
        n_odom = c[b"ODOM"] if not self._odom_from_laser else c[b"FLASER"] + c[b"ROBOTLASER1"]
        if n_odom:
            topics.append(TopicInfo(ODOM_TOPIC, T.ODOMETRY, n_odom))
        start = end = None
        for t, _, _ in self._lines(None):
            start = t if start is None else min(start, t)
            end = t if end is None else max(end, t)
        return LogInfo(self.path, self.format, start or 0, end or 0, topics)

    def read(self, topics: Iterable[str] | None = None) -> Iterator:
        wanted = None if topics is None else set(topics)
        yield from reorder(self._lines(wanted), window_ns=2_000_000_000)
