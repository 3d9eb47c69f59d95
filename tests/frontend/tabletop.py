"""A simulated tabletop: a table with boxes 4–9 cm high on it, seen from above at an angle, ray-cast exactly by
tools/boxroom.py's renderer with its Kinect-like noise (the scene FSPF+ must not bridge: a tilted plane through
the table and the box tops beside it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kosmap.frontend.camera import mount_transform
from kosmap.frontend.records import CameraModel
from kosmap.tools.boxroom import Rect, render_depth

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
    depth, sid = render_depth(Tabletop(scene_seed), (0.0, 0.0, 0.0), mount, cam, np.random.default_rng(noise_seed))
    R = mount.matrix()[:3, :3]
    return depth, sid, cam, R.T @ np.array([0.0, 0.0, 1.0])


