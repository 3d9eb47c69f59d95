"""Ray casting of depth images and laser scans against a World (numba kernels, exact, noise-free).

Every solid is a vertical prism over a convex footprint cut by non-vertical planes (world.py), so a ray's
entry is the slab test of Kay & Kajiya: the largest entering parameter over the footprint's edges (or the
circle) and the caps, accepted when it is below the smallest exiting one.

Speed (tools/bench_simulate.py): for a camera whose image columns stay vertical in the world (no roll, no
pitch: the optical y axis is ±z) every pixel of a column shares one horizontal direction, so the footprint
intervals are computed once per column (one 2D ray, as the issue asks) and each pixel only adds its caps
and the floor/ceiling; the candidates are sorted by entry and the walk stops at the first one that starts
behind the best hit. Any other camera falls back to casting each pixel in 3D against the objects sorted
by a lower bound of their distance, stopping at the first bound behind the best hit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from kosmap.frontend.camera import mount_transform
from kosmap.frontend.records import CameraModel, Transform
from kosmap.tools.simulate.world import World

EPS = 1e-9
OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)  # REP 103 optical frame in camera_link, as roll, pitch, yaw

KINECT_V2_WIDTH, KINECT_V2_HEIGHT = 512, 424
KINECT_V2_FOV_DEG = (70.6, 60.0)


# ---- mounts and sensor models -------------------------------------------------------------------------------------

def camera_mount(xyz=(0.1, 0.0, 1.0), rpy=(0.0, 0.0, 0.0), frame_id: str = "kinect2_ir_optical_frame") -> Transform:
    """base_link ← optical frame of a camera whose camera_link sits at `xyz` with roll, pitch, yaw `rpy`
    (rad; pitch > 0 looks down), with the REP 103 optical rotation appended (frontend.camera)."""
    return mount_transform(xyz, rpy, "base_link", frame_id)


def laser_mount(xyz=(0.15, 0.0, 0.35), rpy=(0.0, 0.0, 0.0), frame_id: str = "laser") -> Transform:
    """base_link ← laser frame (x forward, z up; the scan plane is its x-y plane)."""
    return Transform.from_xyz_rpy("base_link", frame_id, xyz, rpy)


def kinect_v2_model(frame_id: str = "kinect2_ir_optical_frame", width: int = KINECT_V2_WIDTH,
                    height: int = KINECT_V2_HEIGHT, fov_h_deg: float = KINECT_V2_FOV_DEG[0],
                    fov_v_deg: float = KINECT_V2_FOV_DEG[1]) -> CameraModel:
    """The Kinect v2 depth camera (512×424, 70.6°×60°) as a pinhole model: fx = (w/2)/tan(fH/2) (docs/design.md)."""
    return CameraModel.from_fov(width, height, math.radians(fov_h_deg), math.radians(fov_v_deg), frame_id)


@dataclass(frozen=True)
class LaserModel:
    """A planar scanner; defaults: Hokuyo UTM-30LX (1081 beams over 270°, 0.1–30 m, 25 ms per scan)."""

    beams: int = 1081
    fov_deg: float = 270.0
    range_min: float = 0.1
    range_max: float = 30.0
    scan_time: float = 0.025

    @property
    def angle_min(self) -> float:
        return -math.radians(self.fov_deg) / 2.0

    @property
    def angle_increment(self) -> float:
        return math.radians(self.fov_deg) / (self.beams - 1)

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + np.arange(self.beams) * self.angle_increment


def pose_matrix(pose_xyyaw) -> np.ndarray:
    """world ← base_link for a planar pose (x, y, yaw) on the floor."""
    x, y, yaw = (float(v) for v in pose_xyyaw)
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = [x, y]
    return m


# ---- the scene as flat arrays for the kernels ---------------------------------------------------------------------

@dataclass(frozen=True)
class Scene:
    kind: np.ndarray  # (n,) 0 polygon, 1 circle
    bc: np.ndarray  # (n, 3) bounding circle cx, cy, r
    edge_rng: np.ndarray  # (n, 2)
    edges: np.ndarray  # (m, 3) nx, ny, d   (inside: n·xy ≤ d)
    edge_id: np.ndarray  # (m,)
    circ: np.ndarray  # (n, 3)
    circ_id: np.ndarray  # (n,)
    cap_rng: np.ndarray  # (n, 2)
    caps: np.ndarray  # (k, 4) nx, ny, nz, d
    cap_id: np.ndarray  # (k,)
    floor_id: int
    ceil_id: int
    ceil_z: float
    seg_a: np.ndarray  # (m, 2) start vertex of each edge (for distances and angular extents)
    seg_b: np.ndarray  # (m, 2) end vertex

    def args(self) -> tuple:
        return (self.kind, self.edge_rng, self.edges, self.edge_id, self.circ, self.circ_id, self.cap_rng,
                self.caps, self.cap_id, self.floor_id, self.ceil_id, self.ceil_z)


def scene_of(world: World) -> Scene:
    """The world's solids flattened into arrays (cached on the world; rebuilt if solids were added)."""
    cached = getattr(world, "_scene", None)
    if cached is not None and cached[0] == len(world.solids):
        return cached[1]
    n = len(world.solids)
    kind = np.zeros(n, np.int64)
    bc = np.zeros((n, 3))
    edge_rng = np.zeros((n, 2), np.int64)
    circ = np.zeros((n, 3))
    circ_id = np.zeros(n, np.int64)
    cap_rng = np.zeros((n, 2), np.int64)
    edges, edge_id, caps, cap_id, seg_a, seg_b = [], [], [], [], [], []
    for i, s in enumerate(world.solids):
        bc[i] = s.bounding_circle()
        edge_rng[i, 0] = len(edges)
        if s.circle is not None:
            kind[i] = 1
            circ[i] = s.circle
            circ_id[i] = s.circle_id
        else:
            poly = s.polygon
            for k in range(len(poly)):
                a, b = poly[k], poly[(k + 1) % len(poly)]
                e = b - a
                nrm = np.array([e[1], -e[0]]) / math.hypot(*e)
                edges.append((nrm[0], nrm[1], float(nrm @ a)))
                edge_id.append(s.edge_ids[k])
                seg_a.append(a)
                seg_b.append(b)
        edge_rng[i, 1] = len(edges)
        cap_rng[i, 0] = len(caps)
        for nrm, d, sid in s.caps:
            caps.append((nrm[0], nrm[1], nrm[2], d))
            cap_id.append(sid)
        cap_rng[i, 1] = len(caps)
    scene = Scene(kind, bc, edge_rng, np.array(edges, float).reshape(-1, 3), np.array(edge_id, np.int64),
                  circ, circ_id, cap_rng, np.array(caps, float).reshape(-1, 4), np.array(cap_id, np.int64),
                  world.floor_id, world.ceiling_id, world.wall_height,
                  np.array(seg_a, float).reshape(-1, 2), np.array(seg_b, float).reshape(-1, 2))
    world._scene = (n, scene)
    return scene


