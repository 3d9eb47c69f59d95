"""The Kinect Obstacle Scan (thesis Alg. 7), generalised: plane points → laser scans at several heights.

Points (plane points from FSPF+, or all valid depth points) are moved into `base_link` with the camera's mount,
kept when their height lies in a level's band, binned by bearing, and each bin keeps the nearest horizontal range
(the thesis; [kos] nearest = point) or, the default, the mean range of the nearest surface's points (nearest =
surface: KosAccumulator). Several cameras accumulate into the same bins. Written by hand (no library bins a cloud
into several height bands in one pass) and compiled with numba.

Two kernels give the same bins. `KosAccumulator.add` takes N×3 points (any cloud; the reference: kos_points.py).
The pipeline's `KosAccumulator.add_depth` takes the depth image (and FSPF+'s plane pixels) and works from per-pixel
tables memoised per (camera, mount, bin grid) (kos_image.py; docs/bench/kos.md has the numbers). The bins and the
cameras' views over them are in kos_bins.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.frontend.kos_bins import (Bearings, BearingTable, PixelTable, bearing_table, bearings_for, camera_view,
                                      check_camera, in_view, pixel_table, view_centre)
from kosmap.frontend.kos_image import ImageGrid, _accumulate_image, _surface_rule, image_buffers, pixel_mask
from kosmap.frontend.kos_points import PointGrid, _nearest_points, _surface_points, point_bins
from kosmap.frontend.params import StageConfig, param
from kosmap.frontend.records import CameraModel, Scan, Transform

__all__ = ["FUSED", "OBSTACLE", "Bearings", "KosAccumulator", "KosConfig", "bearings_for", "camera_view",
           "check_camera", "fuse_with_laser", "in_view", "level_name"]
_F = np.float32

OBSTACLE = "obstacle"
FUSED = "fused"


@dataclass
class KosConfig(StageConfig):
    """[kos]: levels are heights above the floor in base_link, each band (level ± band, ±0.1 m as in the thesis)
    within the obstacle scan's heights."""

    section = "kos"
    levels: list = param([0.3, 0.75, 1.5], doc="scan heights above the floor, each ± band within obstacle_min..obstacle_max", unit="m")
    band: float = param(0.1, lo=0.0, lo_open=True, doc="half height of each level's band", unit="m")
    obstacle_min: float = param(0.05, doc="obstacle scan: lowest point height", unit="m")
    obstacle_max: float = param(1.9, doc="obstacle scan: highest point height", unit="m")
    angle_increment_deg: float = param(0.0, lo=0.0, doc="bearing bin width; 0 = one bin per image column", unit="deg")
    source: str = param("planes", choices=("planes", "depth"), doc="plane points (thesis) or all valid depth points")
    nearest: str = param("surface", choices=("point", "surface"), doc="what a bin keeps: the nearest point (thesis "
                         "Alg. 7; the depth noise puts it 2-3 σ short) or the mean range of its nearest surface's "
                         "points (those within one plane band of the nearest point, 2·tail_eps·ε of [fspf])")

    def __post_init__(self) -> None:
        super().__post_init__()
        from kosmap.frontend.errors import ConfigError

        if self.obstacle_max <= self.obstacle_min:
            raise ConfigError(f"config [kos] obstacle_max = {self.obstacle_max} must be above obstacle_min = {self.obstacle_min}")
        self._check_levels()

    def _check_levels(self) -> None:
        """Each level once, its band (level ± band) between obstacle_min and obstacle_max: below obstacle_min lies
        the floor, and a band the camera never reaches gives a map of nothing but free cells."""
        from kosmap.frontend.errors import ConfigError

        lo, hi = self.obstacle_min + self.band, self.obstacle_max - self.band
        eps = 1e-9  # 0.15 − 0.1 < 0.05 in floats
        thesis = [0.3, 0.75, 1.5]
        span = f"give heights from {lo:g} to {hi:g} m" + (", e.g. [0.3, 0.75, 1.5]" if lo - eps <= min(thesis) and
                                                          max(thesis) <= hi + eps else "")
        if not self.levels:
            raise ConfigError(f"config [kos] levels = [] is empty: {span} (heights above the floor, a scan and a map "
                              f"each)")
        names = [level_name(h) for h in self.levels]
        dup = next((n for n in names if names.count(n) > 1), None)
        if dup is not None:
            same = sorted({h for h, n in zip(self.levels, names) if n == dup})
            if len(same) == 1:
                raise ConfigError(f"config [kos] levels = {self.levels} repeats {same[0]:g} m: give each height once "
                                  f"(a scan and a map each)")
            raise ConfigError(f"config [kos] levels = {self.levels} has {' and '.join(f'{h:g}' for h in same)} m, both "
                              f"named {dup} (levels are named to the centimetre): give heights at least 1 cm apart")
        if lo > hi + eps:
            raise ConfigError(f"config [kos] band = {self.band:g} m is too wide: a level's band (level ± band) must "
                              f"fit between obstacle_min = {self.obstacle_min:g} and obstacle_max = {self.obstacle_max:g} m")
        for h in self.levels:
            if h <= 0:
                raise ConfigError(f"config [kos] levels: {h:g} m is not above the floor (levels are heights above it, "
                                  f"in base_link): {span}")
            if h - self.band < self.obstacle_min - eps:
                raise ConfigError(f"config [kos] levels: {h:g} m ± band {self.band:g} m reaches below obstacle_min = "
                                  f"{self.obstacle_min:g} m, into the floor: {span}, or narrow [kos] band")
            if h + self.band > self.obstacle_max + eps:
                raise ConfigError(f"config [kos] levels: {h:g} m ± band {self.band:g} m reaches above obstacle_max = "
                                  f"{self.obstacle_max:g} m, the top of the obstacle scan: {span}, or raise [kos] "
                                  f"obstacle_max")

    def bands(self) -> list[tuple[str, float, float]]:
        """(name, lowest, highest) height of each level, then of the obstacle scan."""
        out = [(level_name(h), h - self.band, h + self.band) for h in self.levels]
        return out + [(OBSTACLE, self.obstacle_min, self.obstacle_max)]


