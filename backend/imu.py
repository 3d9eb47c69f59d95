"""Gyro yaw rate: buffered, integrated between graph nodes, and checked for gaps and a stuck output.

The yaw increment between two stamps is the trapezoid integral of the rate samples (linearly interpolated at
both ends), exact for a rate linear in time. Its noise ([graph] gyro_* keys):
σ² = N²·Δt (white rate noise, N the noise density) + (σ_b·Δt)² (bias not estimated) + floor².
Intervals the samples do not cover, with a gap between samples, or overlapping a run of identical outputs
lasting ≥ `stuck_s` (a stuck MEMS part: real rate noise never repeats a float exactly) give no increment;
the caller counts and reports them (backend/slam.py keeps a stuck stretch only where the robot did not turn:
a coarse gyro at rest may repeat its value). The gyro is never trusted blindly.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from dataclasses import dataclass

import numpy as np


@dataclass
class GyroIncrement:
    """The integrated yaw between two stamps, or why there is none (`reason`: "" when usable)."""

    dyaw: float  # rad, bias not removed
    dt: float  # s
    n: int  # samples inside the interval
    reason: str = ""  # "", "uncovered", "gap", "stuck"

    @property
    def ok(self) -> bool:
        return self.reason == ""


class GyroBuffer:
    """Yaw-rate samples (rad/s) in time order; integrates them between stamps; finds gaps and stuck runs."""

    def __init__(self, max_gap_s: float = 0.1, stuck_s: float = 1.0) -> None:
        self.t: list[int] = []
        self.w: list[float] = []
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.stuck_ns = int(stuck_s * 1e9)
        self.stuck: list[list[int]] = []  # [start, end] ns spans of constant output lasting ≥ stuck_s
        self._run_start: int | None = None  # stamp where the current run of identical values began
        self.dropped = 0  # out-of-order or duplicate samples ignored

    def __len__(self) -> int:
        return len(self.t)

    def add(self, stamp_ns: int, rate: float) -> None:
        """One sample (yaw rate about base_link z, rad/s). Out-of-order samples are dropped (counted)."""
        stamp_ns = int(stamp_ns)
        rate = float(rate)
        if not math.isfinite(rate) or (self.t and stamp_ns <= self.t[-1]):
            self.dropped += 1
            return
        if self.w and rate == self.w[-1]:
            if self._run_start is None:
                self._run_start = self.t[-1]
            if stamp_ns - self._run_start >= self.stuck_ns:
                if self.stuck and self.stuck[-1][1] >= self._run_start:
                    self.stuck[-1][1] = stamp_ns
                else:
                    self.stuck.append([self._run_start, stamp_ns])
        else:
            self._run_start = None
        self.t.append(stamp_ns)
        self.w.append(rate)

    def add_many(self, stamps_ns: np.ndarray, rates: np.ndarray) -> None:
        """`add` of each sample in order. Finite rates at rising stamps, no two in a row equal (a gyro's usual
        stream, which cannot start or extend a stuck run) are appended at once; anything else goes one by one."""
        t, w = np.asarray(stamps_ns, np.int64), np.asarray(rates, np.float64)
        if not len(t):
            return
        if (np.isfinite(w).all() and (np.diff(t) > 0).all() and (w[1:] != w[:-1]).all()
                and not (self.t and (t[0] <= self.t[-1] or w[0] == self.w[-1]))):
            self.t.extend(t.tolist())
            self.w.extend(w.tolist())
            self._run_start = None
            return
        for a, b in zip(t.tolist(), w.tolist()):
            self.add(a, b)

    def covers(self, stamp_ns: int) -> bool:
        """A sample at or after `stamp_ns` has arrived (the interval ending there can be integrated)."""
        return bool(self.t) and self.t[-1] >= stamp_ns

    def integrate(self, t0_ns: int, t1_ns: int, allow_stuck: bool = False) -> GyroIncrement:
        """∫ rate dt over [t0, t1] by the trapezoid rule, or an increment whose `reason` says why not. Within
        `max_gap_s` of the stream's first or last sample the rate is held (a keyframe just outside the stream)."""
        dt = (t1_ns - t0_ns) * 1e-9
        t = self.t
        if not t or t[0] - t0_ns > self.max_gap_ns or t1_ns - t[-1] > self.max_gap_ns:
            return GyroIncrement(0.0, dt, 0, "uncovered")
        if t1_ns <= t0_ns:
            return GyroIncrement(0.0, 0.0, 0, "")
        for s, e in ([] if allow_stuck else self.stuck):
            if s <= t1_ns and e >= t0_ns:
                return GyroIncrement(0.0, dt, 0, "stuck")
        lo = bisect_right(t, t0_ns)  # first sample strictly after t0
        hi = bisect_left(t, t1_ns)  # first sample at or after t1
        a, b = max(lo - 1, 0), min(hi + 1, len(t))  # the samples around the interval too
        near_t = np.asarray(t[a:b], dtype=np.int64)
        near_w = np.asarray(self.w[a:b], dtype=float)
        if len(near_t) >= 2 and int(np.max(np.diff(near_t))) > self.max_gap_ns:
            return GyroIncrement(0.0, dt, hi - lo, "gap")
        ts = np.concatenate(([t0_ns], t[lo:hi], [t1_ns])).astype(np.int64)
        ws = np.interp((ts - near_t[0]).astype(float), (near_t - near_t[0]).astype(float), near_w)  # held beyond the ends
        d = np.diff(ts) * 1e-9
        return GyroIncrement(float(np.sum(0.5 * (ws[1:] + ws[:-1]) * d)), dt, hi - lo)

    def drop_before(self, stamp_ns: int) -> None:
        """Forget samples older than the one just before `stamp_ns` (memory stays bounded on long logs)."""
        i = bisect_left(self.t, stamp_ns) - 1
        if i > 1000:
            del self.t[:i]
            del self.w[:i]
        self.stuck = [s for s in self.stuck if s[1] >= stamp_ns]


def yaw_sigma(dt: float, noise_density: float, bias_sigma: float, floor: float) -> float:
    """σ of an integrated yaw increment over dt (rad): white noise N·√Δt, an unmodelled bias σ_b·Δt, a floor."""
    return math.sqrt(noise_density ** 2 * dt + (bias_sigma * dt) ** 2 + floor ** 2)
