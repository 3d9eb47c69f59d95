"""Gravity in the depth camera's frame when no mount says it: from a gravity file, or from the frames themselves.

Plane classes (thesis Alg. 6: ground, ceiling, walls by side, slanted, raised) are angles to gravity. A robot's
camera has a mount (/tf_static or [depth] mount_*) that gives it; a handheld camera pitched 16–36° down has none,
and a level default then calls every floor "slanted". Without a mount, the up direction is the normal of the
dominant horizontal plane family: the planes parallel to one another (floor, table tops, ceiling, flipped to one
side) with the most points, among normals within `max_tilt_deg` of the previous frame's up (the tracked prior;
a level camera at the start). Walls are perpendicular to it and never win: they lie ~90° from the prior. The
camera's height above the floor is the offset of the farthest up-facing plane of that family.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from kosmap.frontend.errors import LogError
from kosmap.frontend.planes import PLANE_CLASSES, Planes, classify
from kosmap.frontend.records import Transform

LEVEL_UP = np.array([0.0, -1.0, 0.0])  # a level camera: up is the optical frame's −y
GRAVITY_FILES = ("gravity-direction.txt", "gravity.txt")


def axes_from_up(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(up, forward, left) in the optical frame from up: forward is the optical axis made horizontal."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    f = z - up * (z @ up)
    if np.linalg.norm(f) < 1e-6:  # looking straight down or up: the image's top is forward
        y = np.array([0.0, -1.0, 0.0])
        f = y - up * (y @ up)
    f /= np.linalg.norm(f)
    return up, f, np.cross(up, f)


def dominant_up(normals: np.ndarray, counts: np.ndarray, prior: np.ndarray, max_tilt_deg: float = 50.0,
                family_deg: float = 5.0, min_points: int = 2000) -> tuple[np.ndarray | None, int]:
    """The up direction from one frame's planes: (the point-weighted mean normal of the largest family of
    parallel planes whose normal lies within max_tilt_deg of ±prior, its points), or (None, 0) when no family
    within the gate holds min_points."""
    n = np.asarray(normals, float).reshape(-1, 3)
    w = np.asarray(counts, float)
    if not len(n):
        return None, 0
    c = n * np.where(n @ prior < 0, -1.0, 1.0)[:, None]  # each normal on the prior's side
    cand = np.flatnonzero(c @ prior > np.cos(np.radians(max_tilt_deg)))
    if not len(cand):
        return None, 0
    cos_f = np.cos(np.radians(family_deg))
    members = np.abs(c[cand] @ c.T) > cos_f  # candidates × planes: parallel within family_deg
    support = members @ w
    best = int(np.argmax(support))
    if support[best] < min_points:
        return None, 0
    fam = members[best]
    up = (c[fam] * w[fam, None]).sum(axis=0)
    return up / np.linalg.norm(up), int(support[best])


def floor_height(normals: np.ndarray, offsets: np.ndarray, counts: np.ndarray, up: np.ndarray,
                 family_deg: float = 5.0, min_points: int = 500) -> float:
    """The camera's height above the floor: the offset of the farthest up-facing level plane (NaN without one)."""
    n = np.asarray(normals, float).reshape(-1, 3)
    level = (n @ up > np.cos(np.radians(family_deg))) & (np.asarray(counts) >= min_points)
    return float(np.max(np.asarray(offsets)[level])) if level.any() else float("nan")


@dataclass
class GravityTracker:
    """Up (and the camera height) over a sequence, each frame's estimate the next one's prior."""

    up: np.ndarray = field(default_factory=lambda: LEVEL_UP.copy())
    height: float = float("nan")
    max_tilt_deg: float = 50.0
    frames: int = 0  # frames whose planes gave an estimate

    def update(self, planes: Planes) -> np.ndarray:
        up, _ = dominant_up(planes.normals, planes.counts, self.up, self.max_tilt_deg)
        if up is not None:
            self.up = up
            self.frames += 1
            h = floor_height(planes.normals, planes.offsets, planes.counts, up)
            if np.isfinite(h):
                self.height = h
        return self.up


def reclassify(planes: Planes, up: np.ndarray, height: float, cfg) -> Planes:
    """The planes' classes from `up` (and the camera height for 'raised'), those of cfg.drop_classes dropped."""
    if not len(planes):
        return planes
    up, fwd, left = axes_from_up(up)
    planes.classes = classify(planes.normals, up, fwd, left, cfg.slanted_min_deg, cfg.slanted_max_deg, planes.offsets,
                              height, cfg.ground_max_height)
    return drop_classes(planes, cfg)


def drop_classes(planes: Planes, cfg) -> Planes:
    """The planes without those of cfg.drop_classes (their points counted as dropped)."""
    drop = np.isin(planes.classes, [PLANE_CLASSES.index(c) for c in cfg.drop_classes])
    if not drop.any():
        return planes
    lost = int(planes.counts[drop].sum())
    out = planes.select(~drop)
    out.stats.inliers -= lost
    out.stats.dropped += lost
    out.stats.planes = len(out)
    return out


def imu_up(accelerations: np.ndarray, orientation: np.ndarray | None, cam_from_imu: np.ndarray) -> np.ndarray:
    """Up in the camera's optical frame from an IMU on the same rigid body: its orientation (x, y, z, w; world z up,
    REP 145) when it gives one, else its mean specific force (at rest +g, pointing up), turned into the camera
    frame by cam_from_imu (3×3, from /tf_static)."""
    if orientation is not None:
        x, y, z, w = np.asarray(orientation, float) / np.linalg.norm(orientation)
        up = np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])  # R(q)ᵀ·e_z
    else:
        up = np.asarray(accelerations, float).reshape(-1, 3).mean(axis=0)
    up = np.asarray(cam_from_imu, float) @ up
    return up / np.linalg.norm(up)


def read_gravity_file(folder: Path) -> tuple[np.ndarray, Path] | None:
    """Up in the optical frame from a folder's gravity file (one line 'gx gy gz': gravity, pointing down, in the
    camera's optical frame), or None when the folder (or its parent) has none."""
    for d in (folder, folder.parent):
        for name in GRAVITY_FILES:
            p = d / name
            if p.is_file():
                try:
                    g = np.array([float(v) for v in p.read_text().split()[:3]])
                except ValueError as e:
                    raise LogError(f"gravity file {p}: {e}; it must hold three numbers 'gx gy gz'") from e
                if len(g) != 3 or not np.all(np.isfinite(g)) or np.linalg.norm(g) == 0:
                    raise LogError(f"gravity file {p} must hold three numbers 'gx gy gz', not all zero")
                return -g / np.linalg.norm(g), p
    return None


def gravity_mount(mount: Transform, up: np.ndarray, height: float = float("nan")) -> Transform:
    """The mount (base_link ← optical) turned by the smallest rotation that makes `up` (in the optical frame) the
    base's +z: the pitch and roll gravity says, the yaw (heading) and x, y kept; z the camera's height above the
    floor when it is known (finite), else the mount's own."""
    m = mount.matrix()
    u = m[:3, :3] @ (np.asarray(up, float) / np.linalg.norm(up))  # up as the given mount puts it in base_link
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, z)
    s, c = np.linalg.norm(axis), float(u @ z)
    turn = Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix() if s > 1e-12 else np.eye(3)
    out = np.eye(4)
    out[:3, :3] = turn @ m[:3, :3]
    out[:3, 3] = m[:3, 3]
    if np.isfinite(height):
        out[2, 3] = height
    return Transform.from_matrix(mount.parent, mount.child, out, mount.stamp_ns)