# ---- kernels -----------------------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _fp_circle(o, px, py, dx, dy, circ, circ_id):
    """Interval [tin, tout] of the ray p + t·d (its horizontal part) inside circle o, the surface id and the
    2D normal where it enters; tin > tout when it misses. (Callers branch on the kind themselves: numba
    compiles one function returning from both kinds' branches ~8× slower.)"""
    cx, cy, r = circ[o, 0], circ[o, 1], circ[o, 2]
    fx, fy = px - cx, py - cy
    A = dx * dx + dy * dy
    C = fx * fx + fy * fy - r * r
    if A < 1e-24:
        if C <= 0.0:
            return -1e300, 1e300, circ_id[o], 0.0, 0.0
        return 1.0, 0.0, -1, 0.0, 0.0
    B = fx * dx + fy * dy
    disc = B * B - A * C
    if disc < 0.0:
        return 1.0, 0.0, -1, 0.0, 0.0
    sq = math.sqrt(disc)
    t0 = (-B - sq) / A
    t1 = (-B + sq) / A
    return t0, t1, circ_id[o], (fx + t0 * dx) / r, (fy + t0 * dy) / r


@njit(cache=True, error_model="numpy")
def _fp_poly(o, px, py, dx, dy, edge_rng, edges, edge_id):
    """As _fp_circle for a convex polygon: the slab test over its edges (n·xy ≤ d inside)."""
    tin, tout, fid, nx, ny = -1e300, 1e300, -1, 0.0, 0.0
    for j in range(edge_rng[o, 0], edge_rng[o, 1]):
        ex, ey, ed = edges[j, 0], edges[j, 1], edges[j, 2]
        den = ex * dx + ey * dy
        num = ed - (ex * px + ey * py)
        if abs(den) < 1e-15:
            if num < 0.0:
                return 1.0, 0.0, -1, 0.0, 0.0
            continue
        t = num / den
        if den < 0.0:
            if t > tin:
                tin, fid, nx, ny = t, edge_id[j], ex, ey
        elif t < tout:
            tout = t
    return tin, tout, fid, nx, ny


