"""The Kinect Obstacle Scan (thesis Alg. 7), generalised: plane points → laser scans at several heights.

Points (plane points from FSPF+, or all valid depth points) are moved into `base_link` with the camera's mount,
kept when their height lies in a level's band, binned by bearing, and each bin keeps the nearest horizontal range
(the thesis; [kos] nearest = point) or, the default, the mean range of the nearest surface's points (nearest =
surface: KosAccumulator). Several cameras accumulate into the same bins. Written by hand (no library bins a cloud
into several height bands in one pass) and compiled with numba.

Two kernels give the same bins. `KosAccumulator.add` takes N×3 points (any cloud; the reference). The
pipeline's `KosAccumulator.add_depth` takes the depth image (and FSPF+'s plane pixels) and works from
per-pixel tables memoised per (camera, mount, bin grid): base_link = d·(column term + row term) + mount
offset, a branch-free float32 pass over each image row that numba vectorises, then, per block of rows, the
nearest range of each column per bin and band, so one bin update stands for a whole column of the block
(docs/bench/kos.md has the numbers).
"""

from __future__ import annotations

import math
import threading
from collections import namedtuple
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from kosmap.frontend.params import StageConfig, param
from kosmap.frontend.records import CameraModel, Scan, Transform

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


@dataclass(frozen=True)
class Bearings:
    """Bins of a scan in base_link: bin i is centred on angle_min + i·angle_increment."""

    angle_min: float
    angle_increment: float
    n: int
    full_circle: bool = False

    def centres(self) -> np.ndarray:
        return self.angle_min + np.arange(self.n) * self.angle_increment


def check_camera(camera: CameraModel) -> None:
    """LogError when the intrinsics cannot place a column's bearing (a 1×1 image, a focal length that is not a
    positive number, a principal point far outside the image: frontend/logs/validate.py); the readers skip such
    records, this keeps the stage itself from dividing by them."""
    from kosmap.frontend.errors import LogError
    from kosmap.frontend.logs.validate import camera_problem

    why = camera_problem(camera)
    if why is not None:
        name = camera.topic or camera.frame_id or "the depth camera"
        raise LogError(f"{name}: the KOS cannot use a camera with {why}; fix its CameraInfo, or leave it out so that "
                       f"[depth] fov_h_deg, fov_v_deg serve")


def camera_view(camera: CameraModel, mount: Transform) -> tuple[float, float]:
    """(rightmost, leftmost) bearing in base_link of the camera's first and last column centres."""
    check_camera(camera)
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

    atan2 per point cost ~60 % of the pass (docs/dependencies.md: "bearing from a tangent lookup instead of atan2"); bins
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


def _view_centre(m: np.ndarray, view_half: float) -> tuple[float, float]:
    """Bearing of a camera's optical axis in base_link (4×4 mount `m`) and the half width of the bins it can fill:
    ±10° beyond the view, for points seen near its edge from a camera mounted off base_link's origin."""
    axis = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
    return float(math.atan2(axis[1], axis[0])), float(min(view_half + math.radians(10.0), math.radians(85.0)))


# The kernels' parameters, one record each: the bearing grid and range limits of `add` (PointGrid), and the
# per-pixel tables, bearing grid and depth and range limits of `add_depth` (ImageGrid)
PointGrid = namedtuple("PointGrid", "cos_c sin_c t_min scale first tan_edges bin0 n full_circle rmin2 rmax2")
ImageGrid = namedtuple("ImageGrid", "ax ay az bx by bz tx ty tz a0 inv_inc n_local bin0 n full_circle dmin dmax rmin2 "
                                    "rmax2")


@njit(cache=True, error_model="numpy", inline="always")
def _to_base(R, t, px, py, pz):  # pragma: no cover - compiled
    """A point of the camera's frame in base_link (the mount R, t)."""
    x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
    y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
    z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
    return x, y, z


