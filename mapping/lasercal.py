"""The depth camera's yaw and x, y offset in base_link from its KOS scans against the laser scan (frontend/mountcal.py
LaserAligner), for `kosmap scan` and `kosmap build`: the KOS level at the laser's height (the obstacle scan when no
level band holds it) beside the laser scan nearest in time, both in base_link, over the whole log; reported with
the rest of the mount (pitch, roll and height as the run used them), a `[depth]` snippet and a /tf_static line,
and a warning when the given mount is more than 1° or 2 cm off (the thesis saw KOS deviate from the Hokuyo by
"a small deviation of the Microsoft Kinect One frame regarding the Hokuyo's frame", Fig. 5.19–5.20)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kosmap.frontend.camera import OPTICAL_ROTATION, lookup_static
from kosmap.frontend.kos import OBSTACLE
from kosmap.frontend.mountcal import LaserAligner
from kosmap.frontend.records import Scan, Transform

MOUNT_TOML = "mount.toml"


def laser_level(bands: list[tuple[str, float, float]], laser_z: float) -> str:
    """The KOS level whose band holds the laser's height, else the obstacle scan."""
    for name, lo, hi in bands:
        if name != OBSTACLE and lo <= laser_z <= hi:
            return name
    return OBSTACLE


def scan_xy(scan: Scan, mount: Transform | None = None) -> np.ndarray:
    """A scan's valid returns as x, y in its parent frame (base_link) through `mount` (None: already there)."""
    ok = scan.valid()
    r, a = scan.ranges[ok], scan.angles[ok]
    p = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(len(r))]
    return (p if mount is None else mount.apply(p))[:, :2]


class KosLaserCal:
    """Feeds each time step's KOS level and laser scan to the aligner; one depth camera only (a merged scan of
    several cannot tell whose yaw is off)."""

    def __init__(self, bands: list[tuple[str, float, float]], cameras: int) -> None:
        self.bands, self.cameras = bands, cameras
        self.aligner = LaserAligner()
        self.level: str | None = None
        self.laser_tf: Transform | None = None

    def add(self, scans: dict[str, Scan], laser: Scan | None, statics) -> None:
        if self.cameras != 1 or laser is None:
            return
        if self.laser_tf is None:
            self.laser_tf = lookup_static(statics, "base_link", laser.frame_id) or \
                Transform.identity("base_link", laser.frame_id)
            self.level = laser_level(self.bands, float(self.laser_tf.translation[2]))
        self.aligner.add(scan_xy(scans[self.level]), scan_xy(laser, self.laser_tf))

    def result(self, mount: Transform | None, child: str = "camera_link") -> dict | None:
        """The alignment (LaserAlignment's fields, differs, the level used, the [depth] lines and /tf_static
        line of the whole mount), or None (several cameras, no laser, fewer than 5 usable steps)."""
        if mount is None or self.level is None:
            return None
        link = mount.matrix()[:3, :3] @ OPTICAL_ROTATION.T
        roll, pitch, yaw = (float(v) for v in np.degrees(Rotation.from_matrix(link).as_euler("xyz")))
        est = self.aligner.estimate(mount.translation[:2], yaw)
        if est is None:
            return None
        z = float(mount.translation[2])
        return est.as_dict() | {"level": self.level, "config": est.config_lines(z, roll, pitch),
                                "tf_static": est.tf_static_command(z, roll, pitch, child)}

    @staticmethod
    def lines(res: dict) -> list[str]:
        """What the console says."""
        xy = (f"x {res['x_m']:.3f} m, y {res['y_m']:.3f} m" if res["offset_determined"]
              else "x, y not fixed by these walls (one direction only: the given x, y kept)")
        return [f"camera to laser ({res['steps']} steps, KOS {res['level']} against the laser): yaw "
                f"{res['yaw_deg']:.2f}°, {xy} (given: yaw {res['given_yaw_deg']:.2f}°, "
                f"x {res['given_x_m']:.3f} m, y {res['given_y_m']:.3f} m; residual {100 * res['rms_m']:.1f} cm)"]

    @staticmethod
    def warning(res: dict) -> str | None:
        if not res["differs"]:
            return None
        return (f"the KOS scans line up with the laser with the depth camera at yaw {res['yaw_deg']:.2f}°, "
                f"x {res['x_m']:.3f} m, y {res['y_m']:.3f} m; the given mount says yaw {res['given_yaw_deg']:.2f}°, "
                f"x {res['given_x_m']:.3f} m, y {res['given_y_m']:.3f} m (more than 1° or 2 cm apart): see mount.toml")


def write_mount_toml(out, res: dict | None, warnings: list[str], say=None) -> dict:
    """The alignment's console line (to `say`), its warning (into `warnings`) and out/mount.toml (the whole mount as
    `[depth]` lines and a /tf_static line); returns {"mount": path} when written."""
    if res is None:
        return {}
    if say is not None:
        say("\n".join(KosLaserCal.lines(res)))
    w = KosLaserCal.warning(res)
    if w:
        warnings.append(w)
    path = out / MOUNT_TOML
    path.write_text(f"# the depth camera's mount with x, y and yaw from its KOS scans against the laser\n"
                    f"{res['config']}\n# {res['tf_static']}\n")
    return {"mount": path}
