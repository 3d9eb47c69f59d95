"""The planes run's gravity stage: each frame's plane classes from where its gravity comes from (the mount, an
IMU, a gravity file, or the frames themselves: the dominant level plane family, tracked), and the depth camera's
mount as the floor planes show it beside the given one (docs/planes.md)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from kosmap.frontend.camera import OPTICAL_ROTATION, gravity_up
from kosmap.frontend.fspf import filter_planes, frame_seed
from kosmap.frontend.gravity import GravityTracker, drop_classes, reclassify
from kosmap.frontend.mountcal import MountCalibrator
from kosmap.frontend.planes import Planes
from kosmap.frontend.records import Transform
from kosmap.mapping.planes.frames import GRAVITY_WORDS, Item, Override, log_frames, note


@dataclass
class Classes:
    """Settles the classes of a run's frames in order; counts the frames per gravity source and gathers the floor
    planes of the frames whose gravity is a mount (for the mount estimate)."""

    cfg: object
    tracker: GravityTracker = field(default_factory=GravityTracker)
    calibrator: MountCalibrator = field(default_factory=MountCalibrator)
    used: dict[str, int] = field(default_factory=dict)  # frames per gravity source
    first_mount: tuple[Transform, str] | None = None  # the first frame's mount and gravity source
    floor_m: float = float("nan")  # the last frame's camera height above the floor its classes used (NaN: none)

    def __call__(self, planes: Planes, item: Item) -> Planes:
        """The frame's plane classes from its gravity source, then its dropped classes removed; a mount's frames
        also feed the mount calibration (their floor planes)."""
        if self.first_mount is None:
            self.first_mount = (item.mount, item.gravity)
        self.used[item.gravity] = self.used.get(item.gravity, 0) + 1
        fspf = self.cfg.fspf
        self.floor_m = float("nan")
        if item.gravity == "frames":
            up = self.tracker.update(planes, item.stamp_ns * 1e-9, item.depth, item.camera,
                                     step=fspf.ground_max_height)
            self.floor_m = self.tracker.height
            return reclassify(planes, up, self.tracker.height, fspf)
        if item.gravity in ("file", "imu"):
            self.floor_m = self.tracker.track_floor(planes, item.up, item.stamp_ns * 1e-9, item.depth, item.camera,
                                                    walls=False, step=fspf.ground_max_height)
            return reclassify(planes, item.up, self.tracker.height, fspf)
        self.calibrator.add(planes.normals, planes.offsets, planes.counts, gravity_up(item.mount))
        self.floor_m = float(item.mount.translation[2])
        return drop_classes(planes, fspf)

    def mount_estimate(self, warnings: list[str]) -> dict | None:
        return mount_estimate(self.calibrator, self.first_mount, warnings)


def mount_estimate(calibrator: MountCalibrator, first: tuple[Transform, str] | None,
                   warnings: list[str]) -> dict | None:
    """The mount seen from the floor planes beside the given one (a warning when they differ by > 1° or 2 cm),
    with the [depth] lines and a /tf_static command that set it."""
    if first is None:
        return None
    mount, src = first
    est = calibrator.estimate(gravity_up(mount), float(mount.translation[2]), src)
    if est is None:
        return None
    # x, y and yaw (not seen from the floor) stay the given mount's: camera_link ← base_link of its rotation
    xyz = [float(v) for v in mount.translation]
    link = mount.matrix()[:3, :3] @ OPTICAL_ROTATION.T
    rpy = [float(v) for v in np.degrees(Rotation.from_matrix(link).as_euler("xyz"))]
    if est.differs:
        note(warnings, f"the floor planes of {est.frames} frames put the depth camera at pitch {est.pitch_deg:.2f}°, "
                       f"roll {est.roll_deg:.2f}°, {est.height_m:.3f} m above the floor; the mount from "
                       f"{GRAVITY_WORDS[src]} says pitch {est.given_pitch_deg:.2f}°, roll {est.given_roll_deg:.2f}°, "
                       f"{est.given_height_m:.3f} m (more than 1° or 2 cm apart): see mount.toml")
    return est.as_dict() | {"given_xyz": xyz, "given_yaw_deg": rpy[2], "config": est.config_lines(xyz, rpy),
                            "tf_static": est.tf_static_command(xyz, rpy[2])}


def estimate_mount(path: Path, cfg, frames: int = 30) -> tuple[dict | None, int]:
    """The depth camera's mount from the floor planes of ≤ `frames` frames spread over the log (nothing written):
    (the estimate as in summary.json's mount_estimate, or None without a floor; the frames read)."""
    given = replace(cfg.depth, mount="given")
    probe = replace(cfg, depth=given)
    src = log_frames(path, probe, Override(), 1, None)
    every = max(1, src.total // frames)
    src.frames.close()
    src = log_frames(path, probe, Override(), every, frames)
    keep_all = replace(cfg.fspf, drop_classes=[])
    calibrator, first, n = MountCalibrator(), None, 0
    try:
        for item in src.frames:
            planes = filter_planes(item.depth, item.camera, keep_all, given, item.mount,
                                   seed=frame_seed(cfg.fspf, item.index))
            calibrator.add(planes.normals, planes.offsets, planes.counts, gravity_up(item.mount))
            first = first or (item.mount, "tf_static" if item.gravity == "tf_static" else "config")
            n += 1
    finally:
        src.frames.close()
    return mount_estimate(calibrator, first, src.warnings), n
