"""Simulated buildings: walls, furniture and clutter as convex solids, every face a numbered surface.

A world file (YAML, angles in degrees) lists wall segments or a raster floor plan (map_server PNG + YAML),
doors cut into the walls, and furniture: tables (a top on four legs), shelves, low obstacles, generic boxes
with a z-range, ramps (wedges) and cylinders (people, bins, pillars). Walls are extruded from the floor to
`wall_height`, which is also the ceiling. Each solid is a vertical prism over a convex footprint (polygon or
circle) cut by non-vertical planes (top, bottom, the ramp's slope); that one form lets the renderer cast a
whole image column as one 2D ray (render.py). Every face is a `Surface` with an id (the value written in
surface-id images; 0 = none), a class and, when planar, its plane n·x = d in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from kosmap.frontend.errors import KosmapError

SURFACE_CLASSES = ("floor", "ceiling", "wall", "table_top", "box_top", "box_side", "box_bottom", "ramp",
                   "cylinder", "cylinder_top")
FLYING_ID = 65535  # surface-id value of a flying (mixed) pixel: it lies on no surface
NO_SURFACE = 0


class WorldError(KosmapError):
    """A world or path file that cannot be used: unreadable, malformed, or geometrically impossible."""


@dataclass(frozen=True)
class Surface:
    """One face of the world. Planar faces carry their plane n·x = d (n the unit normal facing free space);
    cylinder sides carry their axis (cx, cy) and radius instead."""

    id: int
    cls: str
    obj: str
    normal: np.ndarray | None = None
    offset: float | None = None
    axis: tuple[float, float, float] | None = None  # (cx, cy, radius) of a vertical cylinder side

    @property
    def planar(self) -> bool:
        return self.normal is not None

    @property
    def plane(self) -> tuple[np.ndarray, float] | None:
        """(n, d) with n·x = d for points on the surface, or None for a cylinder side."""
        return None if self.normal is None else (self.normal, float(self.offset))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of N×3 world points from the surface's plane (or cylinder), positive in free space."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.normal is not None:
            return p @ self.normal - self.offset
        cx, cy, r = self.axis
        return np.hypot(p[:, 0] - cx, p[:, 1] - cy) - r


@dataclass
class Solid:
    """A vertical prism over a convex footprint, cut by non-vertical planes.

    Footprint: a CCW polygon (K×2) with one surface id per edge (edge i runs from vertex i to i+1), or a
    circle (cx, cy, r) with one side id. Caps: (n (3,), d, surface id) half-spaces n·x ≤ d (top, bottom, slope).
    """

    name: str
    kind: str  # wall, table, shelf, obstacle, box, ramp, cylinder
    z0: float
    z1: float
    polygon: np.ndarray | None = None
    edge_ids: list[int] = field(default_factory=list)
    circle: tuple[float, float, float] | None = None
    circle_id: int = 0
    caps: list[tuple[np.ndarray, float, int]] = field(default_factory=list)

    def bounding_circle(self) -> tuple[float, float, float]:
        if self.circle is not None:
            return self.circle
        c = self.polygon.mean(axis=0)
        return float(c[0]), float(c[1]), float(np.max(np.hypot(*(self.polygon - c).T)))

    def footprint_distance(self, xy: np.ndarray) -> np.ndarray:
        """Distance (m) of N×2 points to the footprint (0 inside)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.circle is not None:
            cx, cy, r = self.circle
            return np.maximum(np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) - r, 0.0)
        return _polygon_distance(self.polygon, xy)

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Which N×3 points lie inside the solid (grown by `margin`)."""
        p = np.asarray(points, float).reshape(-1, 3)
        inside = self.footprint_distance(p[:, :2]) <= margin
        for n, d, _ in self.caps:
            inside &= p @ n - d <= margin
        return inside & (p[:, 2] >= self.z0 - margin) & (p[:, 2] <= self.z1 + margin)


def _polygon_inside(poly: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Points inside a convex CCW polygon."""
    inside = np.ones(len(xy), bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        cross = (b[0] - a[0]) * (xy[:, 1] - a[1]) - (b[1] - a[1]) * (xy[:, 0] - a[0])
        inside &= cross >= 0
    return inside


def _segment_distance(a: np.ndarray, b: np.ndarray, xy: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((xy - a) @ ab) / max(float(ab @ ab), 1e-18), 0.0, 1.0)
    return np.hypot(*(xy - (a + t[:, None] * ab)).T)


def _polygon_distance(poly: np.ndarray, xy: np.ndarray) -> np.ndarray:
    d = np.min([_segment_distance(poly[i], poly[(i + 1) % len(poly)], xy) for i in range(len(poly))], axis=0)
    return np.where(_polygon_inside(poly, xy), 0.0, d)


def rectangle(center, size, yaw: float) -> np.ndarray:
    """CCW corners (4×2) of a rectangle of `size` (along, across) centred at `center`, rotated by yaw (rad)."""
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hy = size[0] / 2.0, size[1] / 2.0
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(center, float)


@dataclass
class PathSpec:
    """Waypoints (N×2, m) the robot drives through, stopping and turning in place at each."""

    waypoints: np.ndarray
    start_yaw: float | None = None  # rad; None = facing the first leg


class World:
    """A building: solids, their surfaces, floor and ceiling, a bundled path; build with `World.load`."""

    def __init__(self, name: str, wall_height: float = 2.7) -> None:
        self.name = name
        self.wall_height = float(wall_height)
        self.solids: list[Solid] = []
        self.surfaces: list[Surface] = []
        self.path: PathSpec | None = None
        self.paths: dict[str, PathSpec] = {}  # further bundled paths by name (`paths:` in the world file)
        self.description = ""
        self.floor_id = self._surface("floor", "floor", np.array([0.0, 0.0, 1.0]), 0.0)
        self.ceiling_id = self._surface("ceiling", "ceiling", np.array([0.0, 0.0, -1.0]), -self.wall_height)

    # -- building --------------------------------------------------------------------------------------------------
    def _surface(self, cls: str, obj: str, normal=None, offset=None, axis=None) -> int:
        sid = len(self.surfaces) + 1
        if sid >= FLYING_ID:
            raise WorldError(f"world {self.name} has more than {FLYING_ID - 1} surfaces; simplify it")
        n = None if normal is None else np.asarray(normal, float) / np.linalg.norm(normal)
        if n is not None:
            n = np.where(np.abs(n) < 1e-12, 0.0, n) + 0.0  # no -0.0 or 1e-17 residues
        self.surfaces.append(Surface(sid, cls, obj, n, None if offset is None else float(offset), axis))
        return sid

    def surface(self, sid: int) -> Surface:
        """The surface with id `sid` (≥ 1)."""
        return self.surfaces[int(sid) - 1]

    def add_prism(self, name: str, kind: str, polygon: np.ndarray, z0: float, z1: float,
                  top_cls: str = "box_top", side_cls: str = "box_side", bottom_cls: str = "box_bottom",
                  caps: bool = True) -> Solid:
        """A vertical prism over a convex polygon from z0 to z1; caps at the floor or ceiling are left out."""
        poly = np.asarray(polygon, float)
        area2 = np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
        if area2 < 0:
            poly = poly[::-1]
        if not z1 > z0:
            raise WorldError(f"{name}: its top {z1} m must be above its bottom {z0} m")
        s = Solid(name, kind, float(z0), float(z1), polygon=poly)
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            e = b - a
            n = np.array([e[1], -e[0], 0.0]) / math.hypot(*e)
            s.edge_ids.append(self._surface(side_cls, name, n, float(n[:2] @ a)))
        if caps:
            self._add_caps(s, name, top_cls, bottom_cls)
        self.solids.append(s)
        return s

    def _add_caps(self, s: Solid, name: str, top_cls: str, bottom_cls: str) -> None:
        if s.z1 < self.wall_height - 1e-9:
            n = np.array([0.0, 0.0, 1.0])
            s.caps.append((n, s.z1, self._surface(top_cls, name, n, s.z1)))
        if s.z0 > 1e-9:
            n = np.array([0.0, 0.0, -1.0])
            s.caps.append((n, -s.z0, self._surface(bottom_cls, name, n, -s.z0)))

    def add_cylinder(self, name: str, center, radius: float, z0: float, z1: float) -> Solid:
        cx, cy = float(center[0]), float(center[1])
        if not radius > 0 or not z1 > z0:
            raise WorldError(f"{name}: radius {radius} m must be > 0 and its top {z1} above its bottom {z0}")
        s = Solid(name, "cylinder", float(z0), float(z1), circle=(cx, cy, float(radius)))
        s.circle_id = self._surface("cylinder", name, axis=(cx, cy, float(radius)))
        self._add_caps(s, name, "cylinder_top", "box_bottom")
        self.solids.append(s)
        return s

    def add_wall(self, name: str, a, b, thickness: float, extend_a: bool = True, extend_b: bool = True) -> Solid:
        """A wall along the centre line a → b; ends marked `extend` reach half a thickness further so that
        corners close (door jambs are not extended: a door keeps its clear width)."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        u = (b - a) / float(np.hypot(*(b - a)))
        a = a - u * thickness / 2 if extend_a else a
        b = b + u * thickness / 2 if extend_b else b
        length = float(np.hypot(*(b - a)))
        yaw = math.atan2(u[1], u[0])
        return self.add_prism(name, "wall", rectangle((a + b) / 2, (length, thickness), yaw),
                              0.0, self.wall_height, "wall", "wall", "wall")

    def add_table(self, name: str, center, size, yaw: float, height: float = 0.75, top: float = 0.04,
                  leg: float = 0.05) -> None:
        """A table: a top slab (its upper face class table_top) on four square legs."""
        if not 0 < top < height:
            raise WorldError(f"{name}: top thickness {top} m must be between 0 and its height {height} m")
        self.add_prism(f"{name} top", "table", rectangle(center, size, yaw), height - top, height, "table_top")
        c, s = math.cos(yaw), math.sin(yaw)
        for sx in (-1, 1):
            for sy in (-1, 1):
                lx, ly = sx * (size[0] / 2 - leg), sy * (size[1] / 2 - leg)
                p = np.asarray(center, float) + [c * lx - s * ly, s * lx + c * ly]
                self.add_prism(f"{name} leg", "table", rectangle(p, (leg, leg), yaw), 0.0, height - top)

    def add_ramp(self, name: str, center, size, yaw: float, height: float) -> Solid:
        """A wedge rising from the floor at one end to `height` at the other, along `yaw` (size = length, width)."""
        if not height > 0:
            raise WorldError(f"{name}: height {height} m must be > 0")
        poly = rectangle(center, size, yaw)
        s = self.add_prism(name, "ramp", poly, 0.0, height, caps=False)
        # the top is the slope: z ≤ height·(u·xy − s0)/length
        u = np.array([math.cos(yaw), math.sin(yaw)])
        k = height / size[0]
        s0 = float(u @ np.asarray(center, float)) - size[0] / 2
        n = np.array([-k * u[0], -k * u[1], 1.0])
        norm = float(np.linalg.norm(n))
        s.caps.append((n / norm, -k * s0 / norm, self._surface("ramp", name, n / norm, -k * s0 / norm)))
        return s

    @staticmethod
    def load(name_or_path: str | Path) -> World:
        """A bundled world by name ('office', 'room') or a world YAML file."""
        return load_world(name_or_path)

    # -- queries ---------------------------------------------------------------------------------------------------
    @property
    def walls(self) -> list[Solid]:
        return [s for s in self.solids if s.kind == "wall"]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the walls (of all solids when there are no walls)."""
        pts = [s.polygon for s in (self.walls or self.solids) if s.polygon is not None]
        pts += [np.array([[s.circle[0] - s.circle[2], s.circle[1] - s.circle[2]],
                          [s.circle[0] + s.circle[2], s.circle[1] + s.circle[2]]])
                for s in (self.walls or self.solids) if s.circle is not None]
        if not pts:
            return (-1.0, -1.0, 1.0, 1.0)
        p = np.vstack(pts)
        return float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max())

    def inside_bounds(self, xy: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.bounds
        xy = np.asarray(xy, float).reshape(-1, 2)
        return (xy[:, 0] > x0) & (xy[:, 0] < x1) & (xy[:, 1] > y0) & (xy[:, 1] < y1)

    def solid_at(self, points: np.ndarray, margin: float = 0.0) -> list[Solid | None]:
        """For each N×3 point, the first solid containing it (or None)."""
        p = np.asarray(points, float).reshape(-1, 3)
        out: list[Solid | None] = [None] * len(p)
        for s in self.solids:
            for i in np.flatnonzero(s.contains(p, margin)):
                if out[i] is None:
                    out[i] = s
        return out

    def surface_distance(self, surface_ids: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of each world point (N×3) to the surface of its id (NaN for id 0 or flying)."""
        ids = np.asarray(surface_ids).reshape(-1).astype(np.int64)
        p = np.asarray(points, float).reshape(-1, 3)
        out = np.full(len(ids), np.nan)
        for sid in np.unique(ids):
            if sid <= 0 or sid > len(self.surfaces):
                continue
            m = ids == sid
            out[m] = self.surface(sid).distance(p[m])
        return out

    def blueprint(self, resolution: float = 0.05, furniture: bool = False, margin: float = 0.5):
        """The floor plan as an OccupancyGrid: walls occupied (and furniture footprints when asked), the
        inside free, the outside (reached from the border without crossing a wall) unknown."""
        import cv2

        from kosmap.mapping.grid import OccupancyGrid

        if not resolution > 0:
            raise WorldError(f"blueprint resolution {resolution} must be > 0 m")
        x0, y0, x1, y1 = self.bounds
        x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
        w, h = int(math.ceil((x1 - x0) / resolution)), int(math.ceil((y1 - y0) / resolution))
        occ = np.zeros((h, w), np.uint8)
        for s in self.solids:
            if s.kind != "wall" and not furniture:
                continue
            _rasterise(s, occ, x0, y0, resolution)
        free = np.where(occ > 0, 0, 255).astype(np.uint8)
        # flood the outside from the border: cells reachable without crossing a wall are unknown
        mask = np.zeros((h + 2, w + 2), np.uint8)
        outside = free.copy()
        cv2.floodFill(outside, mask, (0, 0), 128)
        data = np.zeros((h, w), np.int8)
        data[occ > 0] = 100
        data[outside == 128] = -1
        return OccupancyGrid(data, float(resolution), (x0, y0, 0.0), "map")


def _rasterise(s: Solid, occ: np.ndarray, x0: float, y0: float, res: float) -> None:
    """Mark the cells whose centre lies in the solid's footprint, and (so that a solid thinner than a cell
    still leaves an unbroken line) the cells its centre line passes through."""
    cx, cy, r = s.bounding_circle()
    c0 = max(int((cx - r - x0) / res) - 1, 0)
    c1 = min(int((cx + r - x0) / res) + 2, occ.shape[1])
    r0 = max(int((cy - r - y0) / res) - 1, 0)
    r1 = min(int((cy + r - y0) / res) + 2, occ.shape[0])
    if c1 <= c0 or r1 <= r0:
        return
    cols, rows = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
    xy = np.column_stack((x0 + (cols.ravel() + 0.5) * res, y0 + (rows.ravel() + 0.5) * res))
    hit = s.footprint_distance(xy) <= 0.0
    occ[rows.ravel()[hit], cols.ravel()[hit]] = 1
    if s.polygon is not None and len(s.polygon) == 4:  # rectangles: the line between the short sides' midpoints
        p = s.polygon
        sides = [np.hypot(*(p[(k + 1) % 4] - p[k])) for k in range(4)]
        k = int(np.argmin(sides))
        a, b = (p[k] + p[(k + 1) % 4]) / 2, (p[(k + 2) % 4] + p[(k + 3) % 4]) / 2
    else:
        a = b = np.array([cx, cy])
    n = int(np.hypot(*(b - a)) / (res / 4)) + 2
    line = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    cc = np.floor((line[:, 0] - x0) / res).astype(int)
    rr = np.floor((line[:, 1] - y0) / res).astype(int)
    ok = (cc >= 0) & (cc < occ.shape[1]) & (rr >= 0) & (rr < occ.shape[0])
    occ[rr[ok], cc[ok]] = 1


# ---- world files ---------------------------------------------------------------------------------------------------

BUNDLED = ("office", "room")


def _worlds_dir() -> Path:
    return Path(str(resources.files("kosmap.tools.simulate") / "worlds"))


def world_file(name_or_path: str | Path) -> Path:
    """The YAML file of a bundled world name or a path."""
    p = Path(name_or_path)
    if str(name_or_path) in BUNDLED:
        return _worlds_dir() / f"{name_or_path}.yaml"
    if p.suffix in (".yaml", ".yml"):
        if not p.is_file():
            raise WorldError(f"world file {p} does not exist; give a world YAML or one of: {', '.join(BUNDLED)}")
        return p
    raise WorldError(f"unknown world '{name_or_path}'; give a world YAML file or one of: {', '.join(BUNDLED)}")


def load_world(name_or_path: str | Path) -> World:
    """A bundled world by name ('office', 'room') or a world YAML file."""
    path = world_file(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise WorldError(f"{path} is not valid YAML ({str(e).splitlines()[0]}); fix the world file") from e
    if not isinstance(data, dict):
        raise WorldError(f"{path} is not a world file (expected keys such as walls, tables, path)")
    return world_from_dict(data, path.parent, default_name=path.stem, where=str(path))


_KNOWN = {"name", "description", "wall_height", "wall_thickness", "walls", "floorplan", "doors", "tables",
          "shelves", "obstacles", "boxes", "ramps", "cylinders", "path", "paths"}


class _Reader:
    """Typed access to one YAML item with errors that name the file and the item."""

    def __init__(self, where: str, what: str, item) -> None:
        self.where, self.what, self.item = where, what, item
        if not isinstance(item, dict):
            self.fail(f"must be a mapping of keys, got {item!r}")

    def fail(self, why: str):
        raise WorldError(f"{self.where}: {self.what} {why}")

    def num(self, key: str, default=None, lo: float | None = None, positive: bool = False) -> float:
        v = self.item.get(key, default)
        if v is None:
            self.fail(f"lacks '{key}'")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(f"{key} = {v!r} is not a number")
        if positive and not v > 0:
            self.fail(f"{key} = {v} must be > 0")
        if lo is not None and v < lo:
            self.fail(f"{key} = {v} must be ≥ {lo}")
        return float(v)

    def vec(self, key: str, n: int, default=None) -> np.ndarray:
        v = self.item.get(key, default)
        if v is None:
            self.fail(f"lacks '{key}'")
        try:
            a = np.asarray(v, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            self.fail(f"{key} = {v!r} must be {n} numbers")
        if a.size != n or not np.all(np.isfinite(a)):
            self.fail(f"{key} = {v!r} must be {n} numbers")
        return a


def _points(v, where: str, what: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise WorldError(f"{where}: {what} must be a list of [x, y] points") from None
    if a.ndim != 2 or a.shape[1] != 2 or len(a) < 2 or not np.all(np.isfinite(a)):
        raise WorldError(f"{where}: {what} must be a list of at least two [x, y] points")
    return a


def _wall_segments(data: dict, where: str) -> list[tuple[np.ndarray, np.ndarray]]:
    segs = []
    walls = data.get("walls") or []
    if not isinstance(walls, list):
        raise WorldError(f"{where}: walls must be a list of [x1, y1, x2, y2] segments or {{polyline: [[x, y], …]}}")
    for i, w in enumerate(walls):
        if isinstance(w, dict) and "polyline" in w:
            pts = _points(w["polyline"], where, f"walls[{i}].polyline")
            segs += [(pts[k], pts[k + 1]) for k in range(len(pts) - 1)]
        else:
            try:
                a = np.asarray(w, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                a = np.zeros(0)
            if a.size != 4 or not np.all(np.isfinite(a)):
                raise WorldError(f"{where}: walls[{i}] = {w!r} must be [x1, y1, x2, y2] or {{polyline: [[x, y], …]}}")
            segs.append((a[:2], a[2:]))
    for i, (a, b) in enumerate(segs):
        if np.hypot(*(b - a)) < 1e-6:
            raise WorldError(f"{where}: wall segment {i} from {a.tolist()} to {b.tolist()} has zero length")
    return segs


def _cut_doors(segs, doors, thickness: float, where: str):
    """Remove each door's gap (width along the wall) from every wall segment passing through its point.
    Segments are (a, b, extend_a, extend_b); the ends a door creates are not extended."""
    segs = [(a, b, True, True) for a, b in segs]
    for i, d in enumerate(doors):
        r = _Reader(where, f"doors[{i}]", d)
        at = r.vec("at", 2)
        width = r.num("width", 1.0, positive=True)
        out, cut = [], False
        for a, b, ea, eb in segs:
            ab = b - a
            length = float(np.hypot(*ab))
            u = ab / length
            s = float((at - a) @ u)
            off = abs(float((at - a) @ np.array([-u[1], u[0]])))
            if off <= thickness and -width / 2 < s < length + width / 2:
                cut = True
                if s - width / 2 > 1e-6:
                    out.append((a, a + u * (s - width / 2), ea, False))
                if length - (s + width / 2) > 1e-6:
                    out.append((a + u * (s + width / 2), b, False, eb))
            else:
                out.append((a, b, ea, eb))
        if not cut:
            raise WorldError(f"{where}: doors[{i}] at {at.tolist()} is on no wall; put it on a wall's line")
        segs = out
    return segs


def floorplan_rectangles(occupied: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the occupied cells of a raster (row 0 = bottom) with axis-aligned rectangles
    (col0, row0, col1, row1), exclusive ends: runs per row, merged with identical runs in the next rows."""
    h, w = occupied.shape
    open_runs: dict[tuple[int, int], int] = {}
    rects = []
    for r in range(h + 1):
        runs = set()
        if r < h:
            row = np.concatenate(([False], occupied[r].astype(bool), [False]))
            edges = np.flatnonzero(row[1:] != row[:-1])
            runs = {(int(edges[k]), int(edges[k + 1])) for k in range(0, len(edges), 2)}
        for run in list(open_runs):
            if run not in runs:
                rects.append((run[0], open_runs.pop(run), run[1], r))
        for run in runs:
            open_runs.setdefault(run, r)
    return sorted(rects, key=lambda t: (t[1], t[0]))


def _floorplan_walls(world: World, spec, base: Path, where: str) -> None:
    from kosmap.mapping.mapio import read_map_server

    p = Path(spec)
    p = p if p.is_absolute() else base / p
    grid = read_map_server(p)
    if abs(grid.origin[2]) > 1e-9:
        raise WorldError(f"{where}: floor plan {p} has a rotated origin (yaw {grid.origin[2]}); kosmap reads yaw 0")
    res, (ox, oy) = grid.resolution, grid.origin[:2]
    for k, (c0, r0, c1, r1) in enumerate(floorplan_rectangles(grid.data >= 65)):
        poly = np.array([[c0, r0], [c1, r0], [c1, r1], [c0, r1]], float) * res + [ox, oy]
        world.add_prism(f"wall {k}", "wall", poly, 0.0, world.wall_height, "wall", "wall", "wall")


def world_from_dict(data: dict, base: Path = Path("."), default_name: str = "world", where: str = "world") -> World:
    """Build a World from the parsed YAML of a world file (see the bundled worlds for the format)."""
    unknown = sorted(set(data) - _KNOWN)
    if unknown:
        raise WorldError(f"{where}: unknown key(s) {', '.join(unknown)}; known keys are {', '.join(sorted(_KNOWN))}")
    top = _Reader(where, "world", data)
    world = World(str(data.get("name", default_name)), top.num("wall_height", 2.7, positive=True))
    world.description = str(data.get("description", ""))
    thickness = top.num("wall_thickness", 0.15, positive=True)
    segs = _cut_doors(_wall_segments(data, where), data.get("doors") or [], thickness, where)
    for i, (a, b, ea, eb) in enumerate(segs):
        world.add_wall(f"wall {i}", a, b, thickness, ea, eb)
    if data.get("floorplan"):
        _floorplan_walls(world, data["floorplan"], base, where)
    if not world.solids:
        raise WorldError(f"{where}: the world has no walls; give `walls` segments or a `floorplan` map")
    H = world.wall_height

    def items(key: str):
        v = data.get(key) or []
        if not isinstance(v, list):
            raise WorldError(f"{where}: {key} must be a list")
        return [(i, _Reader(where, f"{key}[{i}]", it)) for i, it in enumerate(v)]

    for i, r in items("tables"):
        world.add_table(str(r.item.get("name", f"table {i}")), r.vec("center", 2), r.vec("size", 2),
                        math.radians(r.num("yaw", 0.0)), r.num("height", 0.75, positive=True),
                        r.num("top", 0.04, positive=True), r.num("leg", 0.05, positive=True))
    for key, kind, height in (("shelves", "shelf", 1.8), ("obstacles", "obstacle", 0.2)):
        for i, r in items(key):
            world.add_prism(str(r.item.get("name", f"{kind} {i}")), kind,
                            rectangle(r.vec("center", 2), r.vec("size", 2), math.radians(r.num("yaw", 0.0))),
                            0.0, min(r.num("height", height, positive=True), H))
    for i, r in items("boxes"):
        z = r.vec("z", 2)
        if not (0 <= z[0] < z[1]):
            r.fail(f"z = {z.tolist()} must be [bottom, top] with 0 ≤ bottom < top")
        world.add_prism(str(r.item.get("name", f"box {i}")), "box",
                        rectangle(r.vec("center", 2), r.vec("size", 2), math.radians(r.num("yaw", 0.0))),
                        float(z[0]), float(min(z[1], H)))
    for i, r in items("ramps"):
        world.add_ramp(str(r.item.get("name", f"ramp {i}")), r.vec("center", 2), r.vec("size", 2),
                       math.radians(r.num("yaw", 0.0)), r.num("height", 0.2, positive=True))
    for i, r in items("cylinders"):
        z = r.vec("z", 2, [0.0, 1.7])
        if not (0 <= z[0] < z[1]):
            r.fail(f"z = {z.tolist()} must be [bottom, top] with 0 ≤ bottom < top")
        world.add_cylinder(str(r.item.get("name", f"cylinder {i}")), r.vec("center", 2),
                           r.num("radius", positive=True), float(z[0]), float(min(z[1], H)))
    if data.get("path") is not None:
        world.path = path_from_dict(data["path"], where)
    named = data.get("paths") or {}
    if not isinstance(named, dict):
        raise WorldError(f"{where}: paths must be a table of named paths ({{name: {{waypoints: …}}}})")
    for name, p in named.items():
        world.paths[str(name)] = path_from_dict(p, f"{where} (paths.{name})")
    return world


SPIN_SIDE = 0.4  # m: the square a {spin: [x, y]} waypoint drives round, turning 90° in place at each corner


def _expand_spins(wps, where: str) -> list:
    """Waypoints with each {spin: [x, y]} replaced by (x, y) and a 0.4 m square back to it: four 90° turns in
    place, so a narrow depth camera looks all round the room (a survey's way to see every wall)."""
    out = []
    for i, w in enumerate(wps if isinstance(wps, list) else []):
        if isinstance(w, dict):
            if set(w) != {"spin"}:
                raise WorldError(f"{where}: waypoint {i} must be [x, y] or {{spin: [x, y]}}, not {w}")
            x, y = _points([w["spin"], w["spin"]], where, f"waypoint {i}'s spin")[0]
            d = SPIN_SIDE
            out += [[x, y], [x + d, y], [x + d, y + d], [x, y + d], [x, y]]
        else:
            out.append(w)
    return out if isinstance(wps, list) else wps


def path_from_dict(p, where: str) -> PathSpec:
    """A path: {waypoints: [[x, y] or {spin: [x, y]}, …], start_yaw: degrees (optional)} or a bare list of points."""
    if isinstance(p, list):
        p = {"waypoints": p}
    r = _Reader(where, "path", p)
    wps = _points(_expand_spins(p.get("waypoints"), where), where, "path.waypoints")
    yaw = p.get("start_yaw")
    return PathSpec(wps, None if yaw is None else math.radians(r.num("start_yaw")))


def load_path(path: str | Path) -> PathSpec:
    """A path file: YAML ({waypoints: …} or a list of [x, y]) or text with one `x y` per line."""
    p = Path(path)
    if not p.is_file():
        raise WorldError(f"path file {p} does not exist; give a YAML or text file of waypoints")
    text = p.read_text()
    if p.suffix in (".yaml", ".yml"):
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise WorldError(f"{p} is not valid YAML ({str(e).splitlines()[0]})") from e
        return path_from_dict(data, str(p))
    rows = []
    for k, line in enumerate(text.splitlines()):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            rows.append([float(v) for v in line.replace(",", " ").split()[:2]])
        except ValueError:
            raise WorldError(f"{p}:{k + 1}: '{line}' is not 'x y'") from None
    return PathSpec(_points(rows, str(p), "the waypoints"))
