"""Gravity in the depth camera's frame when no mount says it: from a gravity file, or from the frames themselves.

Plane classes (thesis Alg. 6: ground, ceiling, walls by side, slanted, raised) are angles to gravity. A robot's
camera has a mount (/tf_static or [depth] mount_*) that gives it; a handheld camera pitched 16–36° down has none,
and a level default then calls every floor "slanted". Without a mount, the up direction is the normal of the
dominant horizontal plane family: the planes parallel to one another (floor, table tops, ceiling, flipped to one
side) with the most points, among normals within `max_tilt_deg` of the previous frame's up (the tracked prior;
a level camera at the start). Walls are perpendicular to it and never win: they lie ~90° from the prior. The
camera's height above the floor is tracked over the sequence (FloorTracker), so a desk filling the view is raised,
not ground; a level plane at the floor's height is ground even when its fit tilts a little more than
slanted_min_deg (on_floor).
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


def depth_sigma(z: np.ndarray) -> np.ndarray:
    """Axial depth noise σ (m) of a Kinect at depth z (m): 1.2 mm + 1.9 mm·(z − 0.4 m)² per m² (Nguyen, Izadi and
    Lovell, "Modeling Kinect sensor noise for improved 3D reconstruction and tracking", 3DIMPVT 2012)."""
    return 0.0012 + 0.0019 * (np.asarray(z, float) - 0.4) ** 2


HAND_SPEED = 1.0  # m/s: the fastest a hand moves a camera up or down (the motion model's bound between frames)
FRAME_PERIOD = 1.0 / 30.0  # s between frames when they carry no time stamps (a depth camera's 30 Hz)


@dataclass
class FloorTracker:
    """The camera's height above the floor over a handheld sequence, through the frames that do not see the floor.

    Motion model: between frames the hand moves the camera by at most HAND_SPEED × their interval; a surface seen
    twice agrees within its gate k_sigma·√2·σ(z) (σ: the depth noise at its points' mean depth); `reach` is the
    two together. Each frame's level, up-facing planes (distance d below the camera, points):
    - a plane farther down than the tracked floor's reach is a lower floor only when the next frame sees it again
      (a single far plane may be a misfit: Kinect v1 offsets at 3 m stray by decimetres): the farthest seen in
      both frames (until then it is one more plane the others place);
    - else the camera height is the one, within reach of the last, that puts the frame's planes best on the floor
      (0) and on the level surfaces measured before (`levels`: heights above the floor measured against the floor
      in the same frame, so no error accumulates, each with its σ, used once two floor frames measured it): least
      truncated squares (each plane's points × (its distance to the nearest level / its gate)², at most its
      points), then the nearest to the last. A plane it puts on the floor becomes the floor (the height, and the
      frame's other planes measure the levels); with no plane near the floor and no level known yet, the farthest
      plane is taken for it.
    So a frame that sees only the desk still puts the floor a desk's height further down (docs/planes.md). Frames
    without a time stamp (NaN) have no motion model: each one's farthest level plane is its floor."""

    height: float = float("nan")  # the camera's height above the floor
    levels: np.ndarray = field(default_factory=lambda: np.zeros(0))  # known level surfaces' heights above the floor
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))  # points that measured each
    sightings: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # floor frames that measured each
    spread: np.ndarray = field(default_factory=lambda: np.zeros(0))  # each level's σ: its and the floor's noise
    step: float = 0.15  # a level surface lower than this is the floor ([fspf] ground_max_height)
    k_sigma: float = 3.0
    stamp: float = float("nan")  # s, the last frame with level planes
    lower: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the last frame's planes below the floor

    def update(self, offsets: np.ndarray, depths: np.ndarray, counts: np.ndarray, stamp: float) -> float:
        """The camera's height above the floor after a frame's level, up-facing planes (distance below the camera,
        mean depth, points); the last one when the frame has none, NaN before any."""
        d, w = np.asarray(offsets, float), np.asarray(counts, float)
        if not len(d):
            return self.height
        sigma = depth_sigma(depths)
        reach = HAND_SPEED * ((stamp - self.stamp) if np.isfinite(stamp) and np.isfinite(self.stamp)
                              and stamp > self.stamp else FRAME_PERIOD) + self.k_sigma * np.sqrt(2.0) * sigma
        self.stamp = stamp
        if not np.isfinite(self.height) or not np.isfinite(stamp):  # the first frame, or frames without times (no
            return self.floor_at(int(np.argmax(d)), d, w, sigma)     # motion model): the farthest plane is the floor
        lower, self.lower = self.lower, d[d > self.height + reach]
        below = d > self.height + reach
        again = below & (np.abs(d[:, None] - lower[None, :]) <= reach[:, None]).any(axis=1)
        if again.any():  # a lower surface seen in two frames running: the farthest such is the floor
            return self.floor_at(int(np.argmax(np.where(again, d, -np.inf))), d, w, sigma)
        if not (np.abs(d - self.height) <= reach).any() and not len(self.levels):  # nothing places the camera:
            # the height as it was beside a lower floor not yet confirmed, else the farthest plane is the floor
            return self.height if below.any() else self.floor_at(int(np.argmax(d)), d, w, sigma)
        self.height = self.relocate(d, w, sigma, reach)
        floor = np.abs(d - self.height) < self.k_sigma * np.sqrt(2.0) * sigma  # the planes it puts on the floor
        if floor.any():
            return self.floor_at(int(np.argmin(np.where(floor, np.abs(d - self.height), np.inf))), d, w, sigma)
        return self.height

    def relocate(self, d: np.ndarray, w: np.ndarray, sigma: np.ndarray, reach: np.ndarray) -> float:
        """The camera height that puts the frame's planes best on the floor and the known levels, within reach of
        the last (class doc); the last when none is."""
        sure = self.sightings >= 2  # measured in two floor frames: not one plane's misfit
        levels = np.concatenate([[0.0], self.levels[sure]])
        spread = np.concatenate([[0.0], self.spread[sure]])  # each level's σ (the floor's noise when measured)
        cand = (d[:, None] + levels[None, :])
        cand = cand[np.abs(cand - self.height) <= reach[:, None]]
        if not len(cand):
            return self.height
        gates = self.k_sigma * np.sqrt(2.0) * np.hypot(sigma[:, None], spread[None, :])  # planes × levels
        res = np.abs((cand[:, None] - d[None, :])[:, :, None] - levels[None, None, :]) / gates[None]
        cost = np.minimum(res.min(axis=2) ** 2, 1.0) @ w
        best = np.flatnonzero(cost <= cost.min() + 1e-9 * w.sum())
        return float(cand[best[np.argmin(np.abs(cand[best] - self.height))]])

    def floor_at(self, j: int, d: np.ndarray, w: np.ndarray, sigma: np.ndarray) -> float:
        """Plane j is the floor: it sets the camera's height, and the frame's other planes measure the levels."""
        self.height = float(d[j])
        self.learn(self.height - d, w, np.hypot(sigma, sigma[j]))
        return self.height

    def learn(self, heights: np.ndarray, counts: np.ndarray, sigmas: np.ndarray) -> None:
        """Measure the level surfaces from one frame's planes' heights above the floor (a floor frame) and their σ."""
        seen = np.zeros(len(self.levels), bool)
        for h, n, sg in zip(heights, counts, sigmas):
            if h < self.step:
                continue
            k = int(np.argmin(np.abs(self.levels - h))) if len(self.levels) else -1
            if k >= 0 and abs(self.levels[k] - h) < self.k_sigma * np.sqrt(2.0) * np.hypot(sg, self.spread[k]):
                self.levels[k] = (self.weights[k] * self.levels[k] + n * h) / (self.weights[k] + n)
                self.spread[k] = (self.weights[k] * self.spread[k] + n * sg) / (self.weights[k] + n)
                self.weights[k] += n
                self.sightings[k] += 0 if seen[k] else 1
                seen[k] = True
            else:
                self.levels = np.append(self.levels, h)
                self.spread = np.append(self.spread, sg)
                self.weights = np.append(self.weights, n)
                self.sightings = np.append(self.sightings, 1)
                seen = np.append(seen, True)