@njit(cache=True, error_model="numpy")
def _bearing_bin(x, y, g):  # pragma: no cover - compiled
    """The global bearing bin of (x, y) from the tangent table of _BearingTable; −1 outside the grid or behind."""
    xc = x * g.cos_c + y * g.sin_c
    if xc <= 0.0:
        return -1
    tt = (y * g.cos_c - x * g.sin_c) / xc
    fj = (tt - g.t_min) * g.scale
    if not (fj >= 0.0 and fj < g.first.shape[0]):  # (int() truncates towards 0: test before, or bin 0 takes 1/8 bin too much)
        return -1
    k = g.first[int(fj)]
    while k + 1 < g.tan_edges.shape[0] - 1 and tt >= g.tan_edges[k + 1]:
        k += 1
    b = g.bin0 + k
    if g.full_circle:
        return b % g.n
    return b if 0 <= b < g.n else -1


@njit(cache=True, error_model="numpy", inline="always")
def _keep_nearest(out, lo, hi, z, b, r):  # pragma: no cover - compiled
    """scan[b] ← min(scan[b], r) for every level whose band holds the height z."""
    for lev in range(lo.shape[0]):
        if z >= lo[lev] and z <= hi[lev] and r < out[lev, b]:
            out[lev, b] = r


@njit(cache=True)
def _accumulate(pts, R, t, lo, hi, g, out):  # pragma: no cover - compiled
    """Thesis Alg. 7 for all levels in one pass: each point into base_link, its height tested against the bands,
    its bearing binned, and each bin keeps the nearest horizontal range. g: PointGrid."""
    zmin = lo.min()
    zmax = hi.max()
    for i in range(pts.shape[0]):
        x, y, z = _to_base(R, t, pts[i, 0], pts[i, 1], pts[i, 2])
        if not (z >= zmin and z <= zmax):  # in some level's band (also drops NaN points)
            continue
        r2 = x * x + y * y
        if r2 < g.rmin2 or r2 > g.rmax2:
            continue
        b = _bearing_bin(x, y, g)
        if b >= 0:
            _keep_nearest(out, lo, hi, z, b, math.sqrt(r2))


@njit(cache=True)
def _surface_points(pts, R, t, lo, hi, g, lim, s, c):  # pragma: no cover - compiled
    """The second pass of `_accumulate` (the surface rule: KosAccumulator): per level and bin, the sum `s` and count
    `c` of the ranges no farther than `lim` (levels × bins), the nearest range plus the surface window."""
    zmin = lo.min()
    zmax = hi.max()
    for i in range(pts.shape[0]):
        x, y, z = _to_base(R, t, pts[i, 0], pts[i, 1], pts[i, 2])
        if not (z >= zmin and z <= zmax):
            continue
        r2 = x * x + y * y
        if r2 < g.rmin2 or r2 > g.rmax2:
            continue
        b = _bearing_bin(x, y, g)
        if b < 0:
            continue
        r = math.sqrt(r2)
        for lev in range(lo.shape[0]):
            if z >= lo[lev] and z <= hi[lev] and r <= lim[lev, b]:
                s[lev, b] += r
                c[lev, b] += 1


# ---- the image kernel: per-pixel tables, vectorised rows, per-column reduction ------------------------------------

_ROWS = 8  # rows per block: one bin update per column and band stands for up to this many pixels
_NO_BIN = np.int32(1 << 30)
_F = np.float32
# Cephes atanf (S. Moshier): range reduction at tan(3π/8) and tan(π/8), then a degree-9 odd polynomial; ≤ 1.4e-7 rad
_T3P8, _TP8 = _F(2.414213562373095), _F(0.41421356237309503)
_PIO2, _PIO4 = _F(math.pi / 2), _F(math.pi / 4)
_A0, _A1, _A2, _A3 = _F(8.05374449538e-2), _F(-1.38776856032e-1), _F(1.99777106478e-1), _F(-3.33329491539e-1)


@njit(cache=True, error_model="numpy", inline="always")
def _atan2_front(y, x):  # pragma: no cover - compiled
    """atan2(y, x) for x > 0 in float32, branch-free so that a loop around it vectorises (no SVML here)."""
    ay = abs(y)
    big = ay > _T3P8 * x
    mid = ay > _TP8 * x
    num = -x if big else (ay - x if mid else ay)
    den = ay if big else (ay + x if mid else x)
    t = num / den
    base = _PIO2 if big else (_PIO4 if mid else _F(0.0))
    z = t * t
    a = base + ((((_A0 * z + _A1) * z + _A2) * z + _A3) * z * t + t)
    return -a if y < 0 else a


