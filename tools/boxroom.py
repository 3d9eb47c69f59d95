"""A small analytic depth renderer: a box room with a ramp and a box, for plane-filtering tests and benchmarks.

Not the simulator (tools/simulate/): a handful of rectangles ray-cast exactly, with a depth noise model, so
FSPF/FSPF+ can be scored against known surfaces without any other machinery. World frame: x forward,
y left, z up (REP 103); the camera sits on a robot at (x, y, yaw) through its mount (base_link ← optical).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kosmap.frontend.camera import mount_transform, rays
from kosmap.frontend.records import CameraModel, Transform


@dataclass(frozen=True)
class Rect:
    """A planar rectangle o + a·u + b·v (0 ≤ a, b ≤ 1, u ⊥ v) with its true class."""

    id: int
    cls: str  # ground, ceiling, wall, slanted, box
    o: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.u, self.v)
        return n / np.linalg.norm(n)

    @property
    def plane(self) -> np.ndarray:
        """(a, b, c, d) with n·p + d = 0."""
        n = self.normal
        return np.append(n, -n @ self.o)


def _r(i, cls, o, u, v) -> Rect:
    return Rect(i, cls, np.asarray(o, float), np.asarray(u, float), np.asarray(v, float))


@dataclass
class BoxRoom:
    """A length × width × height room (floor at z = 0, x ∈ [0, L], y ∈ [−W/2, W/2]) with a ramp and a box."""

    length: float = 6.0
    width: float = 4.0
    height: float = 2.6
    ramp_slope_deg: float = 12.0
    surfaces: list[Rect] = field(default_factory=list)

    def __post_init__(self) -> None:
        L, W, H = self.length, self.width, self.height
        y0, y1 = -W / 2, W / 2
        s = [
            _r(1, "ground", [0, y0, 0], [L, 0, 0], [0, W, 0]),
            _r(2, "ceiling", [0, y0, H], [0, W, 0], [L, 0, 0]),
            _r(3, "wall", [L, y0, 0], [0, W, 0], [0, 0, H]),  # far wall (x = L)
            _r(4, "wall", [0, y1, 0], [L, 0, 0], [0, 0, H]),  # left wall (y = +W/2)
            _r(5, "wall", [0, y0, 0], [0, 0, H], [L, 0, 0]),  # right wall (y = −W/2)
            _r(6, "wall", [0, y0, 0], [0, W, 0], [0, 0, H]),  # back wall (x = 0)
        ]
        # a ramp rising along +x on the right half: 1.6 m long, 1.2 m wide, ramp_slope_deg
        a = np.radians(self.ramp_slope_deg)
        rl = 1.6
        s.append(_r(7, "slanted", [2.2, y0 + 0.1, 0.001], [rl * np.cos(a), 0, rl * np.sin(a)], [0, 1.2, 0]))
        # a box 0.6 × 0.6 × 0.8 m on the left: its front face (toward −x) and top
        bx, by, bh = 3.6, y1 - 1.0, 0.8
        s.append(_r(8, "box", [bx, by, 0], [0, 0.6, 0], [0, 0, bh]))
        s.append(_r(9, "box", [bx, by, bh], [0.6, 0, 0], [0, 0.6, 0]))
        s.append(_r(10, "box", [bx, by, 0], [0, 0, bh], [0.6, 0, 0]))  # its side toward −y
        self.surfaces = s

def noise_sigma(z: np.ndarray) -> np.ndarray:
    """Axial depth noise σ(z) in metres (Kinect-v2-like: 1.5 mm + 0.15 % of the range)."""
    return 0.0015 + 0.0015 * np.asarray(z)


def _rays_of(r: Rect, R: np.ndarray, t: np.ndarray, camera: CameraModel) -> np.ndarray | None:
    """The pixels (flat indices) whose rays can hit rectangle `r`: those of its image bounding box, one pixel of
    margin, when all four corners lie in front of the camera (the rectangle's image is then the convex hull of the
    corners' images); None (every pixel) otherwise. R, t: the optical frame in the world."""
    corners = (np.array([r.o, r.o + r.u, r.o + r.v, r.o + r.u + r.v]) - t) @ R  # optical frame
    if not (corners[:, 2] > 1e-3).all():
        return None
    h, w = camera.height, camera.width
    px = camera.fx * corners[:, 0] / corners[:, 2] + camera.cx
    py = camera.fy * corners[:, 1] / corners[:, 2] + camera.cy
    c0, c1 = max(0, int(np.floor(px.min())) - 1), min(w - 1, int(np.ceil(px.max())) + 1)
    r0, r1 = max(0, int(np.floor(py.min())) - 1), min(h - 1, int(np.ceil(py.max())) + 1)
    if c0 > c1 or r0 > r1:
        return np.zeros(0, np.int64)
    return (np.arange(r0, r1 + 1)[:, None] * w + np.arange(c0, c1 + 1)[None, :]).ravel()


def render_depth(room: BoxRoom, pose, mount: Transform, camera: CameraModel, rng: np.random.Generator | None,
                 quantize_mm: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Depth (m, float32 H×W, 0 = no return) and surface id (int32, 0 = none) seen from robot pose (x, y, yaw).

    With rng, Gaussian axial noise of noise_sigma(z) is added; depths are rounded to mm like a 16UC1 image. Each
    rectangle is tested only on the rays of its image bounding box (`_rays_of`): a plane lies in front of most of
    the image, and testing every ray against every rectangle dominates the time.
    """
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    world_base = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    Rm = mount.matrix()
    R = world_base @ Rm[:3, :3]
    t = world_base @ Rm[:3, 3] + np.array([x, y, 0.0])
    ray = rays(camera).reshape(-1, 3)  # optical, z = 1
    dirs = ray @ R.T  # world direction per unit optical depth
    best = np.full(len(dirs), np.inf)
    sid = np.zeros(len(dirs), np.int32)
    for r in room.surfaces:
        sel = _rays_of(r, R, t, camera)
        if sel is not None and not len(sel):
            continue
        d_sel = dirs if sel is None else dirs[sel]
        n = r.normal
        denom = d_sel @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (n @ (r.o - t)) / denom  # optical depth z of the hit
        ok = np.isfinite(lam) & (lam > 1e-6) & (lam < (best if sel is None else best[sel]))
        if not ok.any():
            continue
        p = t + lam[ok, None] * d_sel[ok]
        q = p - r.o
        a = q @ r.u / (r.u @ r.u)
        b = q @ r.v / (r.v @ r.v)
        inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        hit = np.flatnonzero(ok)[inside]
        idx = hit if sel is None else sel[hit]
        best[idx] = lam[hit]
        sid[idx] = r.id
    depth = np.where(np.isfinite(best), best, 0.0)
    if rng is not None:
        depth = depth + rng.normal(size=depth.shape) * noise_sigma(depth) * (depth > 0)
    if quantize_mm:
        depth = np.round(depth * 1000.0) / 1000.0
    h, w = camera.height, camera.width
    return depth.reshape(h, w).astype(np.float32), sid.reshape(h, w)


def kinect_v2() -> CameraModel:
    """A 512×424 Kinect v2 depth camera by the thesis's field of view (70.6° × 60°)."""
    return CameraModel.from_fov(512, 424, np.radians(70.6), np.radians(60.0), "camera_optical_frame")


def default_mount(pitch_deg: float = 0.0, height: float = 1.0) -> Transform:
    return mount_transform([0.1, 0.0, height], [0.0, np.radians(pitch_deg), 0.0])


def frame(pose=(0.6, 0.3, 0.0), pitch_deg: float = 0.0, seed: int = 0, room: BoxRoom | None = None,
          camera: CameraModel | None = None, height: float = 1.0):
    """One noisy frame: (depth, surface ids, room, camera, mount)."""
    room = room or BoxRoom()
    camera = camera or kinect_v2()
    mount = default_mount(pitch_deg, height)
    depth, sid = render_depth(room, pose, mount, camera, np.random.default_rng(seed))
    return depth, sid, room, camera, mount