@dataclass
class GravityTracker:
    """Up and the camera's height above the floor over a sequence: up from the dominant level family, each frame's
    estimate the next one's prior; the height from the floor, tracked (FloorTracker)."""

    up: np.ndarray = field(default_factory=lambda: LEVEL_UP.copy())
    height: float = float("nan")
    max_tilt_deg: float = 50.0
    frames: int = 0  # frames whose planes gave an estimate
    floor: FloorTracker = field(default_factory=FloorTracker)

    def update(self, planes: Planes, stamp: float = float("nan")) -> np.ndarray:
        up, _ = dominant_up(planes.normals, planes.counts, self.up, self.max_tilt_deg)
        if up is not None:
            self.up = up
            self.frames += 1
            self.height = self.floor.update(*level_planes(planes, up), stamp)
        return self.up


def level_planes(planes: Planes, up: np.ndarray, family_deg: float = 5.0,
                 min_points: int = 500) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The up-facing level planes (within family_deg of up, min_points or more): their distances below the camera,
    their points' mean depths and their points."""
    level = (planes.normals @ up > np.cos(np.radians(family_deg))) & (planes.counts >= min_points)
    depth = np.bincount(planes.plane, planes.points[:, 2], len(planes)) / np.maximum(planes.counts, 1)
    return planes.offsets[level], depth[level], planes.counts[level]


def reclassify(planes: Planes, up: np.ndarray, height: float, cfg) -> Planes:
    """The planes' classes from `up` (and the camera height for 'raised'), those of cfg.drop_classes dropped."""
    if not len(planes):
        return planes
    up, fwd, left = axes_from_up(up)
    planes.classes = classify(planes.normals, up, fwd, left, cfg.slanted_min_deg, cfg.slanted_max_deg, planes.offsets,
                              height, cfg.ground_max_height)
    if np.isfinite(height):
        planes.classes[on_floor(planes, up, height, cfg.ground_max_height)] = PLANE_CLASSES.index("ground")
    return drop_classes(planes, cfg)


def on_floor(planes: Planes, up: np.ndarray, height: float, step: float, family_deg: float = 5.0,
             k: float = 2.0) -> np.ndarray:
    """The planes lying on the floor (P bool): up-facing, of the level family (within family_deg of up, as
    dominant_up groups them), their points' heights above the floor within `step` (mean ± k σ). A real floor's fit
    may tilt a few degrees past slanted_min_deg (a Kinect's depth error grows with range: on TUM fr1_xyz a tenth
    of the floor planes tilt 3–8° off the floor's normal); at the floor's height it is the floor all the same."""
    pts = planes.points.astype(np.float64)
    h = height + pts @ up  # each point's height above the floor
    n = np.maximum(planes.counts, 1)
    mean = np.bincount(planes.plane, h, len(planes)) / n
    sd = np.sqrt(np.maximum(np.bincount(planes.plane, h * h, len(planes)) / n - mean ** 2, 0.0))
    level = planes.normals @ up > np.cos(np.radians(family_deg))
    return level & (np.abs(mean) + k * sd <= step)


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
