"""A simulated tabletop: a table with boxes 4–9 cm high on it, seen from above at an angle, ray-cast exactly by
tools/boxroom.py's renderer with its Kinect-like noise (the scene FSPF+ must not bridge: a tilted plane through
the table and the box tops beside it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kosmap.frontend.camera import mount_transform, rays
from kosmap.frontend.records import CameraModel, Transform
from kosmap.tools.boxroom import Rect, noise_sigma

TABLE_Z = 0.75
TABLE = 1


@dataclass
class Tabletop:
    """A 1.6 × 1.2 m table top (surface id 1) at TABLE_Z with `n_boxes` boxes on it (ids 10, 11, …: top, then
    the four sides), sizes and places drawn from `seed`."""

    seed: int = 0
    n_boxes: int = 6
    surfaces: list[Rect] = field(default_factory=list)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        s = [Rect(TABLE, "ground", np.array([0.4, -0.8, TABLE_Z]), np.array([1.2, 0.0, 0.0]), np.array([0.0, 1.6, 0.0]))]
        k = 10
        placed: list[tuple[float, float, float, float]] = []
        while len(placed) < self.n_boxes:
            w, d, h = rng.uniform(0.12, 0.3), rng.uniform(0.12, 0.3), rng.uniform(0.04, 0.09)
            x, y = rng.uniform(0.5, 1.5 - w), rng.uniform(-0.7, 0.7 - d)
            if any(x < bx + bw + 0.03 and bx < x + w + 0.03 and y < by + bd + 0.03 and by < y + d + 0.03
                   for bx, by, bw, bd in placed):
                continue
            placed.append((x, y, w, d))
            z0, z1 = TABLE_Z, TABLE_Z + h
            o = np.array([x, y, z0])
            ex, ey, ez = np.array([w, 0, 0.0]), np.array([0, d, 0.0]), np.array([0, 0, h])
            s += [Rect(k, "box", o + ez, ex, ey),  # top
                  Rect(k + 1, "box", o, ez, ey), Rect(k + 2, "box", o + ex, ey, ez),  # near and far sides
                  Rect(k + 3, "box", o, ex, ez), Rect(k + 4, "box", o + ey, ez, ex)]  # right and left sides
            k += 5
        self.surfaces = s


def tabletop_frame(scene_seed: int, noise_seed: int = 0, pitch_deg: float = 45.0, height: float = 1.55):
    """(depth, surface ids, camera, table normal in the optical frame) of a 640×480 camera (fx = fy = 525) at
    `height` above the floor, `pitch_deg` down, looking at the tabletop."""
    cam = CameraModel(640, 480, np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]]), np.zeros(5), "plumb_bob",
                      "camera_optical_frame")
    mount = mount_transform([0.0, 0.0, height], [0.0, np.radians(pitch_deg), 0.0])
    depth, sid = render_tabletop(Tabletop(scene_seed), mount, cam, np.random.default_rng(noise_seed))
    R = mount.matrix()[:3, :3]
    return depth, sid, cam, R.T @ np.array([0.0, 0.0, 1.0])


def render_tabletop(scene: Tabletop, mount: Transform, cam: CameraModel, rng: np.random.Generator):
    """tools/boxroom.py's render_depth (robot at the origin) with each rectangle tested only on the rays of its
    image bounding box: the same depths and ids, bit for bit, in a fraction of the time (a box face's plane lies in
    front of most of the table, so the full test ray-casts the whole image 31 times)."""
    Rm = mount.matrix()
    R, t = Rm[:3, :3], Rm[:3, 3]
    ray = rays(cam).reshape(-1, 3)
    dirs = ray @ R.T
    best = np.full(len(dirs), np.inf)
    sid = np.zeros(len(dirs), np.int32)
    h, w = cam.height, cam.width
    for r in scene.surfaces:
        corners = (np.array([r.o, r.o + r.u, r.o + r.v, r.o + r.u + r.v]) - t) @ R  # optical frame
        if (corners[:, 2] > 1e-3).all():
            px = cam.fx * corners[:, 0] / corners[:, 2] + cam.cx
            py = cam.fy * corners[:, 1] / corners[:, 2] + cam.cy
            c0, c1 = max(0, int(np.floor(px.min())) - 1), min(w - 1, int(np.ceil(px.max())) + 1)
            r0, r1 = max(0, int(np.floor(py.min())) - 1), min(h - 1, int(np.ceil(py.max())) + 1)
            if c0 > c1 or r0 > r1:
                continue
            sel = (np.arange(r0, r1 + 1)[:, None] * w + np.arange(c0, c1 + 1)[None, :]).ravel()
        else:
            sel = np.arange(len(dirs))
        n = r.normal
        d_sel = dirs[sel]
        denom = d_sel @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (n @ (r.o - t)) / denom
        ok = np.isfinite(lam) & (lam > 1e-6) & (lam < best[sel])
        if not ok.any():
            continue
        p = t + lam[ok, None] * d_sel[ok]
        q = p - r.o
        a = q @ r.u / (r.u @ r.u)
        b = q @ r.v / (r.v @ r.v)
        inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        hit = np.flatnonzero(ok)[inside]
        best[sel[hit]] = lam[hit]
        sid[sel[hit]] = r.id
    depth = np.where(np.isfinite(best), best, 0.0)
    depth = depth + rng.normal(size=depth.shape) * noise_sigma(depth) * (depth > 0)
    depth = np.round(depth * 1000.0) / 1000.0
    return depth.reshape(h, w).astype(np.float32), sid.reshape(h, w)
