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

from kosmap.frontend.camera import backproject
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
    - the camera height is the one, within reach of the last, that puts the frame's planes best on the floor (0)
      and on the level surfaces measured before (`levels`: heights above the floor measured against the floor in
      a frame that sees both, so no error accumulates, each with its σ, used once two frames measured it): least
      truncated squares (each plane's points × (its distance to the nearest level / its gate)², at most its
      points), then the nearest to the last. A plane it puts on the floor becomes the floor (the height, and the
      frame's other planes measure the levels);
    - a plane farther below the floor than `step` (and its gate once the frame is placed, the reach when it is
      not), when the frame's points surely reach below the floor (`deepest`: a misfit plane has no points below
      the floor) but not below the plane, is a level at a negative height, measured against the placed floor.
      Seen at that height in a second frame, at any rate (a height below the floor does not change as the camera
      moves), it is the floor, every level is re-based on it, and its first sighting counts as one frame that
      confirms it (the old floor stood on it, nothing lay below it);
    - the floor is `confirmed` (its planes may be called ground) once two frames saw it (a plane within `step` of
      it) with something standing on it (a level surface at least `step` above it, or a wall from it to above the
      camera) and no point of the frame surely more than `step` below it. A floor is the lowest surface, and
      things stand on it: a desk filling the view, or a chair seat with the floor beside it, is not confirmed.
      Points surely below the tracked floor withdraw the confirmation until a lower floor is found and confirmed.
    Frames without a time stamp (NaN) have no motion model: each one's farthest level plane is its floor, confirmed
    by that frame alone."""

    height: float = float("nan")  # the camera's height above the floor
    levels: np.ndarray = field(default_factory=lambda: np.zeros(0))  # known level surfaces' heights above the floor
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))  # points that measured each
    sightings: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # frames that measured each
    spread: np.ndarray = field(default_factory=lambda: np.zeros(0))  # each level's σ: its and the floor's noise
    step: float = 0.15  # a level surface lower than this is the floor ([fspf] ground_max_height)
    k_sigma: float = 3.0
    stamp: float = float("nan")  # s, the last frame with level planes
    support: int = 0  # frames that confirmed the tracked floor (class doc)
    walls: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # the frame's walls: bottom, top below camera

    @property
    def confirmed(self) -> bool:
        return self.support >= 2

    def known(self) -> float:
        """The camera's height above the floor once the floor is confirmed, else NaN."""
        return self.height if self.confirmed else float("nan")

    def update(self, offsets: np.ndarray, depths: np.ndarray, counts: np.ndarray, stamp: float,
               deepest: float = float("nan"), walls: np.ndarray | None = None) -> float:
        """The camera's height above the floor after a frame's level, up-facing planes (distance below the camera,
        mean depth, points) and the distance below the camera of its lowest points (NaN: unknown); the last one
        when the frame has none, NaN before any."""
        self.walls = np.zeros((0, 2)) if walls is None else np.asarray(walls, float).reshape(-1, 2)
        d, w = np.asarray(offsets, float), np.asarray(counts, float)
        if not len(d):
            self.refute(deepest)
            return self.height
        sigma = depth_sigma(depths)
        gate = self.k_sigma * np.sqrt(2.0) * sigma
        timed = np.isfinite(stamp) and np.isfinite(self.stamp) and stamp > self.stamp
        reach = HAND_SPEED * ((stamp - self.stamp) if timed else FRAME_PERIOD) + gate
        self.stamp = stamp
        if not np.isfinite(stamp):  # frames without times (no motion model): each one's farthest plane, alone
            self.support = 0
            self.levels = self.levels[:0]
            self.weights, self.sightings, self.spread = self.weights[:0], self.sightings[:0], self.spread[:0]
        if not np.isfinite(self.height) or not np.isfinite(stamp):
            self.floor_at(int(np.argmax(d)), d, w, sigma)
            self.confirm(d, deepest, 2 if not np.isfinite(stamp) else 1)
            return self.height
        placed = (np.abs(d - self.height) <= reach).any() or bool(len(self.levels))
        if placed:
            self.height = self.relocate(d, w, sigma, reach)
        on = np.abs(d - self.height) < gate  # the planes it puts on the floor
        below = d - self.height > np.maximum(self.step, np.where(on.any() or placed, gate, reach))
        below &= not deepest <= self.height + self.step  # the frame's points surely reach below the floor …
        below &= ~(deepest > d + self.step)  # … and not below the plane (a chair seat with the floor beside it)
        if not (below.any() and self.lower(d, w, sigma, below)):
            if on.any():
                self.floor_at(int(np.argmin(np.where(on, np.abs(d - self.height), np.inf))), d, w, sigma)
            elif not placed and not below.any():  # nothing places the camera: the farthest plane is the floor
                self.floor_at(int(np.argmax(d)), d, w, sigma)
        if (np.abs(d - self.height) <= self.step).any():  # the floor in view (within the ground band)
            self.confirm(d, deepest, 1)
        self.refute(deepest)
        return self.height

    def lower(self, d: np.ndarray, w: np.ndarray, sigma: np.ndarray, below: np.ndarray) -> bool:
        """Record the planes below the floor as levels at negative heights; the farthest of them seen at its height
        before is the floor (True): the levels are re-based on it and the confirmation starts again."""
        before = self.sightings.copy()
        h = self.height - d[below]
        self.learn(h, w[below], np.hypot(sigma[below], sigma[below]), low=True)
        twice = (self.levels < 0) & (self.sightings >= 2) & (self.sightings > np.append(before, np.zeros(
            len(self.levels) - len(before), int)))
        if not twice.any():
            return False
        k = int(np.argmin(np.where(twice, self.levels, np.inf)))  # the lowest level seen twice
        j = int(np.argmin(np.where(below, np.abs(self.height - d - self.levels[k]), np.inf)))
        self.levels = self.levels - self.levels[k]  # heights above the new floor
        keep = np.abs(self.levels) >= self.step
        self.levels, self.weights = self.levels[keep], self.weights[keep]
        self.sightings, self.spread = self.sightings[keep], self.spread[keep]
        self.floor_at(j, d, w, sigma)
        self.support = 1  # its first sighting: the old floor stood on it, none below
        return True

    def confirm(self, d: np.ndarray, deepest: float, frames: int) -> None:
        """The frame saw the tracked floor: it confirms it when something stands on it (a level surface at least
        `step` above it, or a wall from it to above the camera) and no point lies more than `step` below it. (Any
        wall standing on it would confirm a desk too: monitors stand on desks; on TUM fr1_xyz that took the desk for
        the floor in up to 8 % of the ground planes.)"""
        bottom, top = self.walls[:, 0], self.walls[:, 1]
        wall = (np.abs(bottom - self.height) <= self.step) & (top <= 0.0)
        if ((self.height - d >= self.step).any() or wall.any()) and not deepest > self.height + self.step:
            self.support += frames

    def refute(self, deepest: float) -> None:
        """Points more than `step` below the tracked floor: it is no floor (not confirmed until a lower one is)."""
        if deepest > self.height + self.step:
            self.support = 0

    def relocate(self, d: np.ndarray, w: np.ndarray, sigma: np.ndarray, reach: np.ndarray) -> float:
        """The camera height that puts the frame's planes best on the floor and the known levels, within reach of
        the last (class doc); the last when none is."""
        sure = (self.sightings >= 2) & (self.levels > 0)  # measured in two floor frames: not one plane's misfit
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

    def learn(self, heights: np.ndarray, counts: np.ndarray, sigmas: np.ndarray, low: bool = False) -> None:
        """Measure the level surfaces from one frame's planes' heights above the floor and their σ: those at least
        `step` above it (a floor frame), or (low) those below it."""
        seen = np.zeros(len(self.levels), bool)
        for h, n, sg in zip(heights, counts, sigmas):
            if (h < self.step) if not low else (h > -self.step):
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
    estimate the next one's prior; the height from the floor, tracked (FloorTracker). `height` is NaN until the
    floor is confirmed: a level plane is then no ground (reclassify)."""

    up: np.ndarray = field(default_factory=lambda: LEVEL_UP.copy())
    height: float = float("nan")
    max_tilt_deg: float = 50.0
    frames: int = 0  # frames whose planes gave an estimate
    floor: FloorTracker = field(default_factory=FloorTracker)

    def update(self, planes: Planes, stamp: float = float("nan"), depth: np.ndarray | None = None,
               camera=None, step: float | None = None) -> np.ndarray:
        """Up after a frame's planes (and its depth image and camera, when given, for the floor's confirmation:
        no point may lie below the floor); the floor tracked under it (track_floor; `step` as there)."""
        up, _ = dominant_up(planes.normals, planes.counts, self.up, self.max_tilt_deg)
        if up is not None:
            self.up = up
            self.frames += 1
            self.track_floor(planes, up, stamp, depth, camera, step=step)
        return self.up

    def track_floor(self, planes: Planes, up: np.ndarray, stamp: float = float("nan"),
                    depth: np.ndarray | None = None, camera=None, walls: bool = True,
                    step: float | None = None) -> float:
        """The floor tracked (FloorTracker) with a frame's level planes under `up`, whatever gave up (the frames,
        an IMU, a gravity file): its lowest points when the depth image and camera are given, its walls rising
        from the floor when `walls`; `step`, the ground band ([fspf] ground_max_height; None keeps the last).
        Returns the camera's height above the floor, NaN until the floor is confirmed (also kept in `height`)."""
        if step is not None:
            self.floor.step = step
        deep = deepest(depth, camera, up) if depth is not None else float("nan")
        self.floor.update(*level_planes(planes, up), stamp, deep, wall_spans(planes, up) if walls else None)
        self.height = self.floor.known()
        return self.height


