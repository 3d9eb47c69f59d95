"""Where a SLAM run had little to hold its poses by, found while it runs: stretches of the log with no usable scan,
no wheel odometry, or scan matches that fix nothing along the way (a featureless corridor), and the keyframes the
pose graph had to chain with a weak motion prior or re-solve another way (backend/graph.py). Each kind becomes one
warning line naming its stretches in log time (seconds from the first scan), on the console, in metrics.json and in
the report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

GAP_S = 2.0  # a stretch without usable scans (or without odometry) longer than this is reported
# A keyframe's scan fixes no position along some direction when its surface normals all but miss it: fewer than
# this many points' worth of normal along the weakest direction (the smaller eigenvalue of Σ n·nᵀ, the point-to-line
# information of Censi's ICP covariance, up to σ²). A bare corridor seen by a 180° laser: 0.4–0.7; the simulated
# office (Hokuyo, 270°): 1st percentile 1.3, median 80. (The matcher's own covariance does not show it: the walls'
# ends at the range limit look like structure to a likelihood field.)
DEGENERATE_POINTS = 2.0
DEGENERATE_M = 3.0  # a run of degenerate keyframes is reported once it spans this much travel (m)


@dataclass
class Stretches:
    """Stretches (first, last stamp in ns) of each kind, and the solver's notes (stamp or None, text)."""

    no_scans: list[tuple[int, int]] = field(default_factory=list)
    no_odometry: list[tuple[int, int]] = field(default_factory=list)
    degenerate: list[tuple[int, int, float]] = field(default_factory=list)  # (first, last, metres travelled)
    weak_chain: list[tuple[int, int, int]] = field(default_factory=list)  # (first, last, keyframes)
    solver: list[tuple[int | None, str]] = field(default_factory=list)
    unusable: int = 0  # scans with too few returns to match

    def as_dict(self, t0_ns: int) -> dict:
        """metrics.json's view: seconds from the first scan."""
        s = lambda t: round((t - t0_ns) * 1e-9, 3)  # noqa: E731
        return {"unusable_scans": self.unusable, "no_scans_s": [[s(a), s(b)] for a, b in self.no_scans],
                "no_odometry_s": [[s(a), s(b)] for a, b in self.no_odometry],
                "degenerate_matches_s": [[s(a), s(b)] for a, b, _ in self.degenerate],
                "weak_motion_prior_s": [[s(a), s(b)] for a, b, _ in self.weak_chain],
                "solver": [{"t_s": None if t is None else s(t), "note": n} for t, n in self.solver]}


class HealthTracker:
    """Fed per scan and per keyframe by mapping/slam.py's Slam; `stretches` at the end."""

    def __init__(self, expect_odom: bool = False, still_m: float = 0.2, still_rad: float = math.radians(10.0)) -> None:
        """`still_m`, `still_rad`: a gap in the scans across which the wheel odometry moved less than this (the
        keyframe spacing, [graph] node_distance / node_angle_deg) lost no keyframe: a pause, not a blackout."""
        self.expect_odom = expect_odom
        self.still = (still_m, still_rad)
        self.first: int | None = None
        self.last: int | None = None
        self.last_usable: int | None = None
        self.last_usable_odom: np.ndarray | None = None
        self.odom_gap: tuple[int, int] | None = None  # (first scan without odometry, last one)
        self.degen: list | None = None  # [first stamp, last stamp, metres, last local pose]
        self.out = Stretches()

    def scan(self, stamp_ns: int, usable: bool, odom_pose: np.ndarray | None) -> None:
        """A scan: whether it has enough returns to match, and the wheel odometry at its stamp (None: none)."""
        stamp_ns = int(stamp_ns)
        if self.first is None:
            self.first = stamp_ns
        self.last = stamp_ns
        self.out.unusable += not usable
        if usable:
            start = self.first if self.last_usable is None else self.last_usable
            if (stamp_ns - start) * 1e-9 > GAP_S and _moved(self.last_usable_odom, odom_pose, *self.still):
                self.out.no_scans.append((start, stamp_ns))
            self.last_usable = stamp_ns
            self.last_usable_odom = None if odom_pose is None else np.asarray(odom_pose, float)
        if self.expect_odom and odom_pose is None:
            self.odom_gap = (self.odom_gap[0] if self.odom_gap else stamp_ns, stamp_ns)
        elif self.odom_gap is not None:
            self._close_odom(stamp_ns)

    def _close_odom(self, end_ns: int) -> None:
        a, _ = self.odom_gap
        if (end_ns - a) * 1e-9 > GAP_S:
            self.out.no_odometry.append((a, end_ns))
        self.odom_gap = None

    def keyframe(self, stamp_ns: int, local_pose: np.ndarray, points: np.ndarray) -> None:
        """A keyframe: its front-end pose and its scan's end points (base_link, in beam order)."""
        bad = weakest_structure(points) < DEGENERATE_POINTS
        if bad and self.degen is None:
            self.degen = [int(stamp_ns), int(stamp_ns), 0.0, np.asarray(local_pose, float)]
        elif bad:
            d = self.degen
            d[2] += math.hypot(*(np.asarray(local_pose[:2], float) - d[3][:2]))
            d[1], d[3] = int(stamp_ns), np.asarray(local_pose, float)
        elif self.degen is not None:
            self._close_degen()

    def _close_degen(self) -> None:
        a, b, m, _ = self.degen
        if m >= DEGENERATE_M:
            self.out.degenerate.append((a, b, m))
        self.degen = None

    def finish(self, key_stamps: np.ndarray, weak_nodes: list[int], solver_notes: list[tuple[int | None, str]]) -> Stretches:
        """Close the open stretches; add the graph's weak-chained keyframes (as runs) and its solver notes."""
        if self.last is not None and self.last_usable is not None and (self.last - self.last_usable) * 1e-9 > GAP_S:
            self.out.no_scans.append((self.last_usable, self.last))
        if self.odom_gap is not None:
            self._close_odom(self.odom_gap[1])
        if self.degen is not None:
            self._close_degen()
        for run in _runs(sorted(weak_nodes)):
            self.out.weak_chain.append((int(key_stamps[run[0]]), int(key_stamps[run[-1]]), len(run)))
        n = len(key_stamps)
        self.out.solver = [(int(key_stamps[k]) if k is not None and 0 <= k < n else None, t) for k, t in solver_notes]
        return self.out