@njit(cache=True, error_model="numpy")
def _caps(o, px, py, pz, dx, dy, dz, tin, tout, fid, nx, ny, nz, cap_rng, caps, cap_id):
    """Narrow [tin, tout] by object o's non-vertical planes (top, bottom, slope)."""
    for j in range(cap_rng[o, 0], cap_rng[o, 1]):
        cx, cy, cz, cd = caps[j, 0], caps[j, 1], caps[j, 2], caps[j, 3]
        den = cx * dx + cy * dy + cz * dz
        num = cd - (cx * px + cy * py + cz * pz)
        if abs(den) < 1e-15:
            if num < 0.0:
                tin, tout = 1.0, 0.0
                break
            continue
        t = num / den
        if den < 0.0:
            if t > tin:
                tin, fid, nx, ny, nz = t, cap_id[j], cx, cy, cz
        elif t < tout:
            tout = t
    return tin, tout, fid, nx, ny, nz


@njit(cache=True, error_model="numpy")
def _floor_ceiling(pz, dz, tmax, floor_id, ceil_id, ceil_z):
    """(t, id, normal z) of the floor or ceiling hit, or (tmax, 0, 0) when it is beyond tmax."""
    t, sid, nz = tmax, 0, 0.0
    if dz < -1e-15:
        tf = -pz / dz
        if tf < tmax:
            t, sid, nz = tf, floor_id, 1.0
    elif dz > 1e-15:
        tc = (ceil_z - pz) / dz
        if tc < tmax:
            t, sid, nz = tc, ceil_id, -1.0
    return t, sid, nz