@njit(cache=True, error_model="numpy")
def _row_bins(drow, mrow, ax, ay, az, bx, by, bz, tx, ty, tz, a0, inv_inc, n_local, zmin, zmax, dmin, dmax, rmin2,
              rmax2, ks, r2s, zs):  # pragma: no cover - compiled
    """One image row, branch-free (numba vectorises it): local bin (−1: dropped), squared range and height per pixel.

    The point of pixel (u, v) at depth d in base_link, turned to the view centre, is t + d·(a[u] + b[v]): the
    column and row terms of the pinhole ray times the mount rotation (thesis eq. 2.1–2.2, then the mount).
    """
    for u in range(drow.shape[0]):
        d = drow[u] if mrow[u] else _F(0.0)
        z = tz + d * (az[u] + bz)
        x = tx + d * (ax[u] + bx)
        y = ty + d * (ay[u] + by)
        r2 = x * x + y * y
        fk = (np.float64(_atan2_front(y, x)) - a0) * inv_inc + 0.5
        ok = ((d > dmin) & (d <= dmax) & (z >= zmin) & (z <= zmax) & (r2 >= rmin2) & (r2 <= rmax2) & (x > 0)
              & (fk >= 0) & (fk < n_local))
        ks[u] = np.int32(fk) if ok else np.int32(-1)
        r2s[u] = r2
        zs[u] = z


@njit(cache=True, error_model="numpy")
def _column_bins(ks, kmin, kmax):  # pragma: no cover - compiled
    """Per column of a block: its lowest and highest local bin (kmax −1: nothing in the column)."""
    for u in range(ks.shape[1]):
        a = _NO_BIN
        b = np.int32(-1)
        for r in range(_ROWS):
            k = ks[r, u]
            a = min(a, k if k >= 0 else _NO_BIN)
            b = max(b, k)
        kmin[u] = a
        kmax[u] = b


@njit(cache=True, error_model="numpy")
def _column_band_min(ks, r2s, zs, lo, hi, kmin, kmax, m_lo, m_hi):  # pragma: no cover - compiled
    """Per column of a block, for one band: the nearest squared range among its points in the column's lowest
    and in its highest bin (vectorised over columns)."""
    inf = _F(np.inf)
    for u in range(ks.shape[1]):
        a = inf
        b = inf
        k0 = kmin[u]
        k1 = kmax[u]
        for r in range(_ROWS):
            k = ks[r, u]
            z = zs[r, u]
            v = r2s[r, u] if (z >= lo) & (z <= hi) else inf  # (k = −1, dropped, matches only a column without points)
            a = min(a, v if k == k0 else inf)
            b = min(b, v if k == k1 else inf)
        m_lo[u] = a
        m_hi[u] = b


@njit(cache=True, error_model="numpy")
def _global_bin(k, bin0, n, full_circle):  # pragma: no cover - compiled
    b = bin0 + k
    if full_circle:
        if b >= n:
            b -= n
        elif b < 0:
            b += n
    return b


@njit(cache=True, error_model="numpy")
def _column_scatter(ks, r2s, zs, lo, hi, kmin, kmax, m_lo, m_hi, bin0, n, full_circle, out2):  # pragma: no cover
    """Nearest range per bin and band: one update per column and bin; columns spread over > 2 bins point by point."""
    n_band = lo.shape[0]
    for u in range(ks.shape[1]):
        k1 = kmax[u]
        if k1 < 0:
            continue
        k0 = kmin[u]
        if k1 - k0 <= 1:
            b = _global_bin(k0, bin0, n, full_circle)
            for j in range(n_band):
                if m_lo[j, u] < out2[b, j]:
                    out2[b, j] = m_lo[j, u]
            if k1 != k0:
                b = _global_bin(k1, bin0, n, full_circle)
                for j in range(n_band):
                    if m_hi[j, u] < out2[b, j]:
                        out2[b, j] = m_hi[j, u]
            continue
        for r in range(_ROWS):
            k = ks[r, u]
            if k < 0:
                continue
            b = _global_bin(k, bin0, n, full_circle)
            z = zs[r, u]
            r2 = r2s[r, u]
            for j in range(n_band):
                if z >= lo[j] and z <= hi[j] and r2 < out2[b, j]:
                    out2[b, j] = r2


