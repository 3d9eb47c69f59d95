"""Map files: map_server PGM/PNG + YAML (read and write) and PNG pictures for people.

map_server conventions (docs/dependencies.md): 254 free, 0 occupied, 205 unknown; YAML `image, mode: trinary,
resolution, origin [x, y, yaw] of the lower-left pixel, negate 0, occupied_thresh 0.65, free_thresh 0.196`.
Image row 0 is the map's top, grid row 0 its bottom: rows are flipped on the way in and out.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import yaml

from kosmap.frontend.errors import KosmapError
from kosmap.mapping.grid import OccupancyGrid

FREE, OCCUPIED, UNKNOWN = 254, 0, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196
REQUIRED_KEYS = ("image", "resolution", "origin")
# What a map file may say. Pixels: 2^28 (16384², 819 m square at 5 cm; ~2 GB as the float grey levels read here).
# Resolution: 0.1 mm to 1 km per pixel. Origin: within ±10^8 m (UTM northings reach 10^7 m).
MAX_MAP_PIXELS = 1 << 28
MIN_RESOLUTION, MAX_RESOLUTION = 1e-4, 1e3
MAX_ORIGIN_M = 1e8


class MapError(KosmapError):
    """A map file that cannot be read or written."""


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def to_trinary(grid: OccupancyGrid) -> np.ndarray:
    """Image (row 0 = top) with 254 free, 0 occupied, 205 unknown, by map_server's thresholds."""
    d = grid.data.astype(np.int16)
    img = np.full(d.shape, UNKNOWN, np.uint8)
    img[(d >= 0) & (d <= FREE_THRESH * 100)] = FREE
    img[d >= OCCUPIED_THRESH * 100] = OCCUPIED
    return np.ascontiguousarray(img[::-1])


def write_map_server(grid: OccupancyGrid, yaml_path: str | Path, image_ext: str = ".pgm") -> Path:
    """Write `<name>.pgm` (or .png) + `<name>.yaml` as map_server reads them; returns the YAML path."""
    yp = Path(yaml_path)
    yp.parent.mkdir(parents=True, exist_ok=True)
    ip = yp.with_suffix(image_ext)
    ok, buf = cv2.imencode(image_ext, to_trinary(grid))
    if not ok:
        raise MapError(f"could not encode {ip.name}")
    _atomic_write_bytes(ip, buf.tobytes())
    meta = {"image": ip.name, "mode": "trinary", "resolution": float(grid.resolution),
            "origin": [float(grid.origin[0]), float(grid.origin[1]), float(grid.origin[2])],
            "negate": 0, "occupied_thresh": OCCUPIED_THRESH, "free_thresh": FREE_THRESH}
    _atomic_write_bytes(yp, yaml.safe_dump(meta, sort_keys=False).encode())
    return yp


def read_map_server(yaml_path: str | Path) -> OccupancyGrid:
    """Read a map_server map (ours or another tool's) back into a grid, applying negate and the thresholds."""
    yp = Path(yaml_path)
    if not yp.is_file():
        raise MapError(f"map file {yp} does not exist; give the map's .yaml")
    try:
        meta = yaml.safe_load(yp.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise MapError(f"{yp} is not valid YAML ({str(e).splitlines()[0]}); give a map_server .yaml") from e
    if not isinstance(meta, dict):
        raise MapError(f"{yp} is not a map_server YAML (expected keys {', '.join(REQUIRED_KEYS)})")
    missing = [k for k in REQUIRED_KEYS if k not in meta]
    if missing:
        raise MapError(f"{yp} lacks {', '.join(missing)}; a map_server YAML needs {', '.join(REQUIRED_KEYS)}")
    res = meta["resolution"]
    if isinstance(res, bool) or not isinstance(res, (int, float)) or not res > 0 or not np.isfinite(res):
        raise MapError(f"{yp}: resolution {res!r} must be a positive number of metres per pixel")
    if not MIN_RESOLUTION <= res <= MAX_RESOLUTION:
        raise MapError(f"{yp}: resolution {res!r} m/pixel is not a map's: give one between {MIN_RESOLUTION:g} and "
                       f"{MAX_RESOLUTION:g} m/pixel")
    origin = meta["origin"]
    if (not isinstance(origin, (list, tuple)) or len(origin) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in origin)):
        raise MapError(f"{yp}: origin {origin!r} must be [x, y, yaw] numbers")
    if not all(np.isfinite(v) and abs(v) <= MAX_ORIGIN_M for v in origin):
        raise MapError(f"{yp}: origin {origin!r} must be finite numbers, x and y within ±{MAX_ORIGIN_M:g} m")
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise MapError(f"{yp}: mode {mode!r} must be trinary, scale or raw")
    try:
        negate = int(meta.get("negate", 0))
        occ_t = float(meta.get("occupied_thresh", OCCUPIED_THRESH))
        free_t = float(meta.get("free_thresh", FREE_THRESH))
    except (TypeError, ValueError) as e:
        raise MapError(f"{yp}: negate, occupied_thresh and free_thresh must be numbers ({e})") from e
    if not 0 <= free_t < occ_t <= 1:
        raise MapError(f"{yp}: thresholds must satisfy 0 ≤ free_thresh ({free_t}) < occupied_thresh ({occ_t}) ≤ 1")
    if not isinstance(meta["image"], str) or not meta["image"]:
        raise MapError(f"{yp}: image {meta['image']!r} must be the image file's name")
    ip = Path(meta["image"]) if os.path.isabs(meta["image"]) else yp.parent / meta["image"]
    img, alpha = _read_gray(ip)
    if img is None:
        raise MapError(f"{yp}: its image {ip} is missing or not an image")
    data = image_to_occupancy(img, alpha, mode, negate, occ_t, free_t)
    return OccupancyGrid(np.ascontiguousarray(data[::-1]), float(res), (float(origin[0]), float(origin[1]), float(origin[2])))