@njit(cache=True, error_model="numpy")
def _render_columns(pos, R, a, b, tmax, order,
                    kind, edge_rng, edges, edge_id, circ, circ_id, cap_rng, caps, cap_id, floor_id, ceil_id, ceil_z,
                    out_t, out_id, out_cos):
    """Depth image of a camera whose optical y axis is vertical: one footprint pass per column (a 2D ray),
    then per pixel only caps, floor and ceiling. Pixel ray: R·(a[u], b[v], 1), t = optical depth.
    Outputs are W×H (column-major image) so each column is written contiguously."""
    n = order.shape[0]
    c_tin = np.empty(n)
    c_tout = np.empty(n)
    c_fid = np.empty(n, np.int64)
    c_nx = np.empty(n)
    c_ny = np.empty(n)
    c_obj = np.empty(n, np.int64)
    px, py, pz = pos[0], pos[1], pos[2]
    kz = R[2, 1]
    for u in range(a.shape[0]):
        dx = R[0, 0] * a[u] + R[0, 2]
        dy = R[1, 0] * a[u] + R[1, 2]
        dz0 = R[2, 0] * a[u] + R[2, 2]
        m = 0
        for j in range(n):
            o = order[j]
            if kind[o] == 1:
                tin, tout, fid, nx, ny = _fp_circle(o, px, py, dx, dy, circ, circ_id)
            else:
                tin, tout, fid, nx, ny = _fp_poly(o, px, py, dx, dy, edge_rng, edges, edge_id)
            if tin > tout or tout <= EPS or tin >= tmax:
                continue
            k = m
            while k > 0 and c_tin[k - 1] > tin:
                c_tin[k], c_tout[k], c_fid[k] = c_tin[k - 1], c_tout[k - 1], c_fid[k - 1]
                c_nx[k], c_ny[k], c_obj[k] = c_nx[k - 1], c_ny[k - 1], c_obj[k - 1]
                k -= 1
            c_tin[k], c_tout[k], c_fid[k], c_nx[k], c_ny[k], c_obj[k] = tin, tout, fid, nx, ny, o
            m += 1
        for v in range(b.shape[0]):
            dz = dz0 + kz * b[v]
            best, bid, bnz = _floor_ceiling(pz, dz, tmax, floor_id, ceil_id, ceil_z)
            bnx, bny = 0.0, 0.0
            for c in range(m):
                tin = c_tin[c]
                if tin >= best:
                    break
                tout, fid, nx, ny, nz = c_tout[c], c_fid[c], c_nx[c], c_ny[c], 0.0
                o = c_obj[c]
                for j in range(cap_rng[o, 0], cap_rng[o, 1]):  # the caps (as in _caps, written out for speed)
                    cx, cy, cz, cd = caps[j, 0], caps[j, 1], caps[j, 2], caps[j, 3]
                    den = cx * dx + cy * dy + cz * dz
                    num = cd - (cx * px + cy * py + cz * pz)
                    if abs(den) < 1e-15:
                        if num < 0.0:
                            tin, tout = 1.0, 0.0
                            break
                        continue
                    t = num / den
                    if den < 0.0:
                        if t > tin:
                            tin, fid, nx, ny, nz = t, cap_id[j], cx, cy, cz
                    elif t < tout:
                        tout = t
                if tin <= tout and tin > EPS and tin < best:
                    best, bid, bnx, bny, bnz = tin, fid, nx, ny, nz
            if bid == 0:
                out_t[u, v] = 0.0
                out_id[u, v] = 0
                out_cos[u, v] = 0.0
            else:
                out_t[u, v] = best
                out_id[u, v] = bid
                out_cos[u, v] = abs(bnx * dx + bny * dy + bnz * dz) / math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, error_model="numpy")
def _cast_binned(ox, oy, oz, dirs, tmax, bin_start, bin_items, lower,
                 kind, edge_rng, edges, edge_id, circ, circ_id, cap_rng, caps, cap_id, floor_id, ceil_id, ceil_z,
                 out_t, out_id, out_cos):
    """Rays from origins ox, oy, oz (N each, or 1 shared) along dirs (N×3), each against the objects listed in the angular bin
    of its bearing (each list sorted by `lower`, a lower bound of the object's horizontal distance; the walk
    stops at the first bound behind the best hit). t is in units of |dir|.
    (The loop body is written out here: numba does not inline a callee taking this many arrays, and the
    call costs more than the work.)"""
    nb = bin_start.shape[0] - 1
    shared = ox.shape[0] == 1
    for i in range(dirs.shape[0]):
        io = 0 if shared else i
        px, py, pz = ox[io], oy[io], oz[io]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        best, bid, bnz = _floor_ceiling(pz, dz, tmax, floor_id, ceil_id, ceil_z)
        bnx, bny = 0.0, 0.0
        dh = math.sqrt(dx * dx + dy * dy)
        k = min(int(_pseudo_angle(dx, dy) * (0.25 * nb)), nb - 1)
        for j in range(bin_start[k], bin_start[k + 1]):
            o = bin_items[j]
            lb = lower[o]
            if lb > 0.0 and (dh < 1e-15 or lb >= best * dh):
                break
            if kind[o] == 1:
                tin, tout, fid, nx, ny = _fp_circle(o, px, py, dx, dy, circ, circ_id)
            else:
                tin, tout, fid, nx, ny = _fp_poly(o, px, py, dx, dy, edge_rng, edges, edge_id)
            if tin > tout or tout <= EPS or tin >= best:
                continue
            nz = 0.0
            for jc in range(cap_rng[o, 0], cap_rng[o, 1]):  # the caps (as in _caps, written out for speed)
                cx, cy, cz, cd = caps[jc, 0], caps[jc, 1], caps[jc, 2], caps[jc, 3]
                den = cx * dx + cy * dy + cz * dz
                num = cd - (cx * px + cy * py + cz * pz)
                if abs(den) < 1e-15:
                    if num < 0.0:
                        tin, tout = 1.0, 0.0
                        break
                    continue
                t = num / den
                if den < 0.0:
                    if t > tin:
                        tin, fid, nx, ny, nz = t, cap_id[jc], cx, cy, cz
                elif t < tout:
                    tout = t
            if tin <= tout and tin > EPS and tin < best:
                best, bid, bnx, bny, bnz = tin, fid, nx, ny, nz
        if bid == 0:
            out_t[i], out_id[i], out_cos[i] = 0.0, 0, 0.0
        else:
            out_t[i] = best
            out_id[i] = bid
            out_cos[i] = abs(bnx * dx + bny * dy + bnz * dz) / math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, error_model="numpy")
