"""The Kinect Obstacle Scan (thesis Alg. 7), generalised: plane points → laser scans at several heights.

Points (plane points from FSPF+, or all valid depth points) are moved into `base_link` with the camera's
mount, kept when their height lies in a level's band, binned by bearing, and each bin keeps the nearest
horizontal range. Several cameras accumulate into the same bins. Written by hand (no library bins a
cloud into several height bands in one pass); the pass is compiled with numba because the height test
over ~140k points per frame dominates (STACK.md: numpy `minimum.at` 3.7–4.1 ms, numba < 1 ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from frontend.params import StageConfig, param
from frontend.records import CameraModel, Scan, Transform

OBSTACLE = "obstacle"
FUSED = "fused"


@dataclass
class KosConfig(StageConfig):
    """[kos]: levels are heights above the floor in base_link; band ±0.1 m as in the thesis."""

    section = "kos"
    levels: list = param([0.3, 0.75, 1.5], doc="scan heights above the floor", unit="m")
    band: float = param(0.1, lo=0.0, lo_open=True, doc="half height of each level's band", unit="m")
    obstacle_min: float = param(0.05, doc="obstacle scan: lowest point height", unit="m")
    obstacle_max: float = param(1.9, doc="obstacle scan: highest point height", unit="m")
    angle_increment_deg: float = param(0.0, lo=0.0, doc="bearing bin width; 0 = one bin per image column", unit="deg")
    source: str = param("planes", choices=("planes", "depth"), doc="plane points (thesis) or all valid depth points")

    def __post_init__(self) -> None:
        super().__post_init__()
        from frontend.errors import ConfigError

        if self.obstacle_max <= self.obstacle_min:
            raise ConfigError(f"config [kos] obstacle_max = {self.obstacle_max} must be above obstacle_min = {self.obstacle_min}")

    def bands(self) -> list[tuple[str, float, float]]:
        """(name, lowest, highest) height of each level, then of the obstacle scan."""
        out = [(level_name(h), h - self.band, h + self.band) for h in self.levels]
        return out + [(OBSTACLE, self.obstacle_min, self.obstacle_max)]


def level_name(height: float) -> str:
    """Topic-safe name of a level: 0.75 m → 'h0_75' (/kinect_scan/h0_75)."""
    return "h" + f"{height:.2f}".replace(".", "_").replace("-", "m")


@dataclass(frozen=True)
class Bearings:
    """Bins of a scan in base_link: bin i is centred on angle_min + i·angle_increment."""

    angle_min: float
    angle_increment: float
    n: int
    full_circle: bool = False

    def centres(self) -> np.ndarray:
        return self.angle_min + np.arange(self.n) * self.angle_increment


def camera_view(camera: CameraModel, mount: Transform) -> tuple[float, float]:
    """(rightmost, leftmost) bearing in base_link of the camera's first and last column centres."""
    axis = mount.matrix()[:3, :3] @ np.array([0.0, 0.0, 1.0])  # optical z: the viewing direction
    yaw = math.atan2(axis[1], axis[0])
    right = math.atan((camera.width - 1 - camera.cx) / camera.fx)  # optical x points right: last column is rightmost
    left = math.atan(camera.cx / camera.fx)
    return yaw - right, yaw + left


def bearings_for(cameras: list[tuple[CameraModel, Transform]], increment_deg: float = 0.0) -> Bearings:
    """One bin per image column over a camera's view (the thesis); several cameras share a full circle."""
    views = [camera_view(c, m) for c, m in cameras]
    widths = [c.width for c, _ in cameras]
    if increment_deg > 0:
        inc = math.radians(increment_deg)
    else:
        inc = min((hi - lo) / (w - 1) for (lo, hi), w in zip(views, widths))
    if len(cameras) == 1:
        lo, hi = views[0]
        n = int(round((hi - lo) / inc)) + 1
        return Bearings(lo, inc, n)
    n = int(math.ceil(2 * math.pi / inc))
    return Bearings(-math.pi, 2 * math.pi / n, n, full_circle=True)


