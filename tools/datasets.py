"""Decoders for the real depth frames in ../shared/data/depth (see its SOURCES.md), each with its camera.

Every dataset has its own resolution, intrinsics and depth encoding: TUM (PNG, value/5000 m), SUN RGB-D
(bits rotated: d = (v >> 3) | (v << 13) mm), NYU v2 raw (little-endian PGM of disparity: m = 351.3 /
(1092.5 − raw), 2047 invalid), slambook2 (PGM mm), CAPE (PNG mm, IR intrinsics) and mOSD (organised PCD,
binary_compressed = LZF, with per-pixel labels; the supporting table plane is labels 1–9).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from kosmap.frontend.errors import KosmapError
from kosmap.frontend.records import CameraModel

DATASETS = ("tum_fr1_xyz", "open3d_rgbd_formats", "slambook2_ch5_rgbd", "cape_tunnel_frame", "pcl_mosd_plane_gt")


@dataclass
class DepthSample:
    """One real depth frame: metres (float32, 0 = no data), its camera, and labels where the dataset has them;
    `units` is the image units per metre the file stores (None: not linear units, e.g. disparity or a cloud)."""

    dataset: str
    name: str
    depth: np.ndarray
    camera: CameraModel
    stamp: float = 0.0
    labels: np.ndarray | None = None
    units: float | None = None


def _cam(w: int, h: int, fx: float, fy: float, cx: float, cy: float, frame_id: str = "camera") -> CameraModel:
    return CameraModel(w, h, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.zeros(5), "plumb_bob", frame_id)


def _imread16(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16:
        raise KosmapError(f"{path} is not a 16-bit depth image; check the file against SOURCES.md")
    return img


def read_tum_depth(path: Path) -> np.ndarray:
    """TUM RGB-D depth PNG → metres (value / 5000)."""
    return _imread16(path).astype(np.float32) / np.float32(5000.0)


def read_sun_depth(path: Path) -> np.ndarray:
    """SUN RGB-D depth PNG → metres: the 16 bits are rotated by 3 (Open3D's CreateRGBDImageFromSUNFormat)."""
    v = _imread16(path)
    mm = (v >> np.uint16(3)) | (v << np.uint16(13))
    return mm.astype(np.float32) / np.float32(1000.0)


def read_nyu_depth(path: Path) -> np.ndarray:
    """NYU v2 raw PGM → metres: little-endian disparity despite the header; 351.3 / (1092.5 − raw); 2047 invalid."""
    data = Path(path).read_bytes()
    parts, pos = [], 0
    while len(parts) < 4:  # magic, width, height, maxval (comments are not used in these files)
        while data[pos:pos + 1].isspace():
            pos += 1
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        parts.append(data[pos:end])
        pos = end
    pos += 1
    w, h = int(parts[1]), int(parts[2])
    raw = np.frombuffer(data, dtype="<u2", count=w * h, offset=pos).reshape(h, w).astype(np.float32)
    with np.errstate(divide="ignore"):
        m = np.float32(351.3) / (np.float32(1092.5) - raw)
    m[(raw >= 2047) | (m <= 0)] = 0.0
    return m.astype(np.float32)


def read_mm(path: Path) -> np.ndarray:
    """A 16-bit PNG/PGM in millimetres → metres."""
    return _imread16(path).astype(np.float32) / np.float32(1000.0)


@njit(cache=True)
def lzf_decompress(src: np.ndarray, out_len: int) -> np.ndarray:
    """LZF (liblzf) decompression, as PCD's binary_compressed uses."""
    out = np.empty(out_len, np.uint8)
    ip = 0
    op = 0
    n = len(src)
    while ip < n:
        ctrl = np.int64(src[ip])
        ip += 1
        if ctrl < 32:
            ln = ctrl + 1
            if op + ln > out_len or ip + ln > n:
                raise ValueError("corrupt LZF data")
            out[op:op + ln] = src[ip:ip + ln]
            op += ln
            ip += ln
        else:
            ln = ctrl >> 5
            ref = op - ((ctrl & 0x1F) << 8) - 1
            if ln == 7:
                ln += np.int64(src[ip])
                ip += 1
            ref -= np.int64(src[ip])
            ip += 1
            ln += 2
            if ref < 0 or op + ln > out_len:
                raise ValueError("corrupt LZF data")
            for _ in range(ln):
                out[op] = out[ref]
                op += 1
                ref += 1
    if op != out_len:
        raise ValueError("LZF data shorter than announced")
    return out


def read_pcd(path: Path) -> dict[str, np.ndarray]:
    """An organised PCD v0.7 (ascii, binary or binary_compressed) → {field: H×W array}."""
    data = Path(path).read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = data.index(b"\n", pos)
        line = data[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    fields = header["FIELDS"]
    sizes = [int(s) for s in header["SIZE"]]
    types = header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    w, h = int(header["WIDTH"][0]), int(header["HEIGHT"][0])
    n = w * h
    dt = [np.dtype({"U": "<u", "I": "<i", "F": "<f"}[t] + str(s)) for t, s in zip(types, sizes)]
    kind = header["DATA"][0].lower()
    out: dict[str, np.ndarray] = {}
    if kind == "binary_compressed":
        csize, usize = np.frombuffer(data, "<u4", 2, pos)
        raw = lzf_decompress(np.frombuffer(data, np.uint8, int(csize), pos + 8), int(usize)).tobytes()
        off = 0
        for f, d, c in zip(fields, dt, counts):  # structure of arrays: each field for all points
            arr = np.frombuffer(raw, d, n * c, off)
            off += n * c * d.itemsize
            out[f] = arr.reshape(h, w) if c == 1 else arr.reshape(h, w, c)
    elif kind == "binary":
        rec = np.dtype([(f, d, (c,)) if c > 1 else (f, d) for f, d, c in zip(fields, dt, counts)])
        arr = np.frombuffer(data, rec, n, pos)
        out = {f: arr[f].reshape(h, w, *arr[f].shape[1:]) for f in fields}
    else:
        vals = np.loadtxt(data[pos:].decode().splitlines(), dtype=np.float64, ndmin=2)
        col = 0
        for f, d, c in zip(fields, dt, counts):
            out[f] = vals[:, col:col + c].astype(d).reshape(h, w) if c == 1 else vals[:, col:col + c].astype(d).reshape(h, w, c)
            col += c
    return out


def intrinsics_from_organised(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> CameraModel:
    """The pinhole camera of an organised cloud, by least squares on col = fx·x/z + cx, row = fy·y/z + cy."""
    h, w = z.shape
    rr, cc = np.mgrid[0:h, 0:w]
    ok = np.isfinite(z) & (z > 0)
    A = np.column_stack(((x / z)[ok], np.ones(ok.sum())))
    fx, cx = np.linalg.lstsq(A, cc[ok].astype(float), rcond=None)[0]
    A = np.column_stack(((y / z)[ok], np.ones(ok.sum())))
    fy, cy = np.linalg.lstsq(A, rr[ok].astype(float), rcond=None)[0]
    return _cam(w, h, float(fx), float(fy), float(cx), float(cy))


def read_mosd(path: Path) -> DepthSample:
    """An mOSD organised cloud: depth = z, labels (1–9 = the supporting table plane), intrinsics fitted."""
    f = read_pcd(path)
    z = np.nan_to_num(f["z"].astype(np.float32), nan=0.0)
    cam = intrinsics_from_organised(f["x"], f["y"], f["z"])
    return DepthSample("pcl_mosd_plane_gt", Path(path).stem, z, cam, 0.0, f["label"].astype(np.int32))


ROS_DEFAULT = (525.0, 525.0, 319.5, 239.5)  # TUM's recommendation for depth → 3D; Open3D's primesense


def tum_frames(folder: Path) -> list[tuple[float, Path]]:
    """(stamp, depth PNG) of every frame of a TUM RGB-D folder's depth list, in order."""
    rows = [line.split()[:2] for line in (folder / "depth_included.txt").read_text().splitlines() if line.strip()]
    return [(float(t), folder / rel) for t, rel in rows]


def iter_dataset(folder: str | Path, limit: int | None = None, every: int = 1) -> Iterator[DepthSample]:
    """The frames of one dataset folder of ../shared/data/depth (by its folder name)."""
    folder = Path(folder)
    name = folder.name
    if name == "tum_fr1_xyz":
        for t, p in tum_frames(folder)[::every][:limit]:
            yield DepthSample(name, p.stem, read_tum_depth(p), _cam(640, 480, *ROS_DEFAULT), t, units=5000.0)
    elif name == "open3d_rgbd_formats":
        items = [("TUM", read_tum_depth, "TUM_depth.png", (535.4, 539.2, 320.1, 247.6), 5000.0),
                 ("SUN", read_sun_depth, "SUN_depth.png", ROS_DEFAULT, 1000.0),
                 ("NYU", read_nyu_depth, "NYU_depth.pgm", (582.6245, 582.6910, 313.0448, 238.4439), None)]
        for label, reader, fn, k, units in items[::every][:limit]:
            d = reader(folder / fn)
            yield DepthSample(name, label, d, _cam(d.shape[1], d.shape[0], *k), units=units)
    elif name == "slambook2_ch5_rgbd":
        files = sorted((folder / "depth").glob("*.pgm"), key=lambda p: int(p.stem))[::every][:limit]
        for p in files:
            yield DepthSample(name, p.stem, read_mm(p), _cam(640, 480, 518.0, 519.0, 325.5, 253.5), float(p.stem),
                              units=1000.0)
    elif name == "cape_tunnel_frame":
        d = read_mm(folder / "depth_0.png")
        yield DepthSample(name, "depth_0", d, _cam(640, 480, 575.92685, 576.40792, 315.15026, 230.58581), units=1000.0)
    elif name == "pcl_mosd_plane_gt":
        for p in sorted(folder.glob("*.pcd"), key=lambda p: (len(p.stem), p.stem))[::every][:limit]:
            yield read_mosd(p)
    else:
        raise KosmapError(f"{folder} is not one of the known depth datasets ({', '.join(DATASETS)})")


def detect(path: str | Path) -> list[Path]:
    """The known dataset folders at `path`: itself, or its children (the depth data root)."""
    p = Path(path)
    if p.name in DATASETS and p.is_dir():
        return [p]
    if p.is_dir():
        return [p / d for d in DATASETS if (p / d).is_dir()]
    return []


def iter_samples(path: str | Path, limit: int | None = None, every: int = 1) -> Iterator[DepthSample]:
    """Every frame of every known dataset at `path` (limit and every apply per dataset)."""
    for folder in detect(path):
        yield from iter_dataset(folder, limit, every)