def _render_naive(pos, R, a, b, tmax, order,
                  kind, edge_rng, edges, edge_id, circ, circ_id, cap_rng, caps, cap_id, floor_id, ceil_id, ceil_z,
                  out_t, out_id, out_cos):
    """The baseline: every pixel in 3D against every object within reach, no acceleration."""
    for v in range(b.shape[0]):
        for u in range(a.shape[0]):
            dx = R[0, 0] * a[u] + R[0, 1] * b[v] + R[0, 2]
            dy = R[1, 0] * a[u] + R[1, 1] * b[v] + R[1, 2]
            dz = R[2, 0] * a[u] + R[2, 1] * b[v] + R[2, 2]
            best, bid, bnz = _floor_ceiling(pos[2], dz, tmax, floor_id, ceil_id, ceil_z)
            bnx, bny = 0.0, 0.0
            for j in range(order.shape[0]):
                o = order[j]
                if kind[o] == 1:
                    tin, tout, fid, nx, ny = _fp_circle(o, pos[0], pos[1], dx, dy, circ, circ_id)
                else:
                    tin, tout, fid, nx, ny = _fp_poly(o, pos[0], pos[1], dx, dy, edge_rng, edges, edge_id)
                tin, tout, fid, nx, ny, nz = _caps(o, pos[0], pos[1], pos[2], dx, dy, dz, tin, tout, fid, nx, ny, 0.0,
                                                   cap_rng, caps, cap_id)
                if tin <= tout and tin > EPS and tin < best:
                    best, bid, bnx, bny, bnz = tin, fid, nx, ny, nz
            if bid == 0:
                out_t[v, u], out_id[v, u], out_cos[v, u] = 0.0, 0, 0.0
            else:
                out_t[v, u] = best
                out_id[v, u] = bid
                out_cos[v, u] = abs(bnx * dx + bny * dy + bnz * dz) / math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def _pseudo_angle(x, y):
    """The "diamond angle": a monotone stand-in for the bearing atan2(y, x) in [0, 4) over [0, 2π). The 3D
    casts bin rays by it because atan2 cost more than the rest of a ray."""
    if y >= 0.0:
        if x >= 0.0:
            return y / (x + y) if x + y > 0.0 else 0.0
        return 1.0 - x / (y - x)
    if x < 0.0:
        return 2.0 - y / (-x - y)
    return 3.0 + x / (x - y)


@njit(cache=True)
def _pixel_dirs(R, a, b):
    """World directions R·(a[u], b[v], 1) of every pixel, row-major (H·W × 3)."""
    out = np.empty((b.shape[0] * a.shape[0], 3))
    i = 0
    for v in range(b.shape[0]):
        for u in range(a.shape[0]):
            for k in range(3):
                out[i, k] = R[k, 0] * a[u] + R[k, 1] * b[v] + R[k, 2]
            i += 1
    return out


