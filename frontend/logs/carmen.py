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
from kosmap.frontend.logs.validate import MAX_BEAMS, MAX_STAMP_NS
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
    """A CARMEN time (s) in ns; ValueError for one no clock gives (not finite, before the epoch, past 2116)."""
    v = float(t)
    if not 0.0 <= v < MAX_STAMP_NS * 1e-9:  # (also False for NaN)
        raise ValueError(f"a time stamp of {t}")
    return int(round(v * 1e9))


def _count(field: str, what: str) -> int:
    """A beam or remission count: ValueError unless 0..MAX_BEAMS."""
    n = int(field)
    if not 0 <= n <= MAX_BEAMS:
        raise ValueError(f"{what} count of {n}")
    return n


def _need(f: list, n: int, what: str) -> None:
    if len(f) < n:
        raise ValueError(f"{len(f)} fields where {what} has at least {n}")


def _floats(fields: list, what: str) -> tuple[float, ...]:
    """Finite numbers (a pose, an angle); ValueError names `what` when one is not."""
    v = tuple(float(x) for x in fields)
    if not all(map(math.isfinite, v)):
        raise ValueError(f"a non-finite {what}")
    return v


def _parse_odom(f: list) -> tuple[int, float, float, float]:
    """ODOM x y theta tv rv accel timestamp hostname logger_timestamp → (stamp, x, y, theta)."""
    _need(f, 8, "an ODOM line")
    x, y, th = _floats(f[1:4], "odometry pose")
    return _ns(f[7]), x, y, th


class CarmenLog(LogReader):
    format = "CARMEN log"

    def __init__(self, path) -> None:
        super().__init__(path)
        counts = {k: 0 for k in _KEYWORDS}
        with open(self.path, "rb") as f:
            for line in f:
                key = line.split(b" ", 1)[0]
                if key == b"ODOM":  # only a well-formed ODOM line means the log has odometry of its own
                    try:
                        _parse_odom(line.decode("ascii", errors="replace").split())
                    except (ValueError, IndexError):
                        continue
                if key in counts:
                    counts[key] += 1
        self._counts = counts
        # Without ODOM lines (save_odom: true), the odometry pose stored in each laser line is the odometry.
        self._odom_from_laser = counts[b"ODOM"] == 0
        if not any(counts.values()):
            raise LogError(f"{self.path.name} has no FLASER, ROBOTLASER1 or ODOM lines; it is not a CARMEN laser log")

    def _parse(self, line: str) -> list[tuple[int, int, object]]:
        """A line's records; ValueError (saying what is wrong) or IndexError for a malformed line."""
        f = line.split()
        kind = f[0]
        if kind == "FLASER":
            n = _count(f[1], "a beam")
            _need(f, 9 + n, f"a FLASER line of {n} beams")
            if n < 2:
                raise ValueError(f"a beam count of {n}")
            r = np.array(f[2:2 + n], dtype=np.float32)
            ox, oy, oth = _floats(f[5 + n:8 + n], "odometry pose")
            t = _ns(f[8 + n])
            out = [(t, 0, Scan(t, r, -math.pi / 2, math.pi / (n - 1), 0.1, NO_RETURN, "base_link", SCAN_TOPIC))]
            if self._odom_from_laser:
                out.append((t, 1, Odometry(t, ox, oy, oth, "odom", "base_link", ODOM_TOPIC)))
            return out
        if kind == "ROBOTLASER1":
            _need(f, 10, "a ROBOTLASER1 line")
            start, _fov, res, maxr = _floats(f[2:6], "beam angle or range")
            n = _count(f[8], "a beam")
            _need(f, 10 + n, f"a ROBOTLASER1 line of {n} beams")
            m = _count(f[9 + n], "a remission")
            rest = f[10 + n + m:]
            _need(rest, 12, "the end of a ROBOTLASER1 line")
            if n < 1 or (n > 1 and res == 0):
                raise ValueError(f"{n} beams {res:g} rad apart")
            r = np.array(f[9:9 + n], dtype=np.float32)
            rx, ry, rth = _floats(rest[3:6], "odometry pose")
            t = _ns(rest[11])
            out = [(t, 0, Scan(t, r, start, res, 0.0, min(maxr, NO_RETURN), "base_link", SCAN_TOPIC))]
            if self._odom_from_laser:
                out.append((t, 1, Odometry(t, rx, ry, rth, "odom", "base_link", ODOM_TOPIC)))
            return out
        if kind == "ODOM":
            t, x, y, th = _parse_odom(f)
            return [(t, 1, Odometry(t, x, y, th, "odom", "base_link", ODOM_TOPIC))]
        return []

    def _lines(self, topics: set[str] | None) -> Iterator[tuple[int, int, object]]:
        bad, first_bad, why = 0, 0, ""
        seq = 0
        with open(self.path, encoding="ascii", errors="replace") as f:
            for lineno, line in enumerate(f, 1):
                if not line.startswith(("FLASER", "ROBOTLASER1", "ODOM")):
                    continue
                try:
                    items = self._parse(line)
                except (ValueError, IndexError, OverflowError) as e:
                    bad += 1
                    if bad == 1:
                        first_bad, why = lineno, str(e) or "too few fields"
                    continue
                for t, _, rec in items:
                    if topics is None or rec.topic in topics:
                        seq += 1
                        yield t, seq, rec
        if bad:
            self._warn(f"{self.path.name}: skipped {bad} malformed line(s), the first at line {first_bad} ({why}); "
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
        stamps = _ScanStamps(self.path.name)
        for rec in reorder(self._lines(wanted), window_ns=2_000_000_000):
            rec = self._usable(rec)  # the read-time checks every reader applies (frontend/logs/validate.py)
            if rec is not None:
                if isinstance(rec, Scan):
                    stamps.check(rec.stamp_ns)
                yield rec


class _ScanStamps:
    """Some research logs write no scan times (every FLASER line stamped 0): read as they are, the whole run would
    collapse into one instant and map as a single scan. The first SAME scans sharing one time end the read."""

    SAME = 20  # at the slowest real laser's 5 Hz, 20 scans span 4 s: no logger stamps them all alike

    def __init__(self, name: str) -> None:
        self.name, self.first, self.n = name, None, 0

    def check(self, stamp_ns: int) -> None:
        if self.n < 0:
            return
        if self.first is None:
            self.first = stamp_ns
        if stamp_ns != self.first:
            self.n = -1  # the times move: nothing more to check
            return
        self.n += 1
        if self.n >= self.SAME:
            raise LogError(f"{self.name}: its first {self.n} laser scans all carry the time {self.first / 1e9:.3f} s, "
                           f"so the log has no usable scan times; re-stamp it with `python -m kosmap.tools.laserimport "
                           f"{self.name} OUT.clf --format carmen` and map OUT.clf")