@njit(cache=True, error_model="numpy", inline="always")
def _block_buffers(w, n_band):  # pragma: no cover - compiled
    """A block's per-pixel local bins, squared ranges and heights (_ROWS × w), its columns' lowest and highest bin,
    and per band the columns' nearest squared range in those two bins."""
    return (np.empty((_ROWS, w), np.int32), np.empty((_ROWS, w), np.float32), np.empty((_ROWS, w), np.float32),
            np.empty(w, np.int32), np.empty(w, np.int32), np.empty((n_band, w), np.float32),
            np.empty((n_band, w), np.float32))


@njit(cache=True, error_model="numpy", inline="always")
def _block_points(depth, mask, v0, g, zmin, zmax, blk):  # pragma: no cover - compiled
    """The points of a block of rows from v0: each pixel's point in base_link, its height and range tested and its
    bearing binned (_row_bins); rows past the image's last are empty."""
    ks, r2s, zs = blk[0], blk[1], blk[2]
    rows = min(_ROWS, depth.shape[0] - v0)
    for r in range(rows):
        v = v0 + r
        _row_bins(depth[v], mask[v], g.ax, g.ay, g.az, g.bx[v], g.by[v], g.bz[v], g.tx, g.ty, g.tz, g.a0, g.inv_inc,
                  g.n_local, zmin, zmax, g.dmin, g.dmax, g.rmin2, g.rmax2, ks[r], r2s[r], zs[r])
    for r in range(rows, _ROWS):
        ks[r, :] = -1


@njit(cache=True, error_model="numpy", inline="always")
def _block_nearest(lo, hi, g, blk, out2):  # pragma: no cover - compiled
    """Each bin keeps the nearest squared range per band of the block's points: per column its lowest and highest
    bin, the column's nearest in each, then one update per column and bin."""
    ks, r2s, zs, kmin, kmax, m_lo, m_hi = blk
    _column_bins(ks, kmin, kmax)
    for j in range(lo.shape[0]):
        _column_band_min(ks, r2s, zs, lo[j], hi[j], kmin, kmax, m_lo[j], m_hi[j])
    _column_scatter(ks, r2s, zs, lo, hi, kmin, kmax, m_lo, m_hi, g.bin0, g.n, g.full_circle, out2)


@njit(cache=True, error_model="numpy")
def _accumulate_image(depth, mask, g, lo, hi, out2):  # pragma: no cover - compiled
    """Thesis Alg. 7 over the pixels of a depth image where `mask` is set (0 / NaN depths dropped), every band at
    once into out2 (bins × bands, squared ranges), in blocks of _ROWS rows: the block's points in base_link with
    their height and bearing bin, then each bin keeps the nearest range per band. g: ImageGrid."""
    blk = _block_buffers(depth.shape[1], lo.shape[0])
    zmin = lo.min()
    zmax = hi.max()
    for v0 in range(0, depth.shape[0], _ROWS):
        _block_points(depth, mask, v0, g, zmin, zmax, blk)
        _block_nearest(lo, hi, g, blk, out2)


