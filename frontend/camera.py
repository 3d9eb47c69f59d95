"""Depth-camera settings and geometry: which depths are usable, the field-of-view fallback, the mount."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from kosmap.frontend.params import StageConfig, param
from kosmap.frontend.records import CameraModel, Transform, Transforms


@dataclass
class DepthConfig(StageConfig):
    """[depth]: thesis Table 5.4 (minDepth, maxDepth, fH, fV) and the mount used when /tf_static lacks one."""

    section = "depth"
    min_depth: float = param(0.5, lo=0.0, doc="nearer pixels are ineligible (thesis minDepth)", unit="m")
    max_depth: float = param(4.5, lo=0.0, lo_open=True, doc="farther pixels are ineligible (thesis maxDepth)", unit="m")
    fov_h_deg: float = param(70.6, lo=1.0, hi=179.0, doc="horizontal field of view when no CameraInfo", unit="deg")
    fov_v_deg: float = param(60.0, lo=1.0, hi=179.0, doc="vertical field of view when no CameraInfo", unit="deg")
    mount_xyz: list = param([0.0, 0.0, 1.0], doc="camera_link in base_link when /tf_static has no mount", unit="m")
    mount_rpy_deg: list = param([0.0, 0.0, 0.0], doc="camera_link roll, pitch, yaw in base_link (pitch > 0 looks down)", unit="deg")
    mount: str = param("given", choices=("given", "auto", "config"), doc="the depth camera's mount: given = /tf_static's, "
                       "else mount_*; config = mount_* even when /tf_static has one; auto = `kosmap build` estimates "
                       "pitch, roll and height from the log's floor planes first (kosmap planes reports the same)")
    gravity: str = param("auto", choices=("auto", "mount", "frames"), doc="where plane classes take gravity from: "
                         "auto = /tf_static's mount, else a gravity file beside the images, else mount_* when set, else "
                         "the frames (the dominant level plane family, tracked: frontend/gravity.py); mount = the "
                         "mount always (a level camera at 1 m by default); frames = the frames always")

    def __post_init__(self) -> None:
        super().__post_init__()
        from kosmap.frontend.errors import ConfigError

        if self.max_depth <= self.min_depth:
            raise ConfigError(f"config [depth] max_depth = {self.max_depth} must be greater than min_depth = {self.min_depth}")
        for name in ("mount_xyz", "mount_rpy_deg"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"config [depth] {name} = {getattr(self, name)!r} must have 3 numbers")


# ---- intrinsics ---------------------------------------------------------------------------------------------------

def camera_for(shape: tuple[int, int], cam: CameraModel | None, cfg: DepthConfig | None = None,
               frame_id: str = "") -> CameraModel:
    """The camera model for an image of `shape` (rows, cols): CameraInfo if it fits, else the FOV model.

    A CameraInfo for another resolution of the same aspect (e.g. HD info for a half-size image) is scaled;
    without one, fx = (w/2)/tan(fH/2), fy = (h/2)/tan(fV/2) (docs/design.md; not the thesis's eq. 2.1–2.2).
    """
    h, w = int(shape[0]), int(shape[1])
    if cam is not None:
        if cam.width == w and cam.height == h:
            return cam
        sx, sy = w / cam.width, h / cam.height
        if abs(sx - sy) < 1e-3 * max(sx, sy):
            K = np.array(cam.K, dtype=float).copy()
            K[0, 0] *= sx
            K[1, 1] *= sy
            K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5  # pixel centres scale about the image corner
            K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
            return CameraModel(w, h, K, cam.D, cam.distortion_model, cam.frame_id, cam.topic, cam.stamp_ns)
    cfg = cfg or DepthConfig()
    return CameraModel.from_fov(w, h, np.radians(cfg.fov_h_deg), np.radians(cfg.fov_v_deg),
                                frame_id or (cam.frame_id if cam is not None else ""))


# ---- depthConstraints (thesis Alg. 4) ------------------------------------------------------------------------------

def depth_constraints(depth_m: np.ndarray, min_depth: float, max_depth: float) -> np.ndarray:
    """Eligible pixels (bool H×W): finite, > minDepth and ≤ maxDepth; 0 and NaN are ineligible (thesis Alg. 4)."""
    d = np.asarray(depth_m)
    with np.errstate(invalid="ignore"):
        return (d > min_depth) & (d <= max_depth)  # NaN compares False


# ---- pixels ↔ 3D (pinhole) -------------------------------------------------------------------------------------------

def backproject(depth_m: np.ndarray, cam: CameraModel, rows: np.ndarray | None = None,
                cols: np.ndarray | None = None) -> np.ndarray:
    """3D points (N×3 float32, optical frame: x right, y down, z forward) of the given pixels.

    Without rows/cols: every pixel of the image (H·W×3, row-major; invalid depths give NaN/0 points).
    """
    d = np.asarray(depth_m, dtype=np.float32)
    if rows is None or cols is None:
        h, w = d.shape
        rr, cc = np.mgrid[0:h, 0:w]
        rows, cols = rr.ravel(), cc.ravel()
        z = d.ravel()
    else:
        rows, cols = np.asarray(rows), np.asarray(cols)
        z = d[rows, cols]
    x = (cols.astype(np.float32) - np.float32(cam.cx)) * z / np.float32(cam.fx)
    y = (rows.astype(np.float32) - np.float32(cam.cy)) * z / np.float32(cam.fy)
    return np.column_stack((x, y, z)).astype(np.float32, copy=False)


def project(points: np.ndarray, cam: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Pixel (row, col) as floats of N×3 optical-frame points (z > 0 expected)."""
    p = np.asarray(points, dtype=float)
    z = p[:, 2]
    return cam.fy * p[:, 1] / z + cam.cy, cam.fx * p[:, 0] / z + cam.cx


def rays(cam: CameraModel) -> np.ndarray:
    """Unit-depth ray (H×W×3) of every pixel: the point at depth z is z·ray."""
    rr, cc = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    return np.dstack(((cc - cam.cx) / cam.fx, (rr - cam.cy) / cam.fy, np.ones_like(rr)))


# ---- the mount: base_link ← camera optical frame (REP 103) ------------------------------------------------------------

# camera_link (x forward, y left, z up) ← optical (x right, y down, z forward): optical x = −link y,
# optical y = −link z, optical z = link x. As roll/pitch/yaw this is (−π/2, 0, −π/2), the usual static publisher.
OPTICAL_ROTATION = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
BASE_FRAMES = ("base_link", "base_footprint")


def mount_is_default(cfg: DepthConfig) -> bool:
    """Whether [depth] mount_xyz / mount_rpy_deg are the defaults (nobody said where the camera is)."""
    d = DepthConfig()
    return list(cfg.mount_xyz) == list(d.mount_xyz) and list(cfg.mount_rpy_deg) == list(d.mount_rpy_deg)


def mount_transform(xyz, rpy, parent: str = "base_link", child: str = "camera_optical_frame") -> Transform:
    """base_link ← camera optical frame, from the camera_link mount: xyz (m) and roll, pitch, yaw (rad).

    Roll/pitch/yaw are ROS fixed-axis angles of camera_link in base_link, so pitch > 0 looks down.
    """
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", np.asarray(rpy, dtype=float)).as_matrix() @ OPTICAL_ROTATION
    m[:3, 3] = np.asarray(xyz, dtype=float)
    return Transform.from_matrix(parent, child, m)


def config_mount(cfg: DepthConfig, child: str = "camera_optical_frame") -> Transform:
    """The mount of DepthConfig.mount_xyz / mount_rpy_deg (used when /tf_static lacks one)."""
    return mount_transform(cfg.mount_xyz, np.radians(cfg.mount_rpy_deg), child=child or "camera_optical_frame")


def _static_list(transforms) -> list[Transform]:
    out: list[Transform] = []
    for t in transforms or ():
        if isinstance(t, Transforms):
            out.extend(t.transforms)
        elif isinstance(t, Transform):
            out.append(t)
    return out


def lookup_static(transforms, target: str, source: str) -> Transform | None:
    """target ← source through a tree of (static) transforms, or None when they are not connected."""
    target, source = target.lstrip("/"), source.lstrip("/")
    if target == source:
        return Transform.identity(target, source)
    edges: dict[str, list[tuple[str, np.ndarray]]] = {}
    for tf in _static_list(transforms):
        m = tf.matrix()
        edges.setdefault(tf.parent, []).append((tf.child, m))
        edges.setdefault(tf.child, []).append((tf.parent, np.linalg.inv(m)))
    # breadth-first from target; each node keeps target ← node
    seen = {target: np.eye(4)}
    queue = [target]
    while queue:
        node = queue.pop(0)
        for nxt, m in edges.get(node, ()):
            if nxt in seen:
                continue
            # an edge parent→child stored under the parent holds parent ← child; under the child, child ← parent
            seen[nxt] = seen[node] @ m
            if nxt == source:
                return Transform.from_matrix(target, source, seen[nxt])
            queue.append(nxt)
    return None


def camera_mount(transforms, frame_id: str, cfg: DepthConfig | None = None) -> tuple[Transform, str]:
    """base_link ← the depth frame's optical frame: from /tf_static when it connects them, else the config.

    `transforms` are Transforms records (or Transform) from /tf_static; the depth image's frame_id is taken
    to be its optical frame (REP 103). Returns the transform and where it came from ("tf_static" or "config").
    """
    cfg = cfg or DepthConfig()
    if cfg.mount == "auto":
        from kosmap.frontend.errors import ConfigError

        raise ConfigError("depth.mount = auto is resolved by `kosmap build` (from the log's floor planes); for this "
                          "command put the estimate `kosmap planes` reports (mount.toml) into [depth], or use given")
    if cfg.mount == "config":
        return config_mount(cfg, child=frame_id.lstrip("/")), "config"
    if frame_id:
        for base in BASE_FRAMES:
            tf = lookup_static(transforms, base, frame_id)
            if tf is not None:
                return tf, "tf_static"
    return config_mount(cfg, child=frame_id.lstrip("/")), "config"


def gravity_up(mount: Transform | None) -> np.ndarray:
    """The world's up direction in the camera optical frame; a level camera (y down) without a mount."""
    if mount is None:
        return np.array([0.0, -1.0, 0.0])
    x, y, z, w = np.asarray(mount.rotation, float) / np.linalg.norm(mount.rotation)
    # the last row of the rotation matrix base ← optical (unit quaternion x, y, z, w) is up in the optical frame
    return np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])


def camera_axes(mount: Transform | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(up, forward, left) in the optical frame: gravity up, and the horizontal viewing direction and its left.

    Forward is the optical axis with its vertical part removed; left = up × forward (REP 103's y).
    """
    up = gravity_up(mount)
    z = np.array([0.0, 0.0, 1.0])
    f = z - up * (z @ up)
    if np.linalg.norm(f) < 1e-6:  # looking straight down or up: use the image's top as forward
        y = np.array([0.0, -1.0, 0.0])
        f = y - up * (y @ up)
    f /= np.linalg.norm(f)
    return up, f, np.cross(up, f)
