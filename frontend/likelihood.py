"""Likelihood fields: M(q) = exp(−d(q)²/2σ²), d the distance from q to the nearest map point, on a grid.

The scan matchers (frontend/matcher.py) score a scan by the field's values at its end points (Thrun et al.,
"Probabilistic Robotics", §6.4, the likelihood field model; hector_mapping and Cartographer match against
such smoothed grids). The field is built by splatting an exact Gaussian around each point and keeping the
maximum per cell: since exp is monotone, max_k exp(−d_k²/2σ²) = exp(−min_k d_k²/2σ²), the same as a distance
transform, but points can be added one scan at a time (no rebuild when a keyframe joins a submap).
Cell (row, col) covers [ox + col·res, ox + (col+1)·res) × [oy + row·res, …); its value is taken at its centre.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def splat_max(field, ox, oy, res, sigma, pts):
    """Raise each cell within 3σ of a point to exp(−d²/2σ²) of its centre's distance d to that point.

    The Gaussian is separable, exp(−(dx² + dy²)/2σ²) = exp(−dx²/2σ²)·exp(−dy²/2σ²): 2(2r+1) exps per point.
    """
    h, w = field.shape
    r = int(math.ceil(3.0 * sigma / res))
    inv = 1.0 / (2.0 * sigma * sigma)
    ex = np.empty(2 * r + 1)
    ey = np.empty(2 * r + 1)
    for k in range(pts.shape[0]):
        fx = (pts[k, 0] - ox) / res - 0.5
        fy = (pts[k, 1] - oy) / res - 0.5
        if not (fx > -r - 1 and fx < w + r and fy > -r - 1 and fy < h + r):
            continue
        cx = int(math.floor(fx + 0.5))
        cy = int(math.floor(fy + 0.5))
        for u in range(2 * r + 1):
            dx = (cx - r + u - fx) * res
            dy = (cy - r + u - fy) * res
            ex[u] = math.exp(-dx * dx * inv)
            ey[u] = math.exp(-dy * dy * inv)
        for iy in range(max(cy - r, 0), min(cy + r + 1, h)):
            vy = ey[iy - cy + r]
            for ix in range(max(cx - r, 0), min(cx + r + 1, w)):
                v = vy * ex[ix - cx + r]
                if v > field[iy, ix]:
                    field[iy, ix] = v


@njit(cache=True)
def sample(field, fx, fy):
    """Bilinear value and gradient (per cell) at continuous cell coordinates (centres at integers); 0 outside."""
    h, w = field.shape
    if not (fx >= 0.0 and fy >= 0.0 and fx < w - 1 and fy < h - 1):
        return 0.0, 0.0, 0.0
    ix = int(fx)
    iy = int(fy)
    ax = fx - ix
    ay = fy - iy
    v00 = field[iy, ix]
    v01 = field[iy, ix + 1]
    v10 = field[iy + 1, ix]
    v11 = field[iy + 1, ix + 1]
    v0 = v00 + ax * (v01 - v00)
    v1 = v10 + ax * (v11 - v10)
    val = v0 + ay * (v1 - v0)
    gx = (1.0 - ay) * (v01 - v00) + ay * (v11 - v10)
    gy = v1 - v0
    return val, gx, gy


class LikelihoodField:
    """A float32 likelihood field over a fixed rectangle of the plane, filled scan by scan."""

    def __init__(self, origin: tuple[float, float], resolution: float, width: int, height: int, sigma: float) -> None:
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.sigma = float(sigma)
        self.values = np.zeros((int(height), int(width)), np.float32)

    @classmethod
    def around(cls, center: tuple[float, float], size: float, resolution: float, sigma: float) -> LikelihoodField:
        """A square field of side `size` metres centred at `center`."""
        n = int(math.ceil(size / resolution))
        return cls((center[0] - n * resolution / 2.0, center[1] - n * resolution / 2.0), resolution, n, n, sigma)

    @classmethod
    def covering(cls, points: np.ndarray, resolution: float, sigma: float, margin: float | None = None) -> LikelihoodField:
        """The smallest field holding every point plus a margin (3σ + one cell by default), filled with them."""
        margin = 3.0 * sigma + 2.0 * resolution if margin is None else margin
        if len(points) == 0:
            return cls((0.0, 0.0), resolution, 1, 1, sigma)
        lo = points.min(axis=0) - margin
        hi = points.max(axis=0) + margin
        w, h = (int(v) for v in np.ceil((hi - lo) / resolution))
        f = cls((float(lo[0]), float(lo[1])), resolution, max(w, 1), max(h, 1), sigma)
        f.insert(points)
        return f

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape  # type: ignore[return-value]

    def insert(self, points_world: np.ndarray) -> None:
        """Add map points (N×2, in the field's frame)."""
        if len(points_world):
            splat_max(self.values, self.origin[0], self.origin[1], self.resolution, self.sigma,
                      np.ascontiguousarray(points_world, dtype=np.float64))

    def contains(self, xy, margin: float = 0.0) -> bool:
        """True when the point lies inside the field, at least `margin` metres from its border."""
        h, w = self.values.shape
        x = (xy[0] - self.origin[0]) / self.resolution
        y = (xy[1] - self.origin[1]) / self.resolution
        m = margin / self.resolution
        return bool(m <= x <= w - m and m <= y <= h - m)

    def crop(self) -> LikelihoodField:
        """The same field cut to the bounding box of its non-zero cells (submaps kept for loop search)."""
        rows = np.flatnonzero(self.values.any(axis=1))
        cols = np.flatnonzero(self.values.any(axis=0))
        if len(rows) == 0:
            return LikelihoodField(self.origin, self.resolution, 1, 1, self.sigma)
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        f = LikelihoodField((self.origin[0] + c0 * self.resolution, self.origin[1] + r0 * self.resolution),
                            self.resolution, c1 - c0, r1 - r0, self.sigma)
        f.values = np.ascontiguousarray(self.values[r0:r1, c0:c1])
        return f

    def score(self, pose, points: np.ndarray) -> float:
        """Mean field value at the points (N×2, scan frame) placed at `pose`."""
        return float(mean_score(self.values, self.origin[0], self.origin[1], self.resolution,
                                np.ascontiguousarray(points, dtype=np.float64), np.asarray(pose, dtype=np.float64)))


@njit(cache=True)
def _grown(out, m, size):
    """A (size, 2) array starting with the first m rows of `out`: copied element by element, as a slice
    assignment makes numba compile a shape check with its error message (~5 s on a fresh machine)."""
    bigger = np.empty((size, 2))
    for q in range(m):
        bigger[q, 0] = out[q, 0]
        bigger[q, 1] = out[q, 1]
    return bigger


@njit(cache=True)
def _densify(pts, spacing, max_gap, rel):
    n = pts.shape[0]
    if n == 0:
        return pts.copy()
    out = np.empty((n * 4 + 16, 2))
    m = 0
    for i in range(n):
        if m + 2 >= out.shape[0]:
            out = _grown(out, m, out.shape[0] * 2)
        out[m, 0] = pts[i, 0]
        out[m, 1] = pts[i, 1]
        m += 1
        if i + 1 == n:
            break
        ax, ay = pts[i, 0], pts[i, 1]
        bx, by = pts[i + 1, 0], pts[i + 1, 1]
        gap = math.hypot(bx - ax, by - ay)
        ra = math.hypot(ax, ay)
        rb = math.hypot(bx, by)
        # the bearing step between the two returns, seen from the sensor (≈ base_link origin)
        dth = abs(math.atan2(ax * by - ay * bx, ax * bx + ay * by))
        allowed = min(max_gap, max(spacing, rel * max(ra, rb) * dth))
        if gap <= spacing or gap > allowed:
            continue
        k = int(gap / spacing)
        if m + k + 2 >= out.shape[0]:
            out = _grown(out, m, out.shape[0] * 2 + k + 2)
        for j in range(1, k + 1):
            a = j / (k + 1.0)
            out[m, 0] = ax + a * (bx - ax)
            out[m, 1] = ay + a * (by - ay)
            m += 1
    return out[:m]


def densify(points: np.ndarray, spacing: float, max_gap: float, rel: float = 3.0) -> np.ndarray:
    """Fill the line between consecutive returns (scan order) with points every `spacing` metres, when they
    are close enough to lie on one surface: gap ≤ min(max_gap, rel · range · bearing step). Sparse beams at
    long range or grazing incidence then leave a wall in the submap, not a row of dots; depth jumps
    (gap ≫ range · bearing step) stay open. max_gap ≤ 0 returns the points unchanged."""
    if max_gap <= 0 or len(points) < 2:
        return points
    return _densify(np.ascontiguousarray(points, dtype=np.float64), float(spacing), float(max_gap), float(rel))


@njit(cache=True)
def mean_score(field, ox, oy, res, pts, pose):
    """Mean bilinear field value of the points placed at pose."""
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    acc = 0.0
    n = pts.shape[0]
    for k in range(n):
        qx = pose[0] + c * pts[k, 0] - s * pts[k, 1]
        qy = pose[1] + s * pts[k, 0] + c * pts[k, 1]
        v, _, _ = sample(field, (qx - ox) / res - 0.5, (qy - oy) / res - 0.5)
        acc += v
    return acc / max(n, 1)