def in_view(bearings: Bearings, cameras: list[tuple[CameraModel, Transform]]) -> np.ndarray:
    """Bins that some camera sees (others are NaN in the scans: no measurement, REP 117)."""
    a = bearings.centres()
    seen = np.zeros(bearings.n, bool)
    half = bearings.angle_increment / 2
    for c, m in cameras:
        lo, hi = camera_view(c, m)
        d_lo = np.angle(np.exp(1j * (a - lo)))
        d_hi = np.angle(np.exp(1j * (hi - a)))
        seen |= (d_lo >= -half) & (d_hi >= -half)
    return seen


@dataclass(frozen=True)
class _BearingTable:
    """Bearing bins as a lookup on the tangent y'/x' in a frame turned to a camera's view centre.

    atan2 per point cost ~60 % of the pass (STACK.md: "bearing from a tangent lookup instead of atan2"); bins
    are uniform in angle, so a uniform table over the tangent gives a first guess that one or two edge
    comparisons correct.
    """

    cos_c: float
    sin_c: float
    t_min: float
    scale: float
    first: np.ndarray  # first candidate local bin per table cell
    tan_edges: np.ndarray  # lower edge of each local bin, then the upper edge of the last
    bin0: int  # global index of local bin 0


@lru_cache(maxsize=32)
def _bearing_table(b: Bearings, centre: float, half_width: float) -> _BearingTable:
    """Table for the global bins whose centres lie within ±half_width (< 90°) of `centre`.

    Memoised: the pipeline makes an accumulator per frame, and building the table costs ~0.3 ms."""
    rel = np.angle(np.exp(1j * (b.centres() - centre)))
    if b.full_circle:
        i0 = int(np.floor((centre - half_width - b.angle_min) / b.angle_increment + 0.5))
        i1 = int(np.floor((centre + half_width - b.angle_min) / b.angle_increment + 0.5))
        idx = np.arange(i0, i1 + 1)
        rel = b.angle_min + idx * b.angle_increment - centre
    else:
        idx = np.flatnonzero(np.abs(rel) <= half_width)
        if idx.size == 0:
            idx = np.array([0])
        idx = np.arange(idx[0], idx[-1] + 1)
        rel = rel[idx]
    edges = np.concatenate((rel - b.angle_increment / 2, rel[-1:] + b.angle_increment / 2))
    tan_edges = np.tan(np.clip(edges, -1.55, 1.55))
    m = 8 * len(idx)
    t_min, t_max = float(tan_edges[0]), float(tan_edges[-1])
    cells = t_min + np.arange(m) * (t_max - t_min) / m
    first = np.clip(np.searchsorted(tan_edges, cells, side="right") - 1, 0, len(idx) - 1).astype(np.int64)
    return _BearingTable(math.cos(centre), math.sin(centre), t_min, m / (t_max - t_min), first, tan_edges, int(idx[0]))


@njit(cache=True)
def _accumulate(pts, R, t, lo, hi, cos_c, sin_c, t_min, scale, first, tan_edges, bin0, n, full_circle, rmin, rmax,
                out):  # pragma: no cover - compiled
    """Thesis Alg. 7 for all levels in one pass: transform, height test, bearing bin, nearest range."""
    n_lev = lo.shape[0]
    zmin = lo.min()
    zmax = hi.max()
    rmin2 = rmin * rmin
    rmax2 = rmax * rmax
    m = first.shape[0]
    n_local = tan_edges.shape[0] - 1
    for i in range(pts.shape[0]):
        px = pts[i, 0]
        py = pts[i, 1]
        pz = pts[i, 2]
        z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        if not (z >= zmin and z <= zmax):  # also drops NaN points
            continue
        x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        r2 = x * x + y * y
        if r2 < rmin2 or r2 > rmax2:
            continue
        xc = x * cos_c + y * sin_c
        if xc <= 0.0:
            continue
        tt = (y * cos_c - x * sin_c) / xc
        j = int((tt - t_min) * scale)
        if j < 0 or j >= m:
            continue
        k = first[j]
        while k + 1 < n_local and tt >= tan_edges[k + 1]:
            k += 1
        b = bin0 + k
        if full_circle:
            b = b % n
        elif b < 0 or b >= n:
            continue
        r = math.sqrt(r2)
        for lev in range(n_lev):
            if z >= lo[lev] and z <= hi[lev] and r < out[lev, b]:
                out[lev, b] = r


