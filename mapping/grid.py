"""Occupancy grids: the shared grid type, and log-odds grids built from poses and scans."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from numba import njit

from kosmap.frontend import se2
from kosmap.frontend.deskew import deskew_points, sensor_twist
from kosmap.frontend.errors import KosmapError
from kosmap.frontend.params import StageConfig, param

MAX_CELLS = 200_000_000  # cells one grid may have: 1.6 GB of log-odds (float32) and stamps (int32)


class GridTooLarge(KosmapError):
    """A map that would need more than MAX_CELLS cells at its resolution."""


@dataclass
class GridConfig(StageConfig):
    """[grid]: resolution and the inverse sensor model."""

    section = "grid"
    resolution: float = param(0.05, lo=0.0, lo_open=True, doc="cell size", unit="m")
    deskew: bool = param(True, doc="de-skew a scan taken beam by beam (time_increment ≠ 0) with the twist between "
                         "consecutive poses")
    p_hit: float = param(0.7, lo=0.5, hi=1.0, lo_open=True, doc="occupancy probability of a beam's end cell")
    p_miss: float = param(0.4, lo=0.0, hi=0.5, doc="occupancy probability of a cell a beam passes")
    no_return_clear: float = param(4.0, lo=0.0, doc="beams without return clear free space this far", unit="m")
    max_range: float = param(0.0, lo=0.0, doc="returns beyond this range only clear free space up to it (0 = the scan's range_max)", unit="m")
    p_min: float = param(0.12, lo=0.0, hi=0.5, lo_open=True, doc="log-odds clamp: a cell's probability never drops below this")
    p_max: float = param(0.97, lo=0.5, hi=1.0, doc="log-odds clamp: a cell's probability never rises above this")


@dataclass
class OccupancyGrid:
    """nav_msgs/OccupancyGrid semantics: data[row, col] in −1 (unknown) or 0..100; row 0 is the map's bottom.

    `origin` is (x, y, yaw) of the lower-left corner of cell (0, 0) in the map frame, as in map_server.
    """

    data: np.ndarray  # H×W int8
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame_id: str = "map"

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """(col, row) integer cells of N×2 map points (origin yaw must be 0)."""
        return np.floor((np.asarray(xy) - np.asarray(self.origin[:2])) / self.resolution).astype(np.int64)

    def center_of(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Map coordinates (N×2) of cell centres (origin yaw must be 0)."""
        return np.column_stack((self.origin[0] + (np.asarray(cols) + 0.5) * self.resolution,
                                self.origin[1] + (np.asarray(rows) + 0.5) * self.resolution))

    def world_of(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Map coordinates (N×2) of cell centres, honouring the origin's yaw (maps from other tools may have one)."""
        u = (np.asarray(cols, float) + 0.5) * self.resolution
        v = (np.asarray(rows, float) + 0.5) * self.resolution
        c, s = np.cos(self.origin[2]), np.sin(self.origin[2])
        return np.column_stack((self.origin[0] + c * u - s * v, self.origin[1] + s * u + c * v))

    def pixel_to_world(self) -> np.ndarray:
        """3×3 affine taking (col, row, 1) of a cell's lower-left corner to map coordinates."""
        c, s = np.cos(self.origin[2]), np.sin(self.origin[2])
        r = self.resolution
        return np.array([[c * r, -s * r, self.origin[0]], [s * r, c * r, self.origin[1]], [0.0, 0.0, 1.0]])


# ---- log-odds grid from poses and scans ---------------------------------------------------------------------------

def _round_up(v: float) -> str:
    """`v` rounded up to two significant digits, as text (0.0123 → "0.013")."""
    e = math.floor(math.log10(v)) - 1
    return f"{math.ceil(v / 10 ** e) * 10 ** e:.{max(0, -e)}f}"


def _logit(p: float) -> float:
    return float(np.log(p / (1.0 - p)))


def _compose(pose, mount) -> tuple[float, float, float]:
    """pose ∘ mount for planar poses (x, y, yaw): the sensor's pose in the map frame."""
    x, y, th = (float(v) for v in pose)
    mx, my, mth = (float(v) for v in mount)
    c, s = np.cos(th), np.sin(th)
    return x + c * mx - s * my, y + s * mx + c * my, th + mth


def _crossings(p0: np.ndarray, p1: np.ndarray, c_start: np.ndarray, c_end: np.ndarray, ax: int) -> np.ndarray:
    """Cells entered where beams from p0 to p1 (cell units) cross grid lines normal to axis `ax`.

    The cell entered at the k-th crossing has index c_start[ax] ± k along `ax` and, along the other axis, the
    floor of the beam's coordinate there; with the start cell these are all the cells the beam passes (the
    order does not matter: each cell is updated once per scan).
    """
    o = 1 - ax
    d = c_end[:, ax] - c_start[ax]
    n = np.abs(d)
    if n.sum() == 0:
        return np.zeros((0, 2), np.int64)
    beam = np.repeat(np.arange(len(p1)), n)
    k = np.arange(beam.size) - np.repeat(np.cumsum(n) - n, n) + 1  # 1..n_i within each beam
    s = np.sign(d)[beam]
    line = c_start[ax] + np.where(s > 0, k, 1 - k)  # coordinate of the crossed grid line
    t = (line - p0[ax]) / (p1[beam, ax] - p0[ax])
    other = np.floor(p0[o] + t * (p1[beam, o] - p0[o])).astype(np.int64)
    lo = np.minimum(c_start[o], c_end[beam, o])
    hi = np.maximum(c_start[o], c_end[beam, o])
    out = np.empty((beam.size, 2), np.int64)
    out[:, ax] = c_start[ax] + s * k
    out[:, o] = np.clip(other, lo, hi)  # guard the floor against rounding at the ends
    return out


@njit(cache=True)
def _trace_numba(lo, stamp, sid, c0, r0, x0, y0, ex, ey, hit, l_hit, l_miss, l_min, l_max):
    """Per-beam Amanatides–Woo traversal in cell units from (x0, y0) to (ex[i], ey[i]); each cell updated once
    per scan (stamp = sid), hits first so that a hit beats a miss of another beam; no-return ends are free."""
    for i in range(ex.size):
        if hit[i]:
            r = int(np.floor(ey[i])) - r0
            c = int(np.floor(ex[i])) - c0
            if stamp[r, c] != sid:
                stamp[r, c] = sid
                lo[r, c] = min(max(lo[r, c] + l_hit, l_min), l_max)
    for i in range(ex.size):
        c, r = int(np.floor(x0)), int(np.floor(y0))
        ce, re = int(np.floor(ex[i])), int(np.floor(ey[i]))
        dx, dy = ex[i] - x0, ey[i] - y0
        sx = 1 if dx > 0 else -1
        sy = 1 if dy > 0 else -1
        tdx = abs(1.0 / dx) if dx != 0 else 1e300
        tdy = abs(1.0 / dy) if dy != 0 else 1e300
        tmx = ((c + (1 if sx > 0 else 0)) - x0) / dx if dx != 0 else 1e300
        tmy = ((r + (1 if sy > 0 else 0)) - y0) / dy if dy != 0 else 1e300
        n = abs(ce - c) + abs(re - r)
        for k in range(n + 1):
            if k == n and hit[i]:
                break  # the end cell took the hit
            rr, cc = r - r0, c - c0
            if stamp[rr, cc] != sid:
                stamp[rr, cc] = sid
                lo[rr, cc] = min(max(lo[rr, cc] + l_miss, l_min), l_max)
            if k == n:
                break
            if tmx < tmy:
                if c == ce:  # rounding: never step past the end cell's column
                    tmy += tdy
                    r += sy
                else:
                    tmx += tdx
                    c += sx
            elif r == re:
                tmx += tdx
                c += sx
            else:
                tmy += tdy
                r += sy


@njit(cache=True)
def _beam_ends(ranges, angle_min, inc, range_min, range_max, clear, max_range, sx, sy, sth, c, s, deskew, t_inc, vx,
               vy, w, res, ex, ey, hit):
    """GridBuilder.beams and the cell units of add_beams for one scan in one call, the same arithmetic in the same
    order (numpy's float64 cos and sin are the C library's, as numba's): the beams to trace into ex, ey, hit;
    returns their count and the cell bounds of their ends (empty bounds when none). Per scan the numpy path made
    ~40 array calls, ~0.2 ms: a third of the laser map's time and most of a KOS map's."""
    n = 0
    cmin = rmin = 1 << 62
    cmax = rmax = -(1 << 62)
    for i in range(ranges.shape[0]):
        r = np.float64(ranges[i])
        fin = math.isfinite(r)
        h = fin and r >= range_min and r < range_max
        no_return = r == math.inf or (fin and r >= range_max)  # REP 117; NaN / -inf / < min: ignored
        length = r if h else clear
        if max_range > 0 and h and r > max_range:
            h = False
            no_return = True
            length = max_range
        if not (h or (no_return and length > 0)):
            continue
        a = angle_min + i * inc
        if deskew:  # frontend/deskew.py deskew_points, then se2.transform_points
            tau = i * t_inc
            b = a + w * tau
            lx = length * math.cos(b) + vx * tau
            ly = length * math.sin(b) + vy * tau
            x = sx + c * lx - s * ly
            y = sy + s * lx + c * ly
        else:
            b = a + sth
            x = sx + length * math.cos(b)
            y = sy + length * math.sin(b)
        x /= res
        y /= res
        if not (abs(x) < 1e15 and abs(y) < 1e15):  # NaN or far beyond any map (a NaN angle or pose): not a beam
            continue
        ex[n] = x
        ey[n] = y
        hit[n] = h
        n += 1
        cx, cy = int(math.floor(x)), int(math.floor(y))
        cmin, cmax, rmin, rmax = min(cmin, cx), max(cmax, cx), min(rmin, cy), max(rmax, cy)
    return n, cmin, rmin, cmax, rmax


class GridBuilder:
    """A streaming log-odds occupancy grid: `add(pose, scan)` per scan, then `to_occupancy()`.

    Inverse sensor model as in Thrun et al., Probabilistic Robotics, Table 9.1/9.2: each scan adds
    logit(p_miss) to every cell a beam passes and logit(p_hit) to the cell where it ends (a cell is
    updated at most once per scan, a hit beating a miss), clamped to [logit(p_min), logit(p_max)].
    Beams are traced exactly (every cell the segment passes: Amanatides & Woo, "A fast voxel traversal
    algorithm", 1987), in a numba loop (15–33× the vectorised numpy path, docs/bench/grid.md); the numpy
    path (`engine="numpy"`) gives the same cells and serves as the reference. Beams without a return
    (REP 117: +inf, or ≥ range_max) clear free space up to `no_return_clear`. The array grows in
    blocks as scans reach beyond it, so memory is the map's, never the log's.
    """

    GROW = 64  # cells: growth granularity (and minimum margin) when a scan leaves the array
    DESKEW_MAX_GAP_S = 0.5  # a twist from poses farther apart than this is not trusted for de-skewing

    def __init__(self, config: GridConfig | None = None, mount=(0.0, 0.0, 0.0), engine: str = "numba") -> None:
        self.config = config or GridConfig()
        if self.config.p_min >= self.config.p_max:
            from kosmap.frontend.errors import ConfigError
            raise ConfigError(f"config [grid] p_min = {self.config.p_min} must be below p_max = {self.config.p_max}")
        self.mount = tuple(float(v) for v in mount)
        self.res = float(self.config.resolution)
        self.l_hit = _logit(self.config.p_hit)
        self.l_miss = _logit(self.config.p_miss) if self.config.p_miss > 0 else _logit(self.config.p_min)
        self.l_min, self.l_max = _logit(self.config.p_min), _logit(self.config.p_max)
        self.log_odds = np.zeros((0, 0), np.float32)
        self.stamp = np.zeros((0, 0), np.int32)  # id of the last scan that updated the cell (0 = never seen)
        if engine not in ("numba", "numpy"):
            raise ValueError(f"engine {engine!r} must be numba or numpy")
        self.engine = engine
        self.c0 = self.r0 = 0  # global cell index (floor(x / res), floor(y / res)) of log_odds[0, 0]
        self.n_scans = 0
        self._last: tuple[int, tuple] | None = None  # (stamp, pose) of the previous scan: the twist for de-skewing
        self._ex = self._ey = np.empty(0)  # the compiled path's beam buffers (_add_compiled)
        self._hit = np.empty(0, np.bool_)

    # -- geometry --------------------------------------------------------------------------------------------------
    def _ensure(self, cmin: int, rmin: int, cmax: int, rmax: int) -> None:
        """Grow the arrays (in GROW-cell blocks, at least by half) so that cells [cmin..cmax]×[rmin..rmax] exist."""
        h, w = self.log_odds.shape
        if h and self.c0 <= cmin and self.r0 <= rmin and cmax < self.c0 + w and rmax < self.r0 + h:
            return
        g = self.GROW
        if h == 0:
            nc0, nr0, nc1, nr1 = cmin - g, rmin - g, cmax + g + 1, rmax + g + 1
        else:
            nc0, nr0, nc1, nr1 = self.c0, self.r0, self.c0 + w, self.r0 + h
            if cmin < nc0:
                nc0 = min(cmin - g, nc0 - w // 2)
            if rmin < nr0:
                nr0 = min(rmin - g, nr0 - h // 2)
            if cmax >= nc1:
                nc1 = max(cmax + g + 1, nc1 + w // 2)
            if rmax >= nr1:
                nr1 = max(rmax + g + 1, nr1 + h // 2)
        if (nr1 - nr0) * (nc1 - nc0) > MAX_CELLS:  # the growth margin alone must not exceed the limit
            nc0, nr0 = min(cmin, self.c0 if h else cmin), min(rmin, self.r0 if h else rmin)
            nc1, nr1 = max(cmax, self.c0 + w - 1 if h else cmax) + 1, max(rmax, self.r0 + h - 1 if h else rmax) + 1
            if (nr1 - nr0) * (nc1 - nc0) > MAX_CELLS:
                self._too_large(nc1 - nc0, nr1 - nr0)
        lo = np.zeros((nr1 - nr0, nc1 - nc0), np.float32)
        se = np.zeros(lo.shape, np.int32)
        if h:
            lo[self.r0 - nr0:self.r0 - nr0 + h, self.c0 - nc0:self.c0 - nc0 + w] = self.log_odds
            se[self.r0 - nr0:self.r0 - nr0 + h, self.c0 - nc0:self.c0 - nc0 + w] = self.stamp
        self.log_odds, self.stamp, self.c0, self.r0 = lo, se, nc0, nr0

    def _too_large(self, cols: int, rows: int) -> None:
        wm, hm = cols * self.res, rows * self.res
        finest = math.sqrt(wm * hm / MAX_CELLS)
        raise GridTooLarge(f"the map would span {wm:.0f} m × {hm:.0f} m: at [grid] resolution = {self.res:g} m that is "
                           f"{cols * rows:.3g} cells, more than the {MAX_CELLS:.0e} a map may have (1.6 GB); give "
                           f"--set grid.resolution={_round_up(finest)} or more (a map this large from a building's "
                           f"log means a jump in its odometry)")

    @property
    def seen(self) -> np.ndarray:
        """Cells that some beam has updated."""
        return self.stamp > 0

    def beams(self, pose, scan, mount=None, twist=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Sensor position (2,), beam ends (N×2, map frame), whether each ends in a hit (N,): the beams to trace.

        With `twist` ((vx, vy), ω: the sensor's velocity in its frame) and a scan whose beams are taken one
        after the other (`time_increment` ≠ 0), each beam is moved into the sensor frame at the stamp
        (frontend/deskew.py)."""
        sx, sy, sth = _compose(pose, self.mount if mount is None else mount)
        r = np.asarray(scan.ranges, np.float64)
        cfg = self.config
        hit = np.isfinite(r) & (r >= scan.range_min) & (r < scan.range_max)
        no_return = (np.isposinf(r) | (np.isfinite(r) & (r >= scan.range_max)))  # REP 117; NaN / -inf / < min: ignored
        length = np.where(hit, r, np.minimum(cfg.no_return_clear, scan.range_max) if cfg.no_return_clear > 0 else 0.0)
        if cfg.max_range > 0:
            far = hit & (r > cfg.max_range)
            hit &= ~far
            no_return |= far
            length = np.where(far, cfg.max_range, length)
        use = hit | (no_return & (length > 0))
        if twist is not None and abs(scan.time_increment) > 0:
            local = deskew_points(length, scan.angles, scan.time_increment, twist[0], twist[1])[use]
            ends = se2.transform_points((sx, sy, sth), local)
        else:
            a = scan.angles[use] + sth
            ends = np.column_stack((sx + length[use] * np.cos(a), sy + length[use] * np.sin(a)))
        return np.array([sx, sy]), ends, hit[use], use

    def add(self, pose, scan, mount=None) -> None:
        """Integrate one scan taken at `pose` (x, y, yaw of base_link in the map); `mount` overrides the builder's.

        A scan with `time_increment` ≠ 0 is de-skewed with the twist between the previous scan's pose and this
        one (within DESKEW_MAX_GAP_S; the first scan, or one after a gap, is taken as instantaneous)."""
        m = self.mount if mount is None else mount
        twist = None
        if self.config.deskew and abs(scan.time_increment) > 0 and self._last is not None:
            dt = (scan.stamp_ns - self._last[0]) * 1e-9
            if 0 < dt <= self.DESKEW_MAX_GAP_S:
                twist = sensor_twist(self._last[1], pose, dt, m)
        self.previous(scan.stamp_ns, pose)  # this scan: the next one's twist
        if self.engine == "numba":
            self._add_compiled(pose, scan, mount, twist)
            return
        origin, ends, hit, _ = self.beams(pose, scan, mount, twist)
        self.add_beams(origin, ends, hit)

    def previous(self, stamp_ns: int, pose) -> None:
        """The stamp and pose (x, y, yaw of base_link) of the sensor's scan before the next one added: the next
        scan's de-skew twist comes from it. `add` sets it; a map at a lower rate than the scans sets it for the
        skipped scan before each one it adds, so the twist is the one at the full rate."""
        self._last = (int(stamp_ns), tuple(float(v) for v in pose))

    def _add_compiled(self, pose, scan, mount, twist) -> None:
        """`beams` then `add_beams`, the beams made in one compiled call (_beam_ends): the same cells."""
        sx, sy, sth = _compose(pose, self.mount if mount is None else mount)
        cfg = self.config
        n = len(scan.ranges)
        if len(self._ex) < n:
            self._ex, self._ey, self._hit = np.empty(n), np.empty(n), np.empty(n, np.bool_)
        deskew = twist is not None and abs(scan.time_increment) > 0
        (vx, vy), w = twist if deskew else ((0.0, 0.0), 0.0)
        clear = float(np.minimum(cfg.no_return_clear, scan.range_max)) if cfg.no_return_clear > 0 else 0.0
        k, cmin, rmin, cmax, rmax = _beam_ends(
            np.asarray(scan.ranges), float(scan.angle_min), float(scan.angle_increment), float(scan.range_min),
            float(scan.range_max), clear, float(cfg.max_range), float(sx), float(sy), float(sth), float(np.cos(sth)),
            float(np.sin(sth)), deskew, float(scan.time_increment), float(vx), float(vy), float(w), self.res,
            self._ex, self._ey, self._hit)
        self.n_scans += 1
        if k == 0:
            return
        p0x, p0y = float(sx) / self.res, float(sy) / self.res
        c_start, r_start = math.floor(p0x), math.floor(p0y)
        self._ensure(min(cmin, c_start), min(rmin, r_start), max(cmax, c_start), max(rmax, r_start))
        _trace_numba(self.log_odds, self.stamp, self.n_scans, self.c0, self.r0, p0x, p0y, self._ex[:k], self._ey[:k],
                     self._hit[:k], np.float32(self.l_hit), np.float32(self.l_miss), np.float32(self.l_min),
                     np.float32(self.l_max))

    def add_beams(self, origin: np.ndarray, ends: np.ndarray, hit: np.ndarray) -> None:
        """Integrate beams from `origin` (2,) to `ends` (N×2, map frame); `hit[i]` marks a return at the end."""
        self.n_scans += 1
        ok = np.all(np.abs(np.asarray(ends, np.float64)) < 1e15 * self.res, axis=1)  # NaN or far beyond any map: no beam
        if not np.all(np.abs(np.asarray(origin, np.float64)) < 1e15 * self.res):
            return
        ends, hit = np.asarray(ends)[ok], np.asarray(hit)[ok]
        if len(ends) == 0:
            return
        res = self.res
        p0 = np.asarray(origin, np.float64) / res
        p1 = np.asarray(ends, np.float64) / res
        c_start = np.floor(p0).astype(np.int64)
        c_end = np.floor(p1).astype(np.int64)
        if self.engine == "numba":
            lo_c = np.minimum(c_end.min(axis=0), c_start)
            hi_c = np.maximum(c_end.max(axis=0), c_start)
            self._ensure(int(lo_c[0]), int(lo_c[1]), int(hi_c[0]), int(hi_c[1]))
            _trace_numba(self.log_odds, self.stamp, self.n_scans, self.c0, self.r0, p0[0], p0[1],
                         np.ascontiguousarray(p1[:, 0]), np.ascontiguousarray(p1[:, 1]), np.asarray(hit, np.bool_),
                         np.float32(self.l_hit), np.float32(self.l_miss), np.float32(self.l_min), np.float32(self.l_max))
            return
        cells = np.vstack([c_start[None]] + [_crossings(p0, p1, c_start, c_end, ax) for ax in (0, 1)])
        allc = np.vstack((cells, c_end, c_start[None]))
        cmin, rmin = allc.min(axis=0)
        cmax, rmax = allc.max(axis=0)
        self._ensure(int(cmin), int(rmin), int(cmax), int(rmax))
        # One update per cell per scan: mark in a window the size of the scan's bounding box.
        bw, bh = int(cmax - cmin + 1), int(rmax - rmin + 1)
        free = np.zeros(bh * bw, bool)
        free[(cells[:, 1] - rmin) * bw + (cells[:, 0] - cmin)] = True
        end_idx = (c_end[:, 1] - rmin) * bw + (c_end[:, 0] - cmin)
        free[end_idx[~hit]] = True  # a no-return beam's last cell is free too
        occ = np.zeros(bh * bw, bool)
        occ[end_idx[hit]] = True
        free &= ~occ
        fi = np.flatnonzero(free)
        oi = np.flatnonzero(occ)
        w = self.log_odds.shape[1]
        off = (rmin - self.r0) * w + (cmin - self.c0)
        gf = off + (fi // bw) * w + fi % bw  # window index → index into the whole array
        go = off + (oi // bw) * w + oi % bw
        lo, stamp = self.log_odds.reshape(-1), self.stamp.reshape(-1)
        lo[gf] = np.clip(lo[gf] + np.float32(self.l_miss), self.l_min, self.l_max)
        lo[go] = np.clip(lo[go] + np.float32(self.l_hit), self.l_min, self.l_max)
        stamp[gf] = self.n_scans
        stamp[go] = self.n_scans

    # -- output ----------------------------------------------------------------------------------------------------

    def to_occupancy(self, crop: bool = True) -> OccupancyGrid:
        """The map as an OccupancyGrid (0..100 = round(100·p), −1 never seen), cropped to the seen cells."""
        if not self.seen.any():
            return OccupancyGrid(np.full((1, 1), -1, np.int8), self.res, (self.c0 * self.res, self.r0 * self.res, 0.0))
        r0, c0 = 0, 0
        lo, seen = self.log_odds, self.seen
        if crop:
            rows = np.flatnonzero(seen.any(axis=1))
            cols = np.flatnonzero(seen.any(axis=0))
            r0, c0 = int(rows[0]), int(cols[0])
            sl = (slice(r0, int(rows[-1]) + 1), slice(c0, int(cols[-1]) + 1))
            lo, seen = lo[sl], seen[sl]
        p = 1.0 / (1.0 + np.exp(-lo.astype(np.float64)))
        data = np.where(seen, np.rint(100.0 * p), -1).astype(np.int8)
        return OccupancyGrid(data, self.res, ((self.c0 + c0) * self.res, (self.r0 + r0) * self.res, 0.0))


class GridSet:
    """One streaming grid per scan source (each KOS level, the obstacle scan, the laser), made on first use.

    `add(key, pose, scan)` with key = the source's name (default: the scan's topic); `mounts[key]` is that
    sensor's mount in base_link (x, y, yaw), identity when absent.
    """

    def __init__(self, config: GridConfig | None = None, mounts: dict | None = None, engine: str = "numba") -> None:
        self.config = config or GridConfig()
        self.mounts = dict(mounts or {})
        self.engine = engine
        self.builders: dict[str, GridBuilder] = {}

    def add(self, pose, scan, key: str | None = None, mount=None) -> None:
        key = key or scan.topic or scan.frame_id or "scan"
        b = self.builders.get(key)
        if b is None:
            b = self.builders[key] = GridBuilder(self.config, self.mounts.get(key, (0.0, 0.0, 0.0)), self.engine)
        b.add(pose, scan, mount)

    def to_occupancy(self) -> dict[str, OccupancyGrid]:
        return {k: b.to_occupancy() for k, b in self.builders.items()}


def build_grid(poses: np.ndarray, scans, mount=(0.0, 0.0, 0.0), config: GridConfig | None = None) -> OccupancyGrid:
    """One grid from N×3 poses (x, y, yaw of base_link in the map) and their N scans (an iterable is streamed)."""
    b = GridBuilder(config, mount)
    for pose, scan in zip(np.asarray(poses, float), scans):
        b.add(pose, scan)
    return b.to_occupancy()
