"""The KOS's bearing bins (frontend/kos.py): the bins of a scan, the cameras' views over them, and the tables that
bin a point's bearing without atan2, for the point kernel (a tangent lookup, frontend/kos_points.py) and for the image
kernel (per-pixel ray terms, frontend/kos_image.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from kosmap.frontend.records import CameraModel, Transform


@dataclass(frozen=True)
class Bearings:
    """Bins of a scan in base_link: bin i is centred on angle_min + i·angle_increment."""

    angle_min: float
    angle_increment: float
    n: int
    full_circle: bool = False

    def centres(self) -> np.ndarray:
        return self.angle_min + np.arange(self.n) * self.angle_increment


def check_camera(camera: CameraModel) -> None:
    """LogError when the intrinsics cannot place a column's bearing (a 1×1 image, a focal length that is not a
    positive number, a principal point far outside the image: frontend/logs/validate.py); the readers skip such
    records, this keeps the stage itself from dividing by them."""
    from kosmap.frontend.errors import LogError
    from kosmap.frontend.logs.validate import camera_problem

    why = camera_problem(camera)
    if why is not None:
        name = camera.topic or camera.frame_id or "the depth camera"
        raise LogError(f"{name}: the KOS cannot use a camera with {why}; fix its CameraInfo, or leave it out so that "
                       f"[depth] fov_h_deg, fov_v_deg serve")


def camera_view(camera: CameraModel, mount: Transform) -> tuple[float, float]:
    """(rightmost, leftmost) bearing in base_link of the camera's first and last column centres."""
    check_camera(camera)
    axis = mount.matrix()[:3, :3] @ np.array([0.0, 0.0, 1.0])  # optical z: the viewing direction
    yaw = math.atan2(axis[1], axis[0])
    right = math.atan((camera.width - 1 - camera.cx) / camera.fx)  # optical x points right: last column is rightmost
    left = math.atan(camera.cx / camera.fx)
    return yaw - right, yaw + left


def bearings_for(cameras: list[tuple[CameraModel, Transform]], increment_deg: float = 0.0) -> Bearings:
    """One bin per image column over a camera's view (the thesis); several cameras share a full circle."""
    views = [camera_view(c, m) for c, m in cameras]
    widths = [c.width for c, _ in cameras]
    if increment_deg > 0:
        inc = math.radians(increment_deg)
    else:
        inc = min((hi - lo) / (w - 1) for (lo, hi), w in zip(views, widths))
    if len(cameras) == 1:
        lo, hi = views[0]
        n = int(round((hi - lo) / inc)) + 1
        return Bearings(lo, inc, n)
    n = int(math.ceil(2 * math.pi / inc))
    return Bearings(-math.pi, 2 * math.pi / n, n, full_circle=True)


def in_view(bearings: Bearings, cameras: list[tuple[CameraModel, Transform]]) -> np.ndarray:
    """Bins that some camera sees (others are NaN in the scans: no measurement, REP 117)."""
    a = bearings.centres()
    seen = np.zeros(bearings.n, bool)
    half = bearings.angle_increment / 2
    for c, m in cameras:
        lo, hi = camera_view(c, m)
        d_lo = np.angle(np.exp(1j * (a - lo)))
        d_hi = np.angle(np.exp(1j * (hi - a)))
        seen |= (d_lo >= -half) & (d_hi >= -half)
    return seen


@dataclass(frozen=True)
class BearingTable:
    """Bearing bins as a lookup on the tangent y'/x' in a frame turned to a camera's view centre.

    atan2 per point cost ~60 % of the pass (docs/dependencies.md: "bearing from a tangent lookup instead of atan2"); bins
    are uniform in angle, so a uniform table over the tangent gives a first guess that one or two edge
    comparisons correct.
    """

    cos_c: float
    sin_c: float
    t_min: float
    scale: float
    first: np.ndarray  # first candidate local bin per table cell
    tan_edges: np.ndarray  # lower edge of each local bin, then the upper edge of the last
    bin0: int  # global index of local bin 0


