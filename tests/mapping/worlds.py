"""Small synthetic 2D worlds for the mapping tests: wall segments, exact ray casting, true-wall rasters."""

from __future__ import annotations

import numpy as np

from kosmap.frontend.records import Scan
from kosmap.mapping.grid import OccupancyGrid


def room() -> np.ndarray:
    """An asymmetric 10 × 7 m L-shaped room with an interior wall and a pillar: M×4 segments (x0, y0, x1, y1)."""
    outline = [(0, 0), (10, 0), (10, 4), (7, 4), (7, 7), (0, 7), (0, 0)]
    segs = [(*a, *b) for a, b in zip(outline[:-1], outline[1:])]
    segs += [(3, 0, 3, 3.2), (3, 4.2, 3, 5.5), (5.0, 5.5, 5.6, 5.5), (5.6, 5.5, 5.6, 6.1), (5.6, 6.1, 5.0, 6.1),
             (5.0, 6.1, 5.0, 5.5), (8.5, 1.5, 9.2, 2.4)]
    return np.array(segs, float)


def office() -> np.ndarray:
    """A 30 × 14 m office floor: two corridors joined at both ends, rooms along one side with doors (M×4)."""
    segs = []
    # outer walls
    segs += [(0, 0, 30, 0), (30, 0, 30, 14), (30, 14, 0, 14), (0, 14, 0, 0)]
    # central block between the corridors (corridors 2 m wide: y 0..2 and y 12..14, cross corridors x 0..2, 28..30)
    segs += [(2, 2, 28, 2), (28, 2, 28, 12), (28, 12, 2, 12), (2, 12, 2, 2)]
    # rooms inside the block, doors 1 m wide on the lower corridor side
    for x in (8, 14, 20):
        segs.append((x, 2, x, 12))
    segs = [s for s in segs if s != (2, 2, 28, 2)]
    for a, b in ((2, 8), (8, 14), (14, 20), (20, 28)):
        segs += [(a, 2, a + 2, 2), (a + 3, 2, b, 2)]  # 1 m door at a+2..a+3
    segs += [(24, 5, 26, 5), (26, 5, 26, 8)]  # furniture-like stub in the last room
    return np.array(segs, float)


def raycast(origin, angles: np.ndarray, segs: np.ndarray, max_range: float) -> np.ndarray:
    """Exact range to the nearest segment along each ray (inf where nothing within max_range)."""
    ox, oy = origin
    d = np.column_stack((np.cos(angles), np.sin(angles)))  # N×2
    p, q = segs[:, :2], segs[:, 2:] - segs[:, :2]  # M×2
    denom = d[:, None, 0] * q[None, :, 1] - d[:, None, 1] * q[None, :, 0]
    w = p - np.array([ox, oy])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * q[None, :, 1] - w[None, :, 1] * q[None, :, 0]) / denom
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / denom
    ok = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
    r = np.where(ok, t, np.inf).min(axis=1)
    r[r >= max_range] = np.inf
    return r


def scan_at(pose, segs, n=541, fov=np.radians(270), max_range=30.0, noise=0.0, rng=None, mount=(0, 0, 0)) -> Scan:
    """A laser scan (REP 117: inf = no return) from the sensor mounted at `mount` on a robot at `pose`."""
    x, y, th = pose
    c, s = np.cos(th), np.sin(th)
    sx, sy, sth = x + c * mount[0] - s * mount[1], y + s * mount[0] + c * mount[1], th + mount[2]
    inc = fov / (n - 1)
    angles = -fov / 2 + np.arange(n) * inc
    r = raycast((sx, sy), angles + sth, segs, max_range)
    if noise and rng is not None:
        r = r + rng.normal(0, noise, r.shape) * np.isfinite(r)
    return Scan(0, r.astype(np.float32), -fov / 2, inc, 0.05, max_range, "laser")