@njit(cache=True)
def _fill_bins(order, b0, b1, nbins):
    """CSR lists of objects per angular bin; objects arrive in `order` (sorted by distance), so each list is
    sorted too. Object k covers bins b0[k]..b1[k] (inclusive, modulo nbins; all when the span ≥ nbins)."""
    count = np.zeros(nbins + 1, np.int64)
    for k in range(order.shape[0]):
        span = b1[k] - b0[k] + 1
        if span >= nbins:
            for j in range(nbins):
                count[j + 1] += 1
        else:
            for j in range(b0[k], b1[k] + 1):
                count[j % nbins + 1] += 1
    for j in range(nbins):
        count[j + 1] += count[j]
    items = np.empty(count[nbins], np.int64)
    fill = count[:-1].copy()
    for k in range(order.shape[0]):
        span = b1[k] - b0[k] + 1
        if span >= nbins:
            for j in range(nbins):
                items[fill[j]] = order[k]
                fill[j] += 1
        else:
            for j in range(b0[k], b1[k] + 1):
                jj = j % nbins
                items[fill[jj]] = order[k]
                fill[jj] += 1
    return count, items


# ---- culling ---------------------------------------------------------------------------------------------------------

def _sorted_candidates(scene: Scene, xy: np.ndarray, reach: float, spread: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Objects whose bounding circle comes within `reach` (horizontal) of xy, sorted by a lower bound of
    their horizontal distance (less `spread`, how far the rays' origins stray from xy)."""
    d = np.hypot(scene.bc[:, 0] - xy[0], scene.bc[:, 1] - xy[1]) - scene.bc[:, 2] - spread
    keep = np.flatnonzero(d < reach)
    order = keep[np.argsort(d[keep], kind="stable")]
    return order.astype(np.int64), np.maximum(d[order], 0.0)


NBINS = 2048  # angular bins over 360° for the 3D casts (0.18° each; a Kinect column is 0.14°)


def diamond_angle(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Vectorised _pseudo_angle (same formula, same bins)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        q0 = np.where(x + y > 0, y / (x + y), 0.0)
        q1 = 1.0 - x / (y - x)
        q2 = 2.0 - y / (-x - y)
        q3 = 3.0 + x / (x - y)
    return np.where(y >= 0, np.where(x >= 0, q0, q1), np.where(x < 0, q2, q3))


def footprint_distances(scene: Scene, xy) -> np.ndarray:
    """Exact horizontal distance from xy to every object's footprint (0 inside)."""
    p = np.asarray(xy, float)
    n = len(scene.kind)
    dist = np.empty(n)
    circles = scene.kind == 1
    dist[circles] = np.maximum(np.hypot(scene.circ[circles, 0] - p[0], scene.circ[circles, 1] - p[1])
                               - scene.circ[circles, 2], 0.0)
    poly = ~circles
    if poly.any():
        A, B = scene.seg_a, scene.seg_b
        ab = B - A
        t = np.clip(np.einsum("ij,ij->i", p - A, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0.0, 1.0)
        dseg = np.hypot(*(p - A - t[:, None] * ab).T)
        inside_edge = scene.edges[:, :2] @ p - scene.edges[:, 2] <= 0.0
        starts = scene.edge_rng[poly, 0]
        dist[poly] = np.where(np.logical_and.reduceat(inside_edge, starts), 0.0, np.minimum.reduceat(dseg, starts))
    return dist


def angular_bins(scene: Scene, xy, reach: float, spread: float = 0.0, nbins: int = NBINS):
    """Objects within `reach` of xy binned by the bearings under which rays from within `spread` of xy can
    meet them: (bin_start (nbins+1), bin_items, lower bound of each object's distance)."""
    p = np.asarray(xy, float)
    dist = footprint_distances(scene, p)
    lower = np.maximum(dist - spread, 0.0)
    order = np.flatnonzero(lower < reach)
    order = order[np.argsort(lower[order], kind="stable")]
    ref = np.arctan2(scene.bc[:, 1] - p[1], scene.bc[:, 0] - p[0])
    lo = np.empty(len(scene.kind))
    hi = np.empty(len(scene.kind))
    circles = scene.kind == 1
    dc = np.hypot(scene.circ[:, 0] - p[0], scene.circ[:, 1] - p[1])
    half = np.arcsin(np.clip(scene.circ[:, 2] / np.maximum(dc, 1e-12), 0.0, 1.0))
    lo[circles], hi[circles] = ref[circles] - half[circles], ref[circles] + half[circles]
    poly = ~circles
    if poly.any():
        obj_of_edge = np.repeat(np.arange(len(scene.kind)), scene.edge_rng[:, 1] - scene.edge_rng[:, 0])
        va = np.arctan2(scene.seg_a[:, 1] - p[1], scene.seg_a[:, 0] - p[0])
        delta = np.mod(va - ref[obj_of_edge] + np.pi, 2 * np.pi) - np.pi
        starts = scene.edge_rng[poly, 0]
        lo[poly] = ref[poly] + np.minimum.reduceat(delta, starts)
        hi[poly] = ref[poly] + np.maximum.reduceat(delta, starts)
    pad = np.arcsin(np.clip(spread / np.maximum(dist, 1e-12), 0.0, 1.0)) + 1e-6
    lo, hi = lo - pad, hi + pad
    # bins are uniform in the diamond angle, whose bins span up to twice the nominal angle
    full = (dist <= spread + 1e-9) | (hi - lo >= 2 * np.pi - 8 * np.pi / nbins)
    b0 = np.minimum((diamond_angle(np.cos(lo), np.sin(lo)) * (nbins / 4)).astype(np.int64), nbins - 1)
    b1 = np.minimum((diamond_angle(np.cos(hi), np.sin(hi)) * (nbins / 4)).astype(np.int64), nbins - 1)
    b1 = np.where(b1 < b0, b1 + nbins, b1)
    b1 = np.where(full, b0 + nbins, b1)
    start, items = _fill_bins(order.astype(np.int64), b0[order], b1[order], nbins)
    return start, items, lower


@lru_cache(maxsize=16)
def _pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    a = (np.arange(width) - cx) / fx
    b = (np.arange(height) - cy) / fy
    a.setflags(write=False)
    b.setflags(write=False)
    return a, b


def camera_pose(pose_xyyaw, mount: Transform) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation world ← optical (3×3)) of a camera on a robot at a planar pose."""
    m = pose_matrix(pose_xyyaw) @ mount.matrix()
    return m[:3, 3].copy(), np.ascontiguousarray(m[:3, :3])


def is_column_camera(R: np.ndarray) -> bool:
    """True when the optical y axis is vertical in the world (no roll, no pitch): columns are 2D rays."""
    return abs(R[0, 1]) < 1e-12 and abs(R[1, 1]) < 1e-12


def render_depth_geometry(world: World, pose_xyyaw, mount: Transform, model: CameraModel, max_range: float = 8.0,
                          method: str = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact optical depth (float32 m, 0 = nothing within max_range), surface ids (uint16) and |cos| of the
    incidence angle (float32) of every pixel, as H×W arrays (the column method returns transposed views of
    column-major buffers). method: auto, column, pixels (3D through angular bins) or naive (3D, all objects)."""
    scene = scene_of(world)
    pos, R = camera_pose(pose_xyyaw, mount)
    a, b = _pixel_rays(model.width, model.height, model.fx, model.fy, model.cx, model.cy)
    # horizontal reach of a ray with optical depth ≤ max_range: max over the image of |horizontal part of R·(a, b, 1)|
    corners = np.array([[a[0], b[0], 1], [a[-1], b[0], 1], [a[0], b[-1], 1], [a[-1], b[-1], 1]]) @ R.T
    reach = max_range * float(np.max(np.linalg.norm(corners, axis=1)))
    order, lower = _sorted_candidates(scene, pos[:2], reach)
    H, W = model.height, model.width
    if method == "auto":
        method = "column" if is_column_camera(R) else "pixels"
    if method == "column":
        if not is_column_camera(R):
            raise ValueError("the column method needs a camera without roll and pitch")
        order = _frustum_cull(scene, order, pos, R, a)
        out_t, out_id, out_cos = np.empty((W, H), np.float32), np.empty((W, H), np.uint16), np.empty((W, H), np.float32)
        _render_columns(pos, R, a, b, max_range, order, *scene.args(), out_t, out_id, out_cos)
        return out_t.T, out_id.T, out_cos.T  # H×W views of column-major buffers (no copy)
    out_t, out_id, out_cos = np.empty((H, W), np.float32), np.empty((H, W), np.uint16), np.empty((H, W), np.float32)
    if method == "pixels":
        start, items, lower = angular_bins(scene, pos[:2], reach)
        _cast_binned(pos[0:1], pos[1:2], pos[2:3], _pixel_dirs(R, a, b), max_range, start, items, lower,
                     *scene.args(), out_t.reshape(-1), out_id.reshape(-1), out_cos.reshape(-1))
    elif method == "naive":
        _render_naive(pos, R, a, b, max_range, order, *scene.args(), out_t, out_id, out_cos)
    else:
        raise ValueError(f"unknown method {method}")
    return out_t, out_id, out_cos


def _frustum_cull(scene: Scene, order: np.ndarray, pos: np.ndarray, R: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Keep the objects whose bounding circle overlaps the horizontal field of view (column cameras)."""
    left = np.array([R[0, 0] * a[0] + R[0, 2], R[1, 0] * a[0] + R[1, 2]])
    right = np.array([R[0, 0] * a[-1] + R[0, 2], R[1, 0] * a[-1] + R[1, 2]])
    fwd = np.array([R[0, 2], R[1, 2]])
    half = max(abs(math.atan2(fwd[0] * left[1] - fwd[1] * left[0], fwd @ left)),
               abs(math.atan2(fwd[0] * right[1] - fwd[1] * right[0], fwd @ right)))
    rel = scene.bc[order, :2] - pos[:2]
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = np.arctan2(fwd[0] * rel[:, 1] - fwd[1] * rel[:, 0], rel @ fwd)
    radius = scene.bc[order, 2]
    ang = np.arcsin(np.clip(radius / np.maximum(dist, 1e-9), 0.0, 1.0))
    keep = (dist <= radius + 1e-6) | (np.abs(bearing) - ang <= half + 1e-3)
    return np.ascontiguousarray(order[keep])


def cast_rays(world: World, origins: np.ndarray, dirs: np.ndarray, tmax: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hits of N rays (world frame; t in units of each direction's length): (t or 0, id, |cos|)."""
    scene = scene_of(world)
    origins = np.ascontiguousarray(origins, dtype=float).reshape(-1, 3)
    dirs = np.ascontiguousarray(dirs, dtype=float).reshape(-1, 3)
    ref = origins.mean(axis=0)
    spread = float(np.max(np.hypot(origins[:, 0] - ref[0], origins[:, 1] - ref[1]))) if len(origins) else 0.0
    reach = tmax * float(np.max(np.hypot(dirs[:, 0], dirs[:, 1]))) if len(dirs) else 0.0
    start, items, lower = angular_bins(scene, ref[:2], reach, spread)
    n = len(origins)
    out_t, out_id, out_cos = np.empty(n), np.empty(n, np.int64), np.empty(n)
    _cast_binned(np.ascontiguousarray(origins[:, 0]), np.ascontiguousarray(origins[:, 1]),
                 np.ascontiguousarray(origins[:, 2]), dirs, tmax, start, items, lower, *scene.args(), out_t, out_id, out_cos)
    return out_t, out_id, out_cos


def laser_rays(poses: np.ndarray, mount: Transform, model: LaserModel) -> tuple[np.ndarray, np.ndarray]:
    """World origins and unit directions of each beam; `poses` is one (x, y, yaw) or one per beam (N×3)."""
    poses = np.asarray(poses, float).reshape(-1, 3)
    ang = model.angles
    m = mount.matrix()
    local = np.column_stack((np.cos(ang), np.sin(ang), np.zeros_like(ang))) @ m[:3, :3].T  # base frame
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    dirs = np.column_stack((c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1], local[:, 2]))
    ox, oy = m[0, 3], m[1, 3]
    origins = np.column_stack((poses[:, 0] + c * ox - s * oy, poses[:, 1] + s * ox + c * oy,
                               np.full(len(poses), m[2, 3])))
    if len(poses) == 1:
        origins = np.repeat(origins, len(ang), axis=0)
    return origins, dirs


def render_laser_geometry(world: World, poses, mount: Transform, model: LaserModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact ranges (+inf = nothing within range_max), surface ids and |cos| incidence of each beam."""
    origins, dirs = laser_rays(poses, mount, model)
    t, sid, cs = cast_rays(world, origins, dirs, model.range_max)
    r = np.where(sid > 0, t, np.inf)
    return r, sid, cs
