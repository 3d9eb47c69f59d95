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
        return bool(max(abs(self.pitch_deg - self.given_pitch_deg), abs(self.roll_deg - self.given_roll_deg)) > 1.0
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


# ---- the camera's yaw and horizontal offset, from KOS against the laser ---------------------------------------------


@dataclass
class LaserAlignment:
    """The depth camera's heading and x, y in base_link as its KOS scans line up with the laser's, beside the given
    mount (deg, m): the rigid motion (dx, dy, dyaw) that takes the KOS points onto the laser's, shared by all steps."""

    steps: int
    pairs: int  # point-to-line correspondences kept in the last iteration
    rms_m: float
    dx_m: float
    dy_m: float
    dyaw_deg: float
    x_m: float
    y_m: float
    yaw_deg: float
    given_x_m: float
    given_y_m: float
    given_yaw_deg: float
    sd_x_m: float  # standard errors (least squares at the residual's RMS)
    sd_y_m: float
    sd_yaw_deg: float
    normal_spread: float  # of the walls matched (LaserAligner.solve): walls one way leave the offset along them free

    @property
    def yaw_determined(self) -> bool:
        return bool(self.sd_yaw_deg < 0.1)

    @property
    def offset_determined(self) -> bool:
        """Walls seen both ways (≥ 10 % of the matches across the main direction) and standard errors under 2.5 mm
        (a quarter of the 1 cm asked): a corridor seen along its length fixes the yaw but not the offset along it."""
        return bool(self.normal_spread >= 0.1 and max(self.sd_x_m, self.sd_y_m) < 0.0025)

    @property
    def differs(self) -> bool:
        """More than 1° (yaw) or 2 cm (x, y) from the given mount, where determined."""
        return bool((self.yaw_determined and abs(self.dyaw_deg) > 1.0)
                    or (self.offset_determined and np.hypot(self.x_m - self.given_x_m, self.y_m - self.given_y_m) > 0.02))

    def as_dict(self) -> dict:
        return asdict(self) | {"yaw_determined": self.yaw_determined, "offset_determined": self.offset_determined,
                               "differs": self.differs}

    def mount_xy_yaw(self) -> tuple[float, float, float]:
        """x, y and yaw for the mount: the estimates where determined, else the given values."""
        x, y = (self.x_m, self.y_m) if self.offset_determined else (self.given_x_m, self.given_y_m)
        return x, y, self.yaw_deg if self.yaw_determined else self.given_yaw_deg

    def config_lines(self, z: float, roll_deg: float, pitch_deg: float) -> str:
        """The [depth] lines of the whole mount: x, y and yaw from the laser (where determined), z, roll and pitch as
        given."""
        x, y, yaw = self.mount_xy_yaw()
        return (f"[depth]\nmount_xyz = [{x:.3f}, {y:.3f}, {z:.3f}]\n"
                f"mount_rpy_deg = [{roll_deg:.2f}, {pitch_deg:.2f}, {yaw:.2f}]\n")

    def tf_static_command(self, z: float, roll_deg: float, pitch_deg: float, child: str = "camera_link") -> str:
        """A ROS 2 static_transform_publisher line publishing that mount on /tf_static."""
        x, y, yaw = self.mount_xy_yaw()
        return (f"ros2 run tf2_ros static_transform_publisher --x {x:.3f} --y {y:.3f} --z {z:.3f} "
                f"--roll {np.radians(roll_deg):.5f} --pitch {np.radians(pitch_deg):.5f} "
                f"--yaw {np.radians(yaw):.5f} --frame-id base_link --child-frame-id {child}")


def _line_normals(q: np.ndarray, tree, k: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Each laser point's line normal (the smallest principal axis of its k nearest points) and whether its
    neighbourhood is a line (the small axis's spread under a tenth of the large one's)."""
    _, idx = tree.query(q, k=min(k, len(q)))
    nb = q[idx] - q[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    w, v = np.linalg.eigh(cov)
    return v[:, :, 0], w[:, 0] < 0.01 * np.maximum(w[:, 1], 1e-12)


class LaserAligner:
    """Collects (KOS points, laser points) of the same instants, both in base_link, and finds the one rigid motion
    of the base plane that lays the KOS points onto the laser's lines: point-to-line ICP (Censi 2008, PL-ICP) over
    all the steps at once, so walls seen at different headings fix x, y and yaw together, with a robust gate (the
    correspondences beyond 3 median absolute residuals, and beyond 0.3 m, do not count: objects the laser does not
    see at its height, people, glass). Written here: scipy has no 2-D ICP and Open3D is an optional extra."""

    def __init__(self, max_steps: int = 300, per_step: int = 120) -> None:
        self.steps: list[tuple] = []  # per step: KOS points, laser points, their normals, line-like, KD-tree
        self.max_steps, self.per_step = max_steps, per_step

    def add(self, kos_xy: np.ndarray, laser_xy: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        p, q = np.asarray(kos_xy, float).reshape(-1, 2), np.asarray(laser_xy, float).reshape(-1, 2)
        p, q = p[np.isfinite(p).all(axis=1)], q[np.isfinite(q).all(axis=1)]
        if len(p) < 10 or len(q) < 10:
            return
        if len(self.steps) >= self.max_steps:  # keep every other step: a spread over the whole log
            self.steps = self.steps[::2]
        p = p[:: max(1, len(p) // self.per_step)]
        tree = cKDTree(q)
        n, line = _line_normals(q, tree)
        if line.sum() >= 10:
            self.steps.append((p, q, n, line, tree))

    def solve(self, iterations: int = 40) -> tuple[np.ndarray, np.ndarray, float, int, float]:
        """(dx, dy, dyaw rad), their standard errors, the normals' spread (the smaller eigenvalue of the matched
        lines' mean n·nᵀ: 0 when every wall seen runs one way, 0.5 for walls both ways), the correspondences kept,
        their RMS residual (m)."""
        T = np.zeros(3)
        gate, kept, rms, sd, spread = 0.3, 0, float("nan"), np.full(3, np.inf), 0.0
        for _ in range(iterations):
            c, s = np.cos(T[2]), np.sin(T[2])
            rows, res, normals = [], [], []
            for p, q, n, line, tree in self.steps:
                pt = p @ np.array([[c, s], [-s, c]]) + T[:2]
                d, j = tree.query(pt)
                ok = (d < gate) & line[j]
                nn = n[j[ok]]
                r = np.einsum("ij,ij->i", nn, pt[ok] - q[j[ok]])
                dp = np.c_[-pt[ok, 1] + T[1], pt[ok, 0] - T[0]]  # ∂(R·p + t)/∂yaw
                rows.append(np.c_[nn, np.einsum("ij,ij->i", nn, dp)])
                res.append(r)
                normals.append(nn)
            if not rows or sum(len(r) for r in res) < 6:
                return T, sd, spread, 0, rms
            A, r, N = np.vstack(rows), np.concatenate(res), np.vstack(normals)
            mad = 1.4826 * np.median(np.abs(r))
            keep = np.abs(r) <= max(3.0 * mad, 0.01)
            step = np.linalg.lstsq(A[keep], -r[keep], rcond=None)[0]
            T += step
            kept, rms = int(keep.sum()), float(np.sqrt(np.mean(r[keep] ** 2)))
            sd = np.sqrt(np.abs(np.diag(rms ** 2 * np.linalg.pinv(A[keep].T @ A[keep]))))
            spread = float(np.linalg.eigvalsh(N[keep].T @ N[keep] / max(kept, 1))[0])
            gate = max(0.05, min(gate, 5.0 * mad))
            if np.abs(step[:2]).max() < 1e-5 and abs(step[2]) < 1e-6:
                break
        return T, sd, spread, kept, rms

    def estimate(self, given_xy, given_yaw_deg: float, min_steps: int = 5) -> LaserAlignment | None:
        """The camera's x, y and yaw in base_link (None with fewer than min_steps usable steps)."""
        if len(self.steps) < min_steps:
            return None
        gx, gy = float(given_xy[0]), float(given_xy[1])
        T, sd, spread, kept, rms = self.solve()
        c, s = np.cos(T[2]), np.sin(T[2])
        x, y = c * gx - s * gy + T[0], s * gx + c * gy + T[1]
        dyaw = float(np.degrees(T[2]))
        return LaserAlignment(len(self.steps), kept, rms, float(T[0]), float(T[1]), dyaw, float(x), float(y),
                              float(given_yaw_deg) + dyaw, gx, gy, float(given_yaw_deg), float(sd[0]), float(sd[1]),
                              float(np.degrees(sd[2])), spread)
