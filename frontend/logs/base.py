"""The one interface every log adapter implements: summary info, and a streaming, time-ordered read."""

from __future__ import annotations

import heapq
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kosmap.frontend.logs.convert import imu_problem, imu_samples_problems
from kosmap.frontend.logs.validate import RecordGuard
from kosmap.frontend.records import Imu, ImuSamples, Record


@dataclass
class TopicInfo:
    name: str
    type: str  # ROS 2 style, e.g. sensor_msgs/msg/LaserScan
    count: int


@dataclass
class LogInfo:
    """What `kosmap info` shows: format, time span and topics."""

    path: Path
    format: str
    start_ns: int
    end_ns: int
    topics: list[TopicInfo]
    truncated: bool = False
    notes: list[str] = field(default_factory=list)

    @property
    def duration(self) -> float:
        return max(0.0, (self.end_ns - self.start_ns) * 1e-9)

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    def types(self) -> dict[str, str]:
        return {t.name: t.type for t in self.topics}

    def count(self, topic: str | None) -> int:
        return next((t.count for t in self.topics if t.name == topic), 0)


class LogReader(ABC):
    """A log opened for reading. Use as a context manager; `warnings` collects non-fatal problems."""

    format: str = ""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.warnings: list[str] = []
        self._bad_imu: dict[str, int] = {}  # per topic: IMU samples skipped for non-finite values
        self._bad_msgs: dict[str, int] = {}  # per topic: messages skipped because their bytes do not decode
        self._guard = RecordGuard(self.path.name, self._warn)  # read-time checks of every record (validate.py)
        self.on_damage = "skip"  # a damaged chunk: "skip" it, "read" it as it is (a CRC mismatch), or "fail"

    @abstractmethod
    def info(self) -> LogInfo:
        """Format, time span and per-topic counts (from the index where the format has one)."""

    @abstractmethod
    def read(self, topics: Iterable[str] | None = None) -> Iterator[Record]:
        """Yield records of the given topics (all known ones if None) in time order, in one pass.

        Messages of types kosmap does not use are skipped. Memory stays flat in the log's length.
        """

    def read_batched(self, topics: Iterable[str] | None = None) -> Iterator:
        """`read`, where the reader may hand a stretch of Imu or Odometry messages of one topic as one ImuSamples or
        OdometrySamples record, in the place of its first sample (the MCAP reader does; others give `read`'s)."""
        return self.read(topics)

    def _usable(self, rec):
        """The record, or None (with one warning per topic) for an IMU sample with non-finite values; of an
        ImuSamples, the usable samples (None when none is). Every other record passes the read-time checks of
        frontend/logs/validate.py (skipped when impossible, odometry jumps bridged)."""
        if isinstance(rec, ImuSamples):
            bad = imu_samples_problems(rec)
            if bad is None:
                return rec
            ok = bad == ""
            i = int(np.flatnonzero(~ok)[0])  # the first one's warning, as `read` gives it
            self._bad_sample(rec.topic, str(bad[i]), int(rec.stamps_ns[i]))
            self._bad_imu[rec.topic] += int((~ok).sum()) - 1
            return rec.select(ok) if ok.any() else None
        if isinstance(rec, Imu):
            why = imu_problem(rec)
            if why is not None:
                self._bad_sample(rec.topic, why, rec.stamp_ns)
                return None
        return self._guard.check(rec)  # (an Imu: its stamp)

    def _bad_sample(self, topic: str, why: str, stamp_ns: int) -> None:
        bad = self._bad_imu
        if topic not in bad:
            self._warn(f"IMU on {topic} has {why} (first at t={stamp_ns * 1e-9:.3f} s); such samples are "
                       f"skipped: check the IMU driver, or pass --imu-topic none to map without it")
        bad[topic] = bad.get(topic, 0) + 1

    def _undecodable(self, topic: str, t_ns: int, err: Exception) -> None:
        """A message whose bytes do not decode as its type (damage inside a chunk): skipped, one warning a topic."""
        bad = self._bad_msgs
        if topic not in bad:
            self._warn(f"a message on {topic} at t={t_ns * 1e-9:.3f} s does not decode ({type(err).__name__}: {err}); "
                       f"such messages are skipped: the log is damaged there, check it with `mcap doctor` or `rosbag check`")
        bad[topic] = bad.get(topic, 0) + 1

    def _warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)

    def close(self) -> None:  # noqa: B027 - adapters without resources need nothing
        pass

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def normalize_type(name: str) -> str:
    """'sensor_msgs/LaserScan' (ROS 1) → 'sensor_msgs/msg/LaserScan' (ROS 2 / rosbags naming)."""
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def reorder(records: Iterable[tuple[int, int, Record]], window_ns: int) -> Iterator[Record]:
    """Sort a nearly ordered stream of (time, seq, record) with a bounded buffer of `window_ns`."""
    heap: list[tuple[int, int, Record]] = []
    for item in records:
        heapq.heappush(heap, item)
        while heap and heap[0][0] < item[0] - window_ns:
            yield heapq.heappop(heap)[2]
    while heap:
        yield heapq.heappop(heap)[2]
