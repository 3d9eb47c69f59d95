"""Manhattan-world heading: most indoor walls run along two perpendicular directions (Coughlan & Yuille, "Manhattan
World", ICCV 1999), so a keyframe whose scan shows straight walls gives its heading modulo 90° once the building's
axes are known. A yaw-only prior per such keyframe is the absolute heading reference that a one-pass survey with a
narrow forward scan lacks: loops are rare there, and without them the graph's heading drifts with the gyro bias
estimate (simulated office survey, KOS, no loops: 2.6° RMS over 300 s windows). The axes are taken from the first
keyframes with walls and must explain nearly all of them; a building that is not Manhattan gets no priors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

QUARTER = math.pi / 2


def wrap_quarter(a):
    """An angle modulo 90°, in [−45°, 45°)."""
    return (np.asarray(a, dtype=float) + QUARTER / 2) % QUARTER - QUARTER / 2


def quarter_mean(a) -> float:
    """The circular mean of angles modulo 90° (of four times each angle), in [−45°, 45°)."""
    return float(wrap_quarter(np.angle(np.exp(4j * np.asarray(a, dtype=float)).mean()) / 4.0))


def wall_direction(points: np.ndarray, window: int = 32, min_extent: float = 0.3, max_gap: float = 0.15,
                   max_rms: float = 0.01, min_windows: int = 5) -> tuple[float, int] | None:
    """The dominant direction, modulo 90° (rad, [−45°, 45°)), of the straight walls in a scan's points (in bearing
    order, any frame), and how many straight `window`-point runs lie along it; None without enough of them.

    A run is straight when it spans ≥ min_extent, has no gap > max_gap and its points lie within max_rms of their
    principal line; directions are voted in 1° bins modulo 90° (perpendicular walls vote together), and the peak is
    refined by the circular mean modulo 90° (quarter_mean) of the runs within 3° of it."""
    p = np.asarray(points, dtype=float)
    if len(p) < window + min_windows:
        return None
    x = sliding_window_view(p[:, 0], window)
    y = sliding_window_view(p[:, 1], window)
    mx, my = x.mean(axis=1), y.mean(axis=1)
    cxx = ((x - mx[:, None]) ** 2).mean(axis=1)
    cyy = ((y - my[:, None]) ** 2).mean(axis=1)
    cxy = ((x - mx[:, None]) * (y - my[:, None])).mean(axis=1)
    lam_min = 0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy ** 2)
    gaps = np.hypot(*np.diff(p, axis=0).T)
    max_gaps = sliding_window_view(gaps, window - 1).max(axis=1)
    extent = np.hypot(x[:, -1] - x[:, 0], y[:, -1] - y[:, 0])
    ok = (extent >= min_extent) & (max_gaps <= max_gap) & (np.sqrt(np.maximum(lam_min, 0.0)) <= max_rms)
    if ok.sum() < min_windows:
        return None
    ang = wrap_quarter(0.5 * np.arctan2(2 * cxy[ok], cxx[ok] - cyy[ok]))
    bins = np.floor((ang + QUARTER / 2) / math.radians(1.0)).astype(np.int64) % 90
    hist = np.bincount(bins, minlength=90).astype(float)
    smooth = sum(np.roll(hist, k) for k in (-2, -1, 0, 1, 2))
    peak = (np.argmax(smooth) + 0.5) * math.radians(1.0) - QUARTER / 2
    near = np.abs(wrap_quarter(ang - peak)) <= math.radians(3.0)
    if near.sum() < min_windows:
        return None
    return quarter_mean(ang[near]), int(near.sum())


@dataclass
class ManhattanStats:
    axis_deg: float | None = None  # the building's wall direction modulo 90° in the map frame (None: not set)
    keyframes_with_walls: int = 0
    priors: int = 0
    off_axis: int = 0  # keyframes whose walls were more than the gate off the axes (not Manhattan walls, or drift)
    disabled: str = ""  # why no priors are made ("" while they are)


@dataclass
class ManhattanHeading:
    """Heading priors from wall directions: `observe` per keyframe → the yaw to hold it at, or None."""

    gate_deg: float = 5.0
    init_keyframes: int = 10  # keyframes with walls that fix the axes (their walls at their current estimates) …
    init_agree_deg: float = 2.0  # … a keyframe agreeing with the axes when its walls lie within this of them …
    init_share: float = 0.8  # … and at least this share of the keyframes agreeing
    init_max_keyframes: int = 60  # give up (not Manhattan) when no consistent axes are found by then
    stats: ManhattanStats = field(default_factory=ManhattanStats)
    _seen: list = field(default_factory=list)
    _axis: float | None = None

    def observe(self, yaw_estimate: float, points: np.ndarray) -> float | None:
        """The keyframe's walls against the axes: the yaw its walls put it at (nearest to `yaw_estimate`), or None."""
        if self.stats.disabled:
            return None
        d = wall_direction(points)
        if d is None:
            return None
        self.stats.keyframes_with_walls += 1
        world = float(wrap_quarter(yaw_estimate + d[0]))
        if self._axis is None:
            self._seen.append(world)
            self._try_axes()
            return None
        r = float(wrap_quarter(world - self._axis))
        if abs(r) > math.radians(self.gate_deg):
            self.stats.off_axis += 1
            return None
        self.stats.priors += 1
        return yaw_estimate - r

    def _try_axes(self) -> None:
        """Fix the axes from the latest `init_keyframes` wall directions when they agree; give up after
        `init_max_keyframes` without agreement."""
        seen = np.array(self._seen[-self.init_keyframes:])
        if len(seen) >= self.init_keyframes:
            axis = quarter_mean(seen)
            agree = np.abs(wrap_quarter(seen - axis)) <= math.radians(self.init_agree_deg)
            if agree.mean() >= self.init_share:
                self._axis = axis
                self.stats.axis_deg = math.degrees(axis)
                self._seen = []
                return
        if len(self._seen) >= self.init_max_keyframes:
            self.stats.disabled = (f"the walls of the first {len(self._seen)} keyframes with walls do not share two "
                                   f"perpendicular directions (not a Manhattan building): no heading priors")
            self._seen = []