def _claimed_size(path: Path) -> tuple[int, int] | None:
    """(width, height) a PNG's IHDR or a binary PGM/PPM header claims, without decoding; None for other files."""
    with open(path, "rb") as f:
        head = f.read(64)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24:
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if head[:2] in (b"P5", b"P6"):
        text = re.sub(rb"#[^\n]*\n", b" ", head[2:])  # (comments may sit between the header's numbers)
        nums = text.split()[:2]
        if len(nums) == 2 and all(n.isdigit() for n in nums):
            return int(nums[0]), int(nums[1])
    return None


def _read_gray(path: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(grey 0..255 float, alpha 0..1 or None) of an image file, or (None, None) if it is not one. MapError for
    one whose header claims more than MAX_MAP_PIXELS (before it is decoded) or that does not decode."""
    if not Path(path).is_file():
        return None, None
    size = _claimed_size(path)
    if size is not None and size[0] * size[1] > MAX_MAP_PIXELS:
        raise MapError(f"{path}: its header claims {size[0]}×{size[1]} pixels, more than a map kosmap reads "
                       f"({MAX_MAP_PIXELS} pixels); check the file, or crop the map")
    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error as e:  # e.g. a header claiming more pixels than OpenCV decodes
        raise MapError(f"{path} is not an image kosmap can read ({str(e).strip().splitlines()[-1]}); "
                       f"check the file") from e
    if img is None:
        return None, None
    if img.shape[0] * img.shape[1] > MAX_MAP_PIXELS:
        raise MapError(f"{path}: {img.shape[1]}×{img.shape[0]} pixels, more than a map kosmap reads "
                       f"({MAX_MAP_PIXELS} pixels); crop the map")
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    img = img.astype(np.float64) * (255.0 / scale)
    alpha = None
    if img.ndim == 3:  # map_server averages the colour channels; a 2nd/4th channel is alpha
        if img.shape[2] in (2, 4):
            alpha = img[..., -1] / 255.0
            img = img[..., :-1]
        img = img.mean(axis=2)
    return img, alpha


def image_to_occupancy(img: np.ndarray, alpha: np.ndarray | None, mode: str, negate: int, occ_t: float,
                       free_t: float) -> np.ndarray:
    """map_server's rule (image row 0 = top): occ = (255 − v)/255 (v/255 with negate); occ > occupied_thresh →
    100, occ < free_thresh → 0, else −1 (trinary) or rint(1 + 98·ratio) (scale); raw keeps v (0..100, else −1)."""
    data = np.full(img.shape, -1, np.int8)
    if mode == "raw":
        v = np.rint(img)
        ok = v <= 100
        data[ok] = v[ok].astype(np.int8)
        return data
    occ = img / 255.0 if negate else (255.0 - img) / 255.0
    if mode == "scale":
        mid = (occ >= free_t) & (occ <= occ_t)
        if alpha is not None:
            mid &= alpha >= 1.0
        data[mid] = np.rint(1 + 98 * (occ[mid] - free_t) / (occ_t - free_t)).astype(np.int8)
    data[occ > occ_t] = 100
    data[occ < free_t] = 0
    return data


def outside_unknown(data: np.ndarray) -> np.ndarray:
    """A plan with the non-wall cells reachable from its border (4-connected, without crossing a wall) set
    unknown (−1): a blueprint says nothing about the outside of the building."""
    import cv2

    n, lab = cv2.connectedComponents((data < 100).astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate((lab[0], lab[-1], lab[:, 0], lab[:, -1])))
    out = data.copy()
    out[np.isin(lab, border[border > 0])] = -1
    return out


def read_blueprint(path: str | Path, scale: float | None = None, dark: float = 0.5) -> OccupancyGrid:
    """A floor blueprint as a grid of walls (100), the inside (0) and the outside (−1, reached from the border
    without crossing a wall): a map_server YAML (walls = its occupied cells) or a plain image with `scale`
    metres per pixel (walls = pixels darker than dark·white, origin at the lower-left pixel)."""
    p = Path(path)
    if p.suffix.lower() in (".yaml", ".yml"):
        if scale is not None:
            raise MapError(f"{p} is a map_server YAML with its own resolution; drop the blueprint scale")
        g = read_map_server(p)
        return OccupancyGrid(outside_unknown(np.where(g.data >= 100 * OCCUPIED_THRESH, 100, 0).astype(np.int8)),
                             g.resolution, g.origin)
    if not p.is_file():
        raise MapError(f"blueprint {p} does not exist; give an image (with its scale in m/pixel) or a map_server .yaml")
    img, alpha = _read_gray(p)
    if img is None:
        raise MapError(f"blueprint {p} is not an image kosmap reads (PNG, PGM, JPEG, BMP, TIFF) nor a .yaml")
    if scale is None:
        raise MapError(f"blueprint {p} is a plain image: give its scale in metres per pixel (--blueprint-scale), or "
                       f"a map_server .yaml that names it with its resolution")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not scale > 0 or not np.isfinite(scale):
        raise MapError(f"blueprint scale {scale!r} must be a positive number of metres per pixel")
    if not MIN_RESOLUTION <= scale <= MAX_RESOLUTION:
        raise MapError(f"--blueprint-scale {scale:g} m/pixel is not a floor plan's: give one between {MIN_RESOLUTION:g} "
                       f"and {MAX_RESOLUTION:g} m/pixel")
    walls = img < dark * 255.0
    if alpha is not None:
        walls &= alpha > 0.5
    data = outside_unknown(np.where(walls, 100, 0).astype(np.int8))
    return OccupancyGrid(np.ascontiguousarray(data[::-1]), float(scale), (0.0, 0.0, 0.0))


PICTURE_UNKNOWN = 160  # grey of unknown (and undecided) cells in pictures for people


def grid_picture(grid: OccupancyGrid, trajectory: np.ndarray | None = None,
                 color: tuple[int, int, int] = (200, 80, 0), graded: bool = False) -> np.ndarray:
    """BGR picture for people, row 0 = top: white free (occupancy < 50), black occupied (≥ 65), grey unknown
    or undecided; `graded` shows known cells' probability as a grey level instead. Optional trajectory
    (N×2 or N×3 map coordinates) drawn as a line."""
    d = grid.data.astype(np.int16)
    g = np.full(d.shape, PICTURE_UNKNOWN, np.uint8)
    known = d >= 0
    if graded:
        g[known] = (255 - np.clip(d[known], 0, 100) * 255 // 100).astype(np.uint8)
    else:
        g[known & (d < 50)] = 255
        g[d >= round(100 * OCCUPIED_THRESH)] = 0
    img = cv2.cvtColor(np.ascontiguousarray(g[::-1]), cv2.COLOR_GRAY2BGR)
    if trajectory is not None and len(trajectory) >= 1:
        draw_trajectory(img, grid, np.asarray(trajectory, float)[:, :2], color)
    return img


def draw_trajectory(img: np.ndarray, grid: OccupancyGrid, xy: np.ndarray, color=(200, 80, 0), thickness: int = 1) -> None:
    """Draw map points N×2 as a polyline on a picture of `grid` (row 0 = top), in place, sub-pixel exact."""
    inv = np.linalg.inv(grid.pixel_to_world())
    uv = xy @ inv[:2, :2].T + inv[:2, 2]  # cell units from the lower-left corner
    px = np.column_stack((uv[:, 0], grid.height - uv[:, 1]))  # image x, y (row 0 = top)
    shift = 4
    pts = np.rint(px * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(img, [pts], False, color, thickness, cv2.LINE_AA, shift)


def write_grid_mcap(grid: OccupancyGrid, path: str | Path, topic: str = "/map", stamp_ns: int = 0,
                    trajectory: np.ndarray | None = None, stamps_ns: np.ndarray | None = None,
                    path_topic: str = "/trajectory") -> Path:
    """The grid as nav_msgs/OccupancyGrid in an MCAP (Foxglove, ROS 2), with the trajectory as nav_msgs/Path."""
    from kosmap.frontend.logs.writer import McapWriter

    with McapWriter(path) as w:
        w.write_grid(topic, int(stamp_ns), grid.frame_id, grid.data, grid.resolution, grid.origin)
        if trajectory is not None and len(trajectory):
            traj = np.asarray(trajectory, float)
            if traj.shape[1] == 2:
                traj = np.column_stack((traj, np.zeros(len(traj))))
            st = np.zeros(len(traj), np.int64) if stamps_ns is None else np.asarray(stamps_ns, np.int64)
            w.write_path(path_topic, int(stamp_ns), grid.frame_id, traj[:, :3], st)
    return Path(path)


def save_figure(fig, path: str | Path) -> Path:
    """Save a matplotlib figure atomically (a `.partial.png` renamed when complete) and close it."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(p.stem + ".partial.png")
    fig.savefig(tmp)
    import matplotlib.pyplot as plt

    plt.close(fig)
    os.replace(tmp, p)
    return p


def write_png(image_bgr: np.ndarray, path: str | Path) -> Path:
    """Write a picture atomically."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", image_bgr)
    if not ok:
        raise MapError(f"could not encode {p.name}")
    _atomic_write_bytes(p, buf.tobytes())
    return p