def warnings(st: Stretches, t0_ns: int, has_odom: bool) -> list[str]:
    """One line per kind of stretch found, naming each stretch (at most four, then how many more)."""
    out = []
    held = "the wheel odometry" if has_odom else "the front end's motion prediction"
    if st.no_scans:
        out.append(f"no usable scan for {_total(st.no_scans)} ({_when(st.no_scans, t0_ns)}): the poses across rest on {held}")
    if st.no_odometry:
        out.append(f"no wheel odometry for {_total(st.no_odometry)} ({_when(st.no_odometry, t0_ns)}): "
                   f"those scans were matched without it")
    if st.degenerate:
        m = sum(d[2] for d in st.degenerate)
        out.append(f"the scans fixed no position along the way for {m:.0f} m ({_when(st.degenerate, t0_ns)}; a featureless "
                   f"corridor?): the position along it rests on {held}")
    if st.weak_chain:
        k = sum(w[2] for w in st.weak_chain)
        out.append(f"{k} keyframe(s) had neither a scan match nor odometry to chain them ({_when(st.weak_chain, t0_ns)}): "
                   f"held by a weak motion prior, the map may be bent there")
    if st.solver:
        where = sorted({t for t, _ in st.solver if t is not None})
        at = f" near t = {', '.join(f'{(t - t0_ns) * 1e-9:.1f}' for t in where[:4])} s" if where else ""
        notes = list(dict.fromkeys(n.split(" near variable")[0] for _, n in st.solver))  # each once, in order
        out.append(f"the pose graph could not be solved as built{at}: " + "; ".join(notes))
    return out


def _when(stretches: list[tuple], t0_ns: int) -> str:
    parts = [f"{(s[0] - t0_ns) * 1e-9:.1f}–{(s[1] - t0_ns) * 1e-9:.1f} s" for s in stretches[:4]]
    more = f" and {len(stretches) - 4} more" if len(stretches) > 4 else ""
    return "t = " + ", ".join(parts) + more


def _total(stretches: list[tuple]) -> str:
    return f"{sum((s[1] - s[0]) * 1e-9 for s in stretches):.1f} s"


def weakest_structure(points: np.ndarray, k: int = 2, min_len: float = 0.1, max_gap: float = 0.5) -> float:
    """How many points' worth of surface normal a scan has along its weakest direction: the smaller eigenvalue of
    Σ n·nᵀ over the points' normals (each from the chord between the points k before and k after, in beam order;
    chords shorter than `min_len` or across a gap over `max_gap` are skipped). Near 0: nothing fixes the position
    along some direction (a corridor's axis)."""
    p = np.asarray(points, float)
    if len(p) < 2 * k + 2:
        return 0.0
    chord = p[2 * k:] - p[:-2 * k]
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    gaps = np.lib.stride_tricks.sliding_window_view(step, 2 * k).max(axis=1)
    length = np.linalg.norm(chord, axis=1)
    ok = (gaps <= max_gap) & (length >= min_len)
    if not ok.any():
        return 0.0
    n = np.column_stack((-chord[ok, 1], chord[ok, 0])) / length[ok, None]
    return float(np.linalg.eigvalsh(n.T @ n)[0])


def _moved(a: np.ndarray | None, b: np.ndarray | None, still_m: float, still_rad: float) -> bool:
    """The wheel odometry moved between two poses by more than `still_m` or `still_rad`, or cannot tell (no
    odometry). A logger that pauses while the robot stands or creeps (the Intel log: 46 gaps of 2–3 s across which
    the wheels moved 0–12 cm) leaves nothing to report."""
    if a is None or b is None:
        return True
    return math.hypot(b[0] - a[0], b[1] - a[1]) > still_m or abs(math.remainder(b[2] - a[2], 2 * math.pi)) > still_rad


def _runs(ids: list[int]) -> list[list[int]]:
    """Consecutive integers grouped: [3, 4, 5, 9] → [[3, 4, 5], [9]]."""
    out: list[list[int]] = []
    for i in ids:
        if out and i == out[-1][-1] + 1:
            out[-1].append(i)
        else:
            out.append([i])
    return out