def level_name(height: float) -> str:
    """Topic-safe name of a level: 0.75 m → 'h0_75' (/kinect_scan/h0_75)."""
    return "h" + f"{height:.2f}".replace(".", "_").replace("-", "m")


class KosAccumulator:
    """Bins the points of one time step (from one or more cameras) into every level at once.

    The surface rule (`window` > 0): thesis Alg. 7 keeps each bin's nearest point, but a bin holds many noisy
    points of the same surface (a wall 2 m away fills ~37 pixels of a 0.2 m band), and the least of N noisy
    samples lies ~σ·E[max of N normals] short (2–3 σ): measured on the simulated office's Kinect v2 noise, 0.5 %
    of the range short, growing with range as σ does, and scans matched to each other shrink the distance driven
    (KOS SLAM's front end free along-track on the harsh simulated office: odometry scale +0.71 % too large, +0.15 %
    with this rule). Each bin then keeps the mean of the ranges within `window` of its nearest range (the nearest
    surface's points; a nearer obstacle still wins, a farther one within the window is averaged in): the image kernel
    keeps the points of its nearest-range pass and sums them per column against the nearest ranges it found
    (kos_image._surface_rule), the point kernel keeps each point's bin, range and height. Cameras added in turn keep, per bin, the nearest of their means (as kosframe.merge_cameras).
    The default ([kos] nearest = surface, kosframe.surface_window); `window` 0 keeps the nearest point. KOS SLAM's
    front end, free along-track where the scan fixes it, needs the unbiased scans (docs/benchmarks.md, KOS SLAM with
    harsh wheel odometry).
    """

    def __init__(self, cfg: KosConfig, bearings: Bearings, min_range: float, max_range: float,
                 window: float = 0.0) -> None:
        self.names = [b[0] for b in cfg.bands()]
        self.lo = np.array([b[1] for b in cfg.bands()], np.float64)
        self.hi = np.array([b[2] for b in cfg.bands()], np.float64)
        self._lo32, self._hi32 = self.lo.astype(np.float32), self.hi.astype(np.float32)
        self.bearings = bearings
        self.min_range, self.max_range = float(min_range), float(max_range)
        self._ranges = np.full((len(self.names), bearings.n), np.inf, np.float32)  # `add`: nearest range
        self._r2 = np.full((bearings.n, len(self.names)), np.inf, np.float32)  # `add_depth`: nearest squared range
        self.window = float(window)  # the surface rule's window (m); 0: the nearest point

    @property
    def ranges(self) -> np.ndarray:
        """(bands × bins) float32 nearest horizontal range, +inf empty: levels in config order, then the obstacle scan."""
        r = np.sqrt(self._r2.T)
        np.minimum(r, self._ranges, out=r)
        return r

    def reset(self) -> None:
        self._ranges.fill(np.inf)
        self._r2.fill(np.inf)

    def _table(self, m: np.ndarray, view_half: float) -> BearingTable:
        return bearing_table(self.bearings, *view_centre(m, view_half))

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
        g = PointGrid(tb.cos_c, tb.sin_c, tb.t_min, tb.scale, tb.first, tb.tan_edges, tb.bin0, b.n, b.full_circle,
                      self.min_range * self.min_range, self.max_range * self.max_range)
        bins, rs, zs = point_bins(pts, m[:3, :3].copy(), m[:3, 3].copy(), self.lo, self.hi, g)
        if self.window <= 0:
            _nearest_points(bins, rs, zs, self.lo, self.hi, self._ranges)
            return
        near = np.full_like(self._ranges, np.inf)
        _nearest_points(bins, rs, zs, self.lo, self.hi, near)
        total, count = np.zeros(near.shape), np.zeros(near.shape, np.int64)
        _surface_points(bins, rs, zs, self.lo, self.hi, near.astype(np.float64) + self.window, total, count)
        np.minimum(self._ranges, _mean(total, count), out=self._ranges)

    def add_depth(self, depth: np.ndarray, camera: CameraModel, mount: Transform, pixels: np.ndarray | None = None,
                  min_depth: float | None = None, max_depth: float | None = None) -> None:
        """Add a depth image (metres, H×W; 0 / NaN invalid) seen by `camera` on `mount` (base_link ← optical frame).

        Every pixel with min_depth < d ≤ max_depth (default: the accumulator's range limits) is a point, or only
        the N×2 (row, col) `pixels` (FSPF+'s `Planes.pixels`). Same bins as `add` on the back-projected points
        (tests/frontend/test_kos_lut.py), through per-pixel tables memoised per camera, mount and bin grid.
        """
        img = np.asarray(depth, np.float32)
        if img.ndim != 2 or img.shape != (camera.height, camera.width):
            raise ValueError(f"KOS needs a {camera.height}×{camera.width} depth image, got shape {img.shape}")
        mask = pixel_mask(img.shape, pixels)
        g = self.image_grid(camera, mount, min_depth, max_depth)
        img = np.ascontiguousarray(img)
        if self.window <= 0:
            _accumulate_image(img, mask, g, self._lo32, self._hi32, self._r2,
                              image_buffers(img.shape, len(self.names), False))
        else:  # every block's points kept for the surface pass
            _surface_rule(img, mask, g, self._lo32, self._hi32, _F(self.window),
                          image_buffers(img.shape, len(self.names), True), self._r2)

    def image_grid(self, camera: CameraModel, mount: Transform, min_depth: float | None = None,
                   max_depth: float | None = None) -> ImageGrid:
        """The image kernels' tables for `camera` on `mount`: per-pixel rays (memoised), the bin grid and the depth
        and range limits (default: the accumulator's)."""
        tb = self._pixel_table(camera, mount)
        dmin = self.min_range if min_depth is None else float(min_depth)
        dmax = self.max_range if max_depth is None else float(max_depth)
        b = self.bearings
        tx, ty, tz = tb.t
        return ImageGrid(tb.ax, tb.ay, tb.az, tb.bx, tb.by, tb.bz, tx, ty, tz, tb.a0, 1.0 / b.angle_increment,
                         tb.n_local, tb.bin0, b.n, b.full_circle, _F(dmin), _F(dmax), _F(self.min_range ** 2),
                         _F(self.max_range ** 2))

    def _pixel_table(self, camera: CameraModel, mount: Transform) -> PixelTable:
        intrinsics = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        return pixel_table(intrinsics, tuple(float(v) for v in mount.translation),
                            tuple(float(v) for v in mount.rotation), self.bearings)

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


def _mean(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    """float32 total / count, +inf where nothing was counted."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.inf).astype(np.float32)


def fuse_with_laser(laser: Scan, laser_mount: Transform | np.ndarray, obstacle: Scan,
                    topic: str = "/kinect_scan/" + FUSED) -> Scan:
    """Thesis future work: per laser beam, the nearer of the laser and the KOS obstacle scan; laser elsewhere.

    The obstacle scan's end points (base_link) are re-binned into the laser's beams from the laser's origin,
    so tables and overhangs the laser passes under appear in the fused scan. `laser_mount`: base_link ← laser, or
    its 4×4 matrix (a caller fusing every step makes it once: Transform.matrix() was half of this function's time).
    """
    ok = np.isfinite(obstacle.ranges)
    r = obstacle.ranges[ok].astype(np.float64)
    a = obstacle.angles[ok]
    pts = np.column_stack((r * np.cos(a), r * np.sin(a), np.zeros_like(r)))
    m = laser_mount if isinstance(laser_mount, np.ndarray) else laser_mount.matrix()  # base_link ← laser; its
    # inverse applied as Rᵀ(p − t) (inverse() cost ~1 ms a step)
    local = (pts - m[:3, 3]) @ m[:3, :3]
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