class KosAccumulator:
    """Bins the points of one time step (from one or more cameras) into every level at once."""

    def __init__(self, cfg: KosConfig, bearings: Bearings, min_range: float, max_range: float) -> None:
        self.names = [b[0] for b in cfg.bands()]
        self.lo = np.array([b[1] for b in cfg.bands()], np.float64)
        self.hi = np.array([b[2] for b in cfg.bands()], np.float64)
        self.bearings = bearings
        self.min_range, self.max_range = float(min_range), float(max_range)
        self.ranges = np.full((len(self.names), bearings.n), np.inf, np.float32)

    def reset(self) -> None:
        self.ranges.fill(np.inf)

    def _table(self, m: np.ndarray, view_half: float) -> _BearingTable:
        axis = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
        # ±10° beyond the view: points seen near its edge from a camera mounted off base_link's origin
        half = min(view_half + math.radians(10.0), math.radians(85.0))
        return _bearing_table(self.bearings, float(math.atan2(axis[1], axis[0])), float(half))

    def add(self, points: np.ndarray, mount: Transform, view_half: float = math.radians(40.0)) -> None:
        """Add N×3 points given in the frame `mount` maps into base_link (a camera's optical frame, z forward).

        `view_half` is half the camera's horizontal field of view (camera_view gives it).
        """
        pts = np.ascontiguousarray(points, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"KOS needs N×3 points, got shape {pts.shape}")
        m = mount.matrix()
        tb = self._table(m, view_half)
        b = self.bearings
        _accumulate(pts, m[:3, :3].copy(), m[:3, 3].copy(), self.lo, self.hi, tb.cos_c, tb.sin_c, tb.t_min, tb.scale,
                    tb.first, tb.tan_edges, tb.bin0, b.n, b.full_circle, self.min_range, self.max_range, self.ranges)

    def scans(self, stamp_ns: int, seen: np.ndarray | None = None, frame_id: str = "base_link",
              topic_prefix: str = "/kinect_scan/") -> dict[str, Scan]:
        """One Scan per level and the obstacle scan; bins outside every camera's view are NaN."""
        out = {}
        b = self.bearings
        for k, name in enumerate(self.names):
            r = self.ranges[k].copy()
            if seen is not None:
                r[~seen] = np.nan
            out[name] = Scan(stamp_ns, r, b.angle_min, b.angle_increment, self.min_range, self.max_range,
                             frame_id, topic_prefix + name)
        return out


def fuse_with_laser(laser: Scan, laser_mount: Transform, obstacle: Scan, topic: str = "/kinect_scan/" + FUSED) -> Scan:
    """Thesis future work: per laser beam, the nearer of the laser and the KOS obstacle scan; laser elsewhere.

    The obstacle scan's end points (base_link) are re-binned into the laser's beams from the laser's origin,
    so tables and overhangs the laser passes under appear in the fused scan.
    """
    ok = np.isfinite(obstacle.ranges)
    r = obstacle.ranges[ok].astype(np.float64)
    a = obstacle.angles[ok]
    pts = np.column_stack((r * np.cos(a), r * np.sin(a), np.zeros_like(r)))
    local = laser_mount.inverse().apply(pts)
    fused = laser.ranges.astype(np.float32).copy()
    if len(local):
        rr = np.hypot(local[:, 0], local[:, 1]).astype(np.float32)
        beam = np.floor((np.arctan2(local[:, 1], local[:, 0]) - laser.angle_min) / laser.angle_increment + 0.5).astype(np.int64)
        keep = (beam >= 0) & (beam < len(fused)) & (rr >= laser.range_min)
        kos = np.full(len(fused), np.inf, np.float32)
        np.minimum.at(kos, beam[keep], rr[keep])
        laser_ok = laser.valid()
        closer = np.isfinite(kos) & (~laser_ok | (kos < fused))
        fused[closer] = kos[closer]
    return Scan(laser.stamp_ns, fused, laser.angle_min, laser.angle_increment, laser.range_min, laser.range_max,
                laser.frame_id, topic)