def wall_grid(segs: np.ndarray, resolution: float, margin: float = 0.5, transform=(0.0, 0.0, 0.0),
              origin_yaw: float = 0.0, cells_thick: int = 1) -> OccupancyGrid:
    """The true walls rasterised (100 on a wall, 0 elsewhere) after moving the world by `transform` (x, y, yaw)."""
    tx, ty, th = transform
    c, s = np.cos(th), np.sin(th)
    a = segs[:, :2] @ np.array([[c, s], [-s, c]]) + (tx, ty)
    b = segs[:, 2:] @ np.array([[c, s], [-s, c]]) + (tx, ty)
    pts = []
    for p, q in zip(a, b):
        k = max(2, int(np.ceil(np.hypot(*(q - p)) / (resolution / 4))))
        pts.append(p + np.linspace(0, 1, k)[:, None] * (q - p))
    pts = np.vstack(pts)
    # the grid's own frame may be rotated by origin_yaw: express points in it
    co, so = np.cos(origin_yaw), np.sin(origin_yaw)
    local = pts @ np.array([[co, -so], [so, co]])
    lo = local.min(axis=0) - margin
    hi = local.max(axis=0) + margin
    lo = np.floor(lo / resolution) * resolution
    w, h = (np.ceil((hi - lo) / resolution)).astype(int)
    data = np.zeros((h, w), np.int8)
    cells = np.floor((local - lo) / resolution).astype(int)
    data[cells[:, 1], cells[:, 0]] = 100
    if cells_thick > 1:
        import cv2
        data = cv2.dilate((data > 0).astype(np.uint8), np.ones((cells_thick, cells_thick), np.uint8)).astype(np.int8) * 100
    ox, oy = co * lo[0] - so * lo[1], so * lo[0] + co * lo[1]
    return OccupancyGrid(data, resolution, (float(ox), float(oy), float(origin_yaw)))


def thick_walls(segs: np.ndarray, thickness: float) -> np.ndarray:
    """Each wall centre line as the outline of a `thickness`-wide rectangle (segments a ray caster sees)."""
    out = []
    for x0, y0, x1, y1 in segs:
        d = np.array([x1 - x0, y1 - y0]) / np.hypot(x1 - x0, y1 - y0)
        n = np.array([-d[1], d[0]]) * thickness / 2
        a, b = np.array([x0, y0]) - d * thickness / 2, np.array([x1, y1]) + d * thickness / 2
        c = [a + n, b + n, b - n, a - n, a + n]
        out += [(*p, *q) for p, q in zip(c[:-1], c[1:])]
    return np.array(out)


def thick_blueprint(segs: np.ndarray, thickness: float, resolution: float, margin: float = 0.5) -> OccupancyGrid:
    """The plan of walls `thickness` wide: cells whose centre is within thickness/2 (+ half a cell, so thin walls
    stay continuous) of a centre line are walls; the outside (reached from the border) unknown, the inside free."""
    from kosmap.mapping.mapio import outside_unknown

    lo = np.floor((segs.reshape(-1, 2).min(axis=0) - margin) / resolution) * resolution
    hi = segs.reshape(-1, 2).max(axis=0) + margin
    w, h = np.ceil((hi - lo) / resolution).astype(int)
    xs = lo[0] + (np.arange(w) + 0.5) * resolution
    ys = lo[1] + (np.arange(h) + 0.5) * resolution
    X, Y = np.meshgrid(xs, ys)
    P = np.column_stack((X.ravel(), Y.ravel()))
    dmin = np.full(len(P), np.inf)
    for x0, y0, x1, y1 in segs:
        a, b = np.array([x0, y0]), np.array([x1, y1])
        t = np.clip((P - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        dmin = np.minimum(dmin, np.hypot(*(P - a - t[:, None] * (b - a)).T))
    data = np.where(dmin.reshape(h, w) <= thickness / 2 + resolution / 2, 100, 0).astype(np.int8)
    return OccupancyGrid(outside_unknown(data), resolution, (float(lo[0]), float(lo[1]), 0.0))


def path_poses(waypoints, step: float) -> np.ndarray:
    """Poses every `step` metres along a polyline, heading along it (x, y, yaw)."""
    wp = np.asarray(waypoints, float)
    out = []
    for a, b in zip(wp[:-1], wp[1:]):
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / step)))
        yaw = np.arctan2(*(b - a)[::-1])
        for t in np.arange(n) / n:
            out.append((*(a + t * (b - a)), yaw))
    out.append((*wp[-1], out[-1][2]))
    return np.array(out)