@njit(cache=True, error_model="numpy")
def _surface_image(depth, mask, g, lo, hi, lim2, s, c):  # pragma: no cover - compiled
    """The second pass of `_accumulate_image` (the surface rule: KosAccumulator): per bin and band, the sum `s` and
    count `c` of the ranges whose square is no more than `lim2` (bins × bands), the nearest range plus the window."""
    blk = _block_buffers(depth.shape[1], lo.shape[0])
    ks, r2s, zs = blk[0], blk[1], blk[2]
    zmin = lo.min()
    zmax = hi.max()
    for v0 in range(0, depth.shape[0], _ROWS):
        _block_points(depth, mask, v0, g, zmin, zmax, blk)
        for r in range(_ROWS):
            for u in range(ks.shape[1]):
                k = ks[r, u]
                if k < 0:
                    continue
                b = _global_bin(k, g.bin0, g.n, g.full_circle)
                z = zs[r, u]
                r2 = r2s[r, u]
                for j in range(lo.shape[0]):
                    if z >= lo[j] and z <= hi[j] and r2 <= lim2[b, j]:
                        s[b, j] += math.sqrt(r2)
                        c[b, j] += 1


@njit(cache=True, error_model="numpy")
def _pixels_mask(pixels, mask):  # pragma: no cover - compiled
    """Set `mask` (H×W uint8) at the given pixels (N×2 row, col; e.g. FSPF+'s plane points); others stay as they are."""
    w = np.uint32(mask.shape[1])
    size = np.uint32(mask.size)
    dst = mask.ravel()
    for i in range(pixels.shape[0]):
        p = np.uint32(pixels[i, 0]) * w + np.uint32(pixels[i, 1])  # unsigned: no negative-index wrap test
        if p < size:  # (a pixel above or below the image is ignored)
            dst[p] = 1


_SCRATCH = threading.local()


def _mask(shape: tuple[int, int], pixels: np.ndarray | None) -> np.ndarray:
    """The pixels to use as a uint8 H×W mask: all (a shared array of ones) or those given (a per-thread buffer,
    reused: a fresh one costs its page faults). One of each per image shape (cameras may differ)."""
    cache = getattr(_SCRATCH, "masks", None)
    if cache is None:
        cache = _SCRATCH.masks = {}
    key = (pixels is None, tuple(shape))
    buf = cache.get(key)
    if buf is None:
        buf = cache[key] = np.ones(shape, np.uint8) if pixels is None else np.zeros(shape, np.uint8)
    elif pixels is not None:
        buf.fill(0)
    if pixels is not None:
        _pixels_mask(np.ascontiguousarray(pixels), buf)
    return buf


@dataclass(frozen=True)
class _PixelTable:
    """Per-pixel tables of one camera on one mount for one bin grid (see `_pixel_table`)."""

    ax: np.ndarray  # W float32: column term of the ray in base_link, turned to the view centre
    ay: np.ndarray
    az: np.ndarray
    bx: np.ndarray  # H float32: row term (plus the optical axis)
    by: np.ndarray
    bz: np.ndarray
    t: tuple  # mount offset in the same frame (float32 x, y, z)
    a0: float  # bearing of local bin 0's centre relative to the view centre
    n_local: int
    bin0: int  # global index of local bin 0


@lru_cache(maxsize=64)
def _pixel_table(intrinsics: tuple, translation: tuple, quaternion: tuple, b: Bearings) -> _PixelTable:
    """Tables for a camera (w, h, fx, fy, cx, cy) on a mount (base_link ← optical: translation, quaternion x y z w).

    The ray of pixel (u, v) is ((u − cx)/fx, (v − cy)/fy, 1); in base_link turned by −centre it is
    M·ray = (u − cx)/fx·M[:, 0] + ((v − cy)/fy·M[:, 1] + M[:, 2]): a column term plus a row term, so the tables
    are W + H entries (a full H×W×3 table costs 2.6 MB of memory traffic per frame; measured slower). The bins
    are those whose centres lie within the view ±10° (as `KosAccumulator._table` chooses for `add`). Memoised:
    the pipeline makes an accumulator per frame.
    """
    w, h, fx, fy, cx, cy = intrinsics
    mount = Transform("base_link", "optical", np.array(translation), np.array(quaternion))
    m = mount.matrix()
    view_half = (math.atan((w - 1 - cx) / fx) + math.atan(cx / fx)) / 2  # as camera_view
    centre, half_width = _view_centre(m, view_half)
    c, s = math.cos(centre), math.sin(centre)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    rot = turn @ m[:3, :3]
    col = np.outer((np.arange(w) - cx) / fx, rot[:, 0])
    row = np.outer((np.arange(h) - cy) / fy, rot[:, 1]) + rot[:, 2]
    t = turn @ m[:3, 3]
    if b.full_circle:
        i0 = int(np.floor((centre - half_width - b.angle_min) / b.angle_increment + 0.5))
        i1 = int(np.floor((centre + half_width - b.angle_min) / b.angle_increment + 0.5))
    else:
        rel = np.angle(np.exp(1j * (b.centres() - centre)))
        idx = np.flatnonzero(np.abs(rel) <= half_width)
        i0, i1 = (int(idx[0]), int(idx[-1])) if idx.size else (0, 0)
    a0 = float(np.angle(np.exp(1j * (b.angle_min + i0 * b.angle_increment - centre))))
    f = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    return _PixelTable(f(col[:, 0]), f(col[:, 1]), f(col[:, 2]), f(row[:, 0]), f(row[:, 1]), f(row[:, 2]),
                       tuple(np.float32(v) for v in t), a0, i1 - i0 + 1, i0)

