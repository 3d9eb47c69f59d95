"""Gravity for `kosmap build` and `kosmap scan`: where the depth camera's plane classes (and so KOS's ground and
ceiling removal and its height bands) take gravity from, in the order `kosmap planes` uses (mapping/planes/frames.py:
the mount in /tf_static or set in [depth], the log's IMU on the camera's rigid body, the frames themselves).

A mount (the first source) is used as it is. Otherwise gravity is measured before the run on ≤ 30 frames spread over
the log: each frame's up in the optical frame (the IMU's specific force, or the dominant level plane family of its
FSPF+ planes, tracked: frontend/gravity.py) and the floor's distance below the camera, tracked over those frames
and taken once the floor is confirmed (frontend/gravity.FloorTracker: a desk or a box top filling a frame is not
the floor); their median turns the given
mount (its pitch and roll) until up is the base's +z, and sets its height (frontend/gravity.gravity_mount). A robot's
camera is rigid on its base, so one mount per camera holds for the whole log, and serial and parallel runs see the
same one.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from kosmap.frontend.camera import gravity_up
from kosmap.frontend.fspf import filter_planes, frame_seed
from kosmap.frontend.gravity import GravityTracker, gravity_mount
from kosmap.frontend.mountcal import pitch_roll
from kosmap.frontend.records import Transform
from kosmap.mapping.planes.frames import GRAVITY_WORDS, Override, log_frames

SAMPLE_FRAMES = 30  # frames spread over the log that measure gravity when no mount gives it


@dataclass
class CameraGravity:
    """One camera's gravity-aligned mount beside the given one (degrees, metres)."""

    frames: int  # frames that gave an up
    pitch_deg: float
    roll_deg: float
    height_m: float  # NaN: no floor seen (the given mount's height is kept)
    given_pitch_deg: float
    given_roll_deg: float
    given_height_m: float

    @property
    def differs(self) -> bool:
        """More than 1° or 2 cm from the given mount."""
        dh = abs(self.height_m - self.given_height_m) if np.isfinite(self.height_m) else 0.0
        return max(abs(self.pitch_deg - self.given_pitch_deg), abs(self.roll_deg - self.given_roll_deg)) > 1.0 or dh > 0.02


@dataclass
class GravityMount:
    """Where a run's gravity comes from and, when it is not a mount, each camera's gravity-aligned mount."""

    source: str  # tf_static, config, imu, frames; "" without a depth frame
    mounts: dict[str, Transform] = field(default_factory=dict)  # optical frame id → mount to use instead
    cameras: dict[str, CameraGravity] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"source": self.source, "from": GRAVITY_WORDS.get(self.source, "no depth frame"),
                "cameras": {k: vars(c) | {"differs": c.differs} for k, c in self.cameras.items()}}

    def lines(self) -> list[str]:
        """What the console says: the source, and per camera the mount it gives beside the given one."""
        out = [f"gravity: {GRAVITY_WORDS.get(self.source, 'no depth frame')}"]
        for k, c in self.cameras.items():
            h = f"{c.height_m:.3f} m" if np.isfinite(c.height_m) else f"{c.given_height_m:.3f} m (given; no floor seen)"
            out.append(f"  {k}: pitch {c.pitch_deg:.2f}°, roll {c.roll_deg:.2f}°, height {h} from {c.frames} frames "
                       f"(given: pitch {c.given_pitch_deg:.2f}°, roll {c.given_roll_deg:.2f}°, {c.given_height_m:.3f} m)")
        return out

    def warnings(self) -> list[str]:
        return [f"gravity from {GRAVITY_WORDS[self.source]} puts depth camera {k} at pitch {c.pitch_deg:.2f}°, roll "
                f"{c.roll_deg:.2f}° (given: {c.given_pitch_deg:.2f}°, {c.given_roll_deg:.2f}°; more than 1° or 2 cm "
                f"apart): its planes and KOS scans use the gravity-aligned mount"
                for k, c in self.cameras.items() if c.differs]


def resolve_gravity(path: Path, cfg, frames: int = SAMPLE_FRAMES) -> GravityMount:
    """The run's gravity (module doc): the first depth frame says the source; an IMU or the frames are measured on
    ≤ `frames` frames spread over the log."""
    src = log_frames(Path(path), cfg, Override(), 1, None)
    try:
        first = next(src.frames, None)
    finally:
        src.frames.close()
    if first is None:
        return GravityMount("")
    if first.gravity not in ("imu", "frames"):
        return GravityMount(first.gravity)
    src = log_frames(Path(path), cfg, Override(), max(1, src.total // frames), frames)
    keep_all = replace(cfg.fspf, drop_classes=[])
    seen: dict[str, tuple[Transform, GravityTracker, list, list]] = {}
    try:
        for item in src.frames:
            if item.frame_id not in seen:
                seen[item.frame_id] = (item.mount, GravityTracker(up=gravity_up(item.mount)), [], [])
            _, tracker, ups, heights = seen[item.frame_id]
            planes = filter_planes(item.depth, item.camera, keep_all, cfg.depth, item.mount,
                                   seed=frame_seed(cfg.fspf, item.index))
            stamp = item.stamp_ns * 1e-9
            step = cfg.fspf.ground_max_height  # the ground band, as mapping/planes/classes.py tracks the floor
            if item.gravity == "imu" and item.up is not None:
                up = np.asarray(item.up, float)
                tracker.track_floor(planes, up, stamp, item.depth, item.camera, walls=False, step=step)
            else:
                n = tracker.frames
                up = tracker.update(planes, stamp, item.depth, item.camera, step=step)
                if tracker.frames == n:  # no level plane family in this frame
                    continue
            ups.append(up)
            heights.append(tracker.floor.known())  # the floor tracked and confirmed (frontend/gravity.FloorTracker)
    finally:
        src.frames.close()
    out = GravityMount(first.gravity)
    for fid, (mount, _, ups, heights) in seen.items():
        if not ups:
            continue
        up = np.median(np.asarray(ups), axis=0)
        up /= np.linalg.norm(up)
        h = np.asarray(heights, float)
        height = float(np.median(h[np.isfinite(h)])) if np.isfinite(h).any() else float("nan")
        out.mounts[fid] = gravity_mount(mount, up, height)
        p, r = pitch_roll(up)
        gp, gr = pitch_roll(gravity_up(mount))
        out.cameras[fid] = CameraGravity(len(ups), p, r, height, gp, gr, float(mount.translation[2]))
    return out
