"""Mount self-calibration: the depth camera's pitch, roll and height above the floor from the floor planes of a log.

Each frame whose planes hold a dominant level family (frontend/gravity.py) gives up in the optical frame and the
floor's offset. With the camera_link mount of frontend/camera.mount_transform (fixed-axis roll, pitch, yaw;
pitch > 0 looks down), up in the optical frame is (−sin r·cos p, −cos r·cos p, −sin p), so p = asin(−up_z),
r = atan2(−up_x, −up_y); yaw and the horizontal offset are not observable from the floor. The log's estimate is
the median over the frames (robust to frames where a table top outvoted the floor).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from kosmap.frontend.gravity import dominant_up, floor_height


def pitch_roll(up: np.ndarray) -> tuple[float, float]:
    """(pitch, roll) in degrees of the camera_link whose optical frame sees `up`."""
    u = np.asarray(up, float) / np.linalg.norm(up)
    return float(np.degrees(np.arcsin(np.clip(-u[2], -1.0, 1.0)))), float(np.degrees(np.arctan2(-u[0], -u[1])))


@dataclass
class MountEstimate:
    """The mount seen from the floor, the one given, and their differences (deg, m)."""

    frames: int
    pitch_deg: float
    roll_deg: float
    height_m: float
    given_pitch_deg: float
    given_roll_deg: float
    given_height_m: float
    source: str  # where the given mount came from (tf_static, config)

    @property
    def differs(self) -> bool:
        """More than 1° or 2 cm from the given mount."""
        return (max(abs(self.pitch_deg - self.given_pitch_deg), abs(self.roll_deg - self.given_roll_deg)) > 1.0
                or abs(self.height_m - self.given_height_m) > 0.02)

    def as_dict(self) -> dict:
        return asdict(self) | {"differs": self.differs}

    def config_lines(self, xyz, rpy_deg) -> str:
        """The [depth] lines that set this mount (x, y and yaw kept from the given mount)."""
        return (f"[depth]\nmount_xyz = [{xyz[0]:.3f}, {xyz[1]:.3f}, {self.height_m:.3f}]\n"
                f"mount_rpy_deg = [{self.roll_deg:.2f}, {self.pitch_deg:.2f}, {rpy_deg[2]:.2f}]\n")

    def tf_static_command(self, xyz, yaw_deg: float, child: str = "camera_link") -> str:
        """A ROS 2 static_transform_publisher line publishing this mount on /tf_static."""
        return (f"ros2 run tf2_ros static_transform_publisher --x {xyz[0]:.3f} --y {xyz[1]:.3f} --z {self.height_m:.3f} "
                f"--roll {np.radians(self.roll_deg):.5f} --pitch {np.radians(self.pitch_deg):.5f} "
                f"--yaw {np.radians(yaw_deg):.5f} --frame-id base_link --child-frame-id {child}")


class MountCalibrator:
    """Collects each frame's floor (up, height) and gives the log's mount estimate."""

    def __init__(self, min_frames: int = 3) -> None:
        self.ups: list[np.ndarray] = []
        self.heights: list[float] = []
        self.min_frames = min_frames

    def add(self, normals: np.ndarray, offsets: np.ndarray, counts: np.ndarray, prior_up: np.ndarray) -> None:
        up, _ = dominant_up(normals, counts, prior_up, max_tilt_deg=20.0)
        if up is None:
            return
        h = floor_height(normals, offsets, counts, up)
        if np.isfinite(h):
            self.ups.append(up)
            self.heights.append(h)

    def estimate(self, given_up: np.ndarray, given_height: float, source: str) -> MountEstimate | None:
        if len(self.ups) < self.min_frames:
            return None
        pr = np.array([pitch_roll(u) for u in self.ups])
        gp, gr = pitch_roll(given_up)
        return MountEstimate(len(self.ups), float(np.median(pr[:, 0])), float(np.median(pr[:, 1])),
                             float(np.median(self.heights)), gp, gr, float(given_height), source)