def deepest(depth: np.ndarray, camera, up: np.ndarray, share: float = 0.005, stride: int = 4,
            k_sigma: float = 3.0) -> float:
    """How far below the camera (along up) the frame's lowest points surely lie: each point's distance below it
    less k_sigma times its depth noise σ(z), exceeded by `share` of the points (every stride-th pixel of each
    stride-th row; NaN without depth). Robust to a few stray pixels and to the far range's noise (a Kinect's
    floor at 4 m strays by decimetres)."""
    sub = np.asarray(depth)[::stride, ::stride]
    r, c = np.nonzero(np.isfinite(sub) & (sub > 0))
    if not len(r):
        return float("nan")
    pts = backproject(depth, camera, r * stride, c * stride).astype(np.float64)
    return float(np.quantile(-(pts @ up) - k_sigma * depth_sigma(pts[:, 2]), 1.0 - share))


def wall_spans(planes: Planes, up: np.ndarray, wall_deg: float = 80.0) -> np.ndarray:
    """The walls' (planes tilted more than wall_deg from level) bottoms and tops as distances below the camera
    (W×2): the mean ± √3 standard deviations of their points' heights (the ends of a uniform spread, as a wall seen
    face on has)."""
    wall = np.abs(planes.normals @ up) < np.cos(np.radians(wall_deg))
    if not wall.any():
        return np.zeros((0, 2))
    below = -(planes.points.astype(np.float64) @ up)
    n = np.maximum(planes.counts, 1)
    mean = np.bincount(planes.plane, below, len(planes)) / n
    sd = np.sqrt(np.maximum(np.bincount(planes.plane, below * below, len(planes)) / n - mean ** 2, 0.0))
    return np.stack([mean + np.sqrt(3.0) * sd, mean - np.sqrt(3.0) * sd], axis=1)[wall]