class KosAccumulator:
    """Bins the points of one time step (from one or more cameras) into every level at once.

    The surface rule (`window` > 0): thesis Alg. 7 keeps each bin's nearest point, but a bin holds many noisy
    points of the same surface (a wall 2 m away fills ~37 pixels of a 0.2 m band), and the least of N noisy
    samples lies ~σ·E[max of N normals] short (2–3 σ): measured on the simulated office's Kinect v2 noise, 0.5 %
    of the range short, growing with range as σ does, and scans matched to each other shrink the distance driven
    (KOS SLAM's front end free along-track on the harsh simulated office: odometry scale +0.71 % too large, +0.15 %
    with this rule). Each image then takes two passes: the nearest range per bin, then the mean of the ranges within
    `window` of it (the nearest surface's points; a nearer obstacle still wins, a farther one within the window is
    averaged in). Cameras added in turn keep, per bin, the nearest of their means (as kosframe.merge_cameras).
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

    def _table(self, m: np.ndarray, view_half: float) -> _BearingTable:
        return _bearing_table(self.bearings, *_view_centre(m, view_half))

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
        R, t = m[:3, :3].copy(), m[:3, 3].copy()
        if self.window <= 0:
            _accumulate(pts, R, t, self.lo, self.hi, g, self._ranges)
            return
        near = np.full_like(self._ranges, np.inf)
        _accumulate(pts, R, t, self.lo, self.hi, g, near)
        total, count = np.zeros(near.shape), np.zeros(near.shape, np.int64)
        _surface_points(pts, R, t, self.lo, self.hi, g, near.astype(np.float64) + self.window, total, count)
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
        mask = _mask(img.shape, pixels)
        tb = self._pixel_table(camera, mount)
        dmin = self.min_range if min_depth is None else float(min_depth)
        dmax = self.max_range if max_depth is None else float(max_depth)
        b = self.bearings
        tx, ty, tz = tb.t
        g = ImageGrid(tb.ax, tb.ay, tb.az, tb.bx, tb.by, tb.bz, tx, ty, tz, tb.a0, 1.0 / b.angle_increment, tb.n_local,
                      tb.bin0, b.n, b.full_circle, _F(dmin), _F(dmax), _F(self.min_range ** 2), _F(self.max_range ** 2))
        img = np.ascontiguousarray(img)
        if self.window <= 0:
            _accumulate_image(img, mask, g, self._lo32, self._hi32, self._r2)
            return
        near2 = np.full_like(self._r2, np.inf)
        _accumulate_image(img, mask, g, self._lo32, self._hi32, near2)
        lim2 = np.square(np.sqrt(near2) + _F(self.window))
        total, count = np.zeros(near2.shape), np.zeros(near2.shape, np.int64)
        _surface_image(img, mask, g, self._lo32, self._hi32, lim2, total, count)
        np.minimum(self._r2, np.square(_mean(total, count)), out=self._r2)

    def _pixel_table(self, camera: CameraModel, mount: Transform) -> _PixelTable:
        intrinsics = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        return _pixel_table(intrinsics, tuple(float(v) for v in mount.translation),
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
