"""The last metres of scans stitched by the odometry into one local submap: a narrow depth camera's view widened
by the robot's own motion, for the global search (backend/globalsearch.py) that confirms or replaces the particle
filter's pose before it is claimed."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from kosmap.frontend import se2


@dataclass
class ScanWindow:
    """Scans with their odometry poses, at most `length_m` of travel back from the newest."""

    length_m: float
    odom: list[np.ndarray] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)
    travel: list[float] = field(default_factory=list)  # cumulative path length at each scan

    def clear(self) -> None:
        self.odom.clear()
        self.points.clear()
        self.travel.clear()

    def add(self, odom: np.ndarray, pts: np.ndarray) -> None:
        t = 0.0
        if self.odom:
            d = se2.between(self.odom[-1], odom)
            t = self.travel[-1] + math.hypot(d[0], d[1])
        self.odom.append(np.asarray(odom, float))
        self.points.append(np.asarray(pts, float))
        self.travel.append(t)
        while len(self.travel) > 1 and t - self.travel[1] >= self.length_m:
            self.odom.pop(0)
            self.points.pop(0)
            self.travel.pop(0)

    def keep_recent(self, m: float) -> None:
        """Drop the scans more than `m` of travel back from the newest."""
        while len(self.travel) > 1 and self.travel[-1] - self.travel[1] >= m:
            self.odom.pop(0)
            self.points.pop(0)
            self.travel.pop(0)

    @property
    def span_m(self) -> float:
        """Path length the window covers."""
        return self.travel[-1] - self.travel[0] if self.travel else 0.0

    @property
    def total_m(self) -> float:
        """Path length since the window was cleared (a clock for when to search again)."""
        return self.travel[-1] if self.travel else 0.0

    def submap(self, recent_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The window's end points (those of the last `recent_m` of travel, or all) in the newest scan's frame (N×2),
        and where each was seen from (N×2: the robot's position at its scan; the camera sits at the robot's centre
        to within the map's blur)."""
        if not self.odom:
            return np.zeros((0, 2)), np.zeros((0, 2))
        ref = self.odom[-1]
        out, views = [], []
        for u, p, t in zip(self.odom, self.points, self.travel):
            if len(p) == 0 or (recent_m is not None and self.travel[-1] - t > recent_m):
                continue
            t = se2.between(ref, u)
            c, s = math.cos(t[2]), math.sin(t[2])
            out.append(np.column_stack((t[0] + c * p[:, 0] - s * p[:, 1], t[1] + s * p[:, 0] + c * p[:, 1])))
            views.append(np.tile(t[:2], (len(p), 1)))
        if not out:
            return np.zeros((0, 2)), np.zeros((0, 2))
        return np.concatenate(out), np.concatenate(views)
