"""Map files: map_server PGM/PNG + YAML (read and write) and PNG pictures for people.

map_server conventions (STACK.md): 254 free, 0 occupied, 205 unknown; YAML `image, mode: trinary,
resolution, origin [x, y, yaw] of the lower-left pixel, negate 0, occupied_thresh 0.65, free_thresh 0.196`.
Image row 0 is the map's top, grid row 0 its bottom: rows are flipped on the way in and out.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import yaml

from frontend.errors import KosmapError
from mapping.grid import OccupancyGrid

FREE, OCCUPIED, UNKNOWN = 254, 0, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196
REQUIRED_KEYS = ("image", "resolution", "origin")


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
    if not isinstance(res, (int, float)) or not res > 0:
        raise MapError(f"{yp}: resolution {res!r} must be a positive number of metres per pixel")
    origin = meta["origin"]
    if not isinstance(origin, (list, tuple)) or len(origin) != 3:
        raise MapError(f"{yp}: origin {origin!r} must be [x, y, yaw]")
    ip = Path(meta["image"]) if os.path.isabs(str(meta["image"])) else yp.parent / str(meta["image"])
    img = cv2.imread(str(ip), cv2.IMREAD_UNCHANGED) if ip.is_file() else None
    if img is None:
        raise MapError(f"{yp}: its image {ip} is missing or not an image")
    if img.ndim == 3:  # colour images: map_server averages the channels
        img = img[..., :3].mean(axis=2)
    img = img.astype(np.float64)
    if img.dtype != np.uint8 and img.max() > 255:
        img = img / 257.0
    occ = (255.0 - img) / 255.0 if not int(meta.get("negate", 0)) else img / 255.0
    occ_t = float(meta.get("occupied_thresh", OCCUPIED_THRESH))
    free_t = float(meta.get("free_thresh", FREE_THRESH))
    data = np.full(img.shape, -1, np.int8)
    mode = meta.get("mode", "trinary")
    if mode == "scale":
        mid = (occ > free_t) & (occ < occ_t)
        data[mid] = np.round(99 * (occ[mid] - free_t) / (occ_t - free_t)).astype(np.int8)
    data[occ >= occ_t] = 100
    data[occ <= free_t] = 0
    return OccupancyGrid(np.ascontiguousarray(data[::-1]), float(res), (float(origin[0]), float(origin[1]), float(origin[2])))


def grid_picture(grid: OccupancyGrid) -> np.ndarray:
    """BGR picture for people: white free, black occupied, grey unknown; row 0 = top."""
    d = grid.data.astype(np.int16)
    g = np.full(d.shape, 128, np.uint8)
    known = d >= 0
    g[known] = (255 - np.clip(d[known], 0, 100) * 255 // 100).astype(np.uint8)
    return cv2.cvtColor(np.ascontiguousarray(g[::-1]), cv2.COLOR_GRAY2BGR)


def write_png(image_bgr: np.ndarray, path: str | Path) -> Path:
    """Write a picture atomically."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", image_bgr)
    if not ok:
        raise MapError(f"could not encode {p.name}")
    _atomic_write_bytes(p, buf.tobytes())
    return p