@lru_cache(maxsize=32)
def bearing_table(b: Bearings, centre: float, half_width: float) -> BearingTable:
    """Table for the global bins whose centres lie within ±half_width (< 90°) of `centre`.

    Memoised: the pipeline makes an accumulator per frame, and building the table costs ~0.3 ms."""
    rel = np.angle(np.exp(1j * (b.centres() - centre)))
    if b.full_circle:
        i0 = int(np.floor((centre - half_width - b.angle_min) / b.angle_increment + 0.5))
        i1 = int(np.floor((centre + half_width - b.angle_min) / b.angle_increment + 0.5))
        idx = np.arange(i0, i1 + 1)
        rel = b.angle_min + idx * b.angle_increment - centre
    else:
        idx = np.flatnonzero(np.abs(rel) <= half_width)
        if idx.size == 0:
            idx = np.array([0])
        idx = np.arange(idx[0], idx[-1] + 1)
        rel = rel[idx]
    edges = np.concatenate((rel - b.angle_increment / 2, rel[-1:] + b.angle_increment / 2))
    tan_edges = np.tan(np.clip(edges, -1.55, 1.55))
    m = 8 * len(idx)
    t_min, t_max = float(tan_edges[0]), float(tan_edges[-1])
    cells = t_min + np.arange(m) * (t_max - t_min) / m
    first = np.clip(np.searchsorted(tan_edges, cells, side="right") - 1, 0, len(idx) - 1).astype(np.int64)
    return BearingTable(math.cos(centre), math.sin(centre), t_min, m / (t_max - t_min), first, tan_edges, int(idx[0]))


def view_centre(m: np.ndarray, view_half: float) -> tuple[float, float]:
    """Bearing of a camera's optical axis in base_link (4×4 mount `m`) and the half width of the bins it can fill:
    ±10° beyond the view, for points seen near its edge from a camera mounted off base_link's origin."""
    axis = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
    return float(math.atan2(axis[1], axis[0])), float(min(view_half + math.radians(10.0), math.radians(85.0)))


# The kernels' parameters, one record each: the bearing grid and range limits of `add` (PointGrid), and the


@dataclass(frozen=True)
class PixelTable:
    """Per-pixel tables of one camera on one mount for one bin grid (see `pixel_table`)."""

    ax: np.ndarray  # W float32: column term of the ray in base_link, turned to the view centre
    ay: np.ndarray
    az: np.ndarray
    bx: np.ndarray  # H float32: row term (plus the optical axis)
    by: np.ndarray
    bz: np.ndarray
    t: tuple  # mount offset in the same frame (float32 x, y, z)
    a0: float  # bearing of local bin 0's centre relative to the view centre
    n_local: int
    bin0: int  # global index of local bin 0


@lru_cache(maxsize=64)
def pixel_table(intrinsics: tuple, translation: tuple, quaternion: tuple, b: Bearings) -> PixelTable:
    """Tables for a camera (w, h, fx, fy, cx, cy) on a mount (base_link ← optical: translation, quaternion x y z w).

    The ray of pixel (u, v) is ((u − cx)/fx, (v − cy)/fy, 1); in base_link turned by −centre it is
    M·ray = (u − cx)/fx·M[:, 0] + ((v − cy)/fy·M[:, 1] + M[:, 2]): a column term plus a row term, so the tables
    are W + H entries (a full H×W×3 table costs 2.6 MB of memory traffic per frame; measured slower). The bins
    are those whose centres lie within the view ±10° (as `KosAccumulator._table` chooses for `add`). Memoised:
    the pipeline makes an accumulator per frame.
    """
    w, h, fx, fy, cx, cy = intrinsics
    mount = Transform("base_link", "optical", np.array(translation), np.array(quaternion))
    m = mount.matrix()
    view_half = (math.atan((w - 1 - cx) / fx) + math.atan(cx / fx)) / 2  # as camera_view
    centre, half_width = view_centre(m, view_half)
    c, s = math.cos(centre), math.sin(centre)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    rot = turn @ m[:3, :3]
    col = np.outer((np.arange(w) - cx) / fx, rot[:, 0])
    row = np.outer((np.arange(h) - cy) / fy, rot[:, 1]) + rot[:, 2]
    t = turn @ m[:3, 3]
    if b.full_circle:
        i0 = int(np.floor((centre - half_width - b.angle_min) / b.angle_increment + 0.5))
        i1 = int(np.floor((centre + half_width - b.angle_min) / b.angle_increment + 0.5))
    else:
        rel = np.angle(np.exp(1j * (b.centres() - centre)))
        idx = np.flatnonzero(np.abs(rel) <= half_width)
        i0, i1 = (int(idx[0]), int(idx[-1])) if idx.size else (0, 0)
    a0 = float(np.angle(np.exp(1j * (b.angle_min + i0 * b.angle_increment - centre))))
    f = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    return PixelTable(f(col[:, 0]), f(col[:, 1]), f(col[:, 2]), f(row[:, 0]), f(row[:, 1]), f(row[:, 2]),
                       tuple(np.float32(v) for v in t), a0, i1 - i0 + 1, i0)