def level_planes(planes: Planes, up: np.ndarray, family_deg: float = 5.0,
                 min_points: int = 500) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The up-facing level planes (within family_deg of up, min_points or more): their distances below the camera,
    their points' mean depths and their points."""
    level = (planes.normals @ up > np.cos(np.radians(family_deg))) & (planes.counts >= min_points)
    depth = np.bincount(planes.plane, planes.points[:, 2], len(planes)) / np.maximum(planes.counts, 1)
    return planes.offsets[level], depth[level], planes.counts[level]


def reclassify(planes: Planes, up: np.ndarray, height: float, cfg) -> Planes:
    """The planes' classes from `up` and the camera's height above the floor, those of cfg.drop_classes dropped.
    Without a height (NaN: the floor not yet confirmed) no plane is ground: an up-facing level plane is 'raised'
    (it may be a desk filling the view), and kept."""
    if not len(planes):
        return planes
    up, fwd, left = axes_from_up(up)
    planes.classes = classify(planes.normals, up, fwd, left, cfg.slanted_min_deg, cfg.slanted_max_deg, planes.offsets,
                              height, cfg.ground_max_height)
    if np.isfinite(height):
        planes.classes[on_floor(planes, up, height, cfg.ground_max_height)] = PLANE_CLASSES.index("ground")
    else:
        planes.classes[planes.classes == PLANE_CLASSES.index("ground")] = PLANE_CLASSES.index("raised")
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
