"""A folder of depth images (16-bit PNG/PGM) with a camera file, read like a log.

The camera file (YAML or JSON) gives `fx, fy, cx, cy` and `depth_scale` (image units per metre: 1000 for
millimetres, 5000 for TUM); `width`/`height` are optional. Open3D's `{"width", "height", "intrinsic_matrix"}`
(column-major) and a row-major `K` are read too. Frames are stamped by their file name when it is a
time (TUM's `1305031102.160407.png`, or an integer Unix time in s, ms, µs or ns), else at `fps` from zero (a
numbered sequence, `000123.png`, counts frames).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs import topics as T
from kosmap.frontend.logs.base import LogInfo, LogReader, TopicInfo
from kosmap.frontend.records import CameraModel, DepthFrame, seconds_to_ns

IMAGE_SUFFIXES = (".png", ".pgm", ".tif", ".tiff")
CAMERA_NAMES = ("camera.yaml", "camera.yml", "camera.json", "intrinsics.yaml", "intrinsics.json", "calibration.yaml")
DEPTH_TOPIC = "/camera/depth/image"
INFO_TOPIC = "/camera/depth/camera_info"
FRAME_ID = "camera_depth_optical_frame"


def _natural(p: Path):
    try:
        return (0, float(p.stem), p.name)
    except ValueError:
        return (1, 0.0, [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)])


# An integer name is a Unix time when it has the digits of one since 2001-09-09 (1e9 s) in s, ms, µs or ns;
# shorter integers (000123.png) count frames, not seconds.
_EPOCH_DIGITS_UNIT_NS = {10: 1_000_000_000, 13: 1_000_000, 16: 1_000, 19: 1}


def _name_ns(stem: str) -> int | None:
    """The time a file name says, in ns: seconds with a fraction (TUM's 1305031102.160407) or an integer Unix time
    in s, ms, µs or ns; None for any other name (a frame counter, words)."""
    sec, dot, frac = stem.partition(".")
    if not sec.isdigit() or (dot and (not frac.isdigit() or len(frac) > 9)):
        return None
    if dot:
        return int(sec) * 1_000_000_000 + int(frac.ljust(9, "0"))
    unit = _EPOCH_DIGITS_UNIT_NS.get(len(sec))
    return int(sec) * unit if unit and sec[0] != "0" else None


# images whose names say they are not depth: colour, labels, masks, segmentations (the NYU/SUN/ScanNet layouts)
NOT_DEPTH = re.compile(r"rgb|colou?r|label|mask|seg|semantic|instance", re.IGNORECASE)


def depth_files(folder: Path, pattern: str | None = None) -> tuple[list[Path], list[Path]]:
    """The depth images of a folder (or of its `depth/` subfolder), in numeric/natural order, and the images
    skipped by name (NOT_DEPTH). With `pattern` (a glob, e.g. "*_depth.png") exactly the files it matches."""
    for d in (folder, folder / "depth"):
        if not d.is_dir():
            continue
        if pattern:
            images = [p for p in d.glob(pattern) if p.is_file()]
            skipped: list[Path] = []
        else:
            images = [p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
            skipped = [p for p in images if NOT_DEPTH.search(p.name)]
            images = [p for p in images if not NOT_DEPTH.search(p.name)]
        if images:
            return sorted(images, key=_natural), skipped
    return [], []


METRES_PER_UNIT_KEYS = ("depth_units", "depth_unit", "meters_per_unit", "metres_per_unit", "depth_unit_m")
UNITS_PER_METRE_KEYS = ("units_per_meter", "units_per_metre", "depth_factor", "depth_scale_factor", "factor")


def units_per_metre(value: float) -> float:
    """A depth scale in either convention as image units per metre: a value below 1 is metres per unit
    (RealSense's depth_scale 0.001), one of 1 or more units per metre (1000 = millimetres, 5000 = TUM)."""
    return 1.0 / value if 0 < value < 1 else value


def read_camera_file(path: str | Path, default_scale: float | None = 1000.0) -> tuple[dict, float | None]:
    """{fx, fy, cx, cy[, width, height]} and depth_scale (units per metre) from YAML/JSON; `default_scale` when the
    file gives none (None lets a caller with its own depth encoding tell "not given" apart)."""
    p = Path(path)
    try:
        text = p.read_text()
        if p.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(text)
    except (OSError, ValueError) as e:
        raise LogError(f"cannot read camera file {p}: {e}; it must be YAML or JSON with fx, fy, cx, cy, depth_scale") from e
    if not isinstance(data, dict):
        raise LogError(f"camera file {p} must be a mapping with fx, fy, cx, cy, depth_scale")
    data = {str(k).lower(): v for k, v in data.items()}
    cam: dict = {}
    try:
        if "intrinsic_matrix" in data:  # Open3D PinholeCameraIntrinsic JSON: column-major 3×3
            K = np.asarray(data["intrinsic_matrix"], float).reshape(3, 3).T
            cam.update(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
        elif "k" in data:
            K = np.asarray(data["k"], float).reshape(3, 3)
            cam.update(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
        else:
            cam.update({k: float(data[k]) for k in ("fx", "fy", "cx", "cy")})
    except (KeyError, ValueError, TypeError) as e:
        raise LogError(f"camera file {p} lacks the intrinsics ({e}); give fx, fy, cx, cy (pixels) and depth_scale") from e
    for k in ("width", "height"):
        if k in data:
            cam[k] = int(data[k])
    # depth_scale in either convention (units_per_metre); a named key removes the doubt
    key = next((k for k in ("depth_scale", *METRES_PER_UNIT_KEYS, *UNITS_PER_METRE_KEYS) if k in data), None)
    try:
        scale = float(data[key]) if key is not None else default_scale
    except (ValueError, TypeError) as e:
        raise LogError(f"camera file {p}: {key} {data[key]!r} is not a number ({e})") from e
    if not (cam["fx"] > 0 and cam["fy"] > 0) or (scale is not None and not 0 < scale < np.inf):
        raise LogError(f"camera file {p}: fx, fy and {key or 'depth_scale'} must be positive")
    if scale is not None and key in METRES_PER_UNIT_KEYS:
        scale = 1.0 / scale
    elif scale is not None and key == "depth_scale":
        scale = units_per_metre(scale)
    return cam, scale


def check_depth_scale(scale: float | None, option: str = "--depth-scale") -> float | None:
    """The depth scale if it is a positive finite number (None: not given); a one-line error otherwise."""
    if scale is not None and not 0 < scale < np.inf:
        raise LogError(f"{option} {scale:g} must be a positive number: image units per metre "
                       f"(1000 = millimetres, 5000 = TUM) or, below 1, metres per unit (0.001 = millimetres)")
    return None if scale is None else units_per_metre(scale)


def scale_words(scale: float) -> str:
    """How a warning names a depth scale: "millimetres" for 1000, else the number of image units per metre."""
    return "millimetres" if scale == 1000.0 else f"{scale:g} image units per metre"


def camera_model(intrinsics: dict, shape: tuple[int, int], frame_id: str = FRAME_ID, topic: str = INFO_TOPIC,
                 stamp_ns: int = 0) -> CameraModel:
    """The pinhole camera of a camera file's intrinsics for an image of `shape` (its size unless the file gives one)."""
    c = intrinsics
    K = np.array([[c["fx"], 0.0, c["cx"]], [0.0, c["fy"], c["cy"]], [0.0, 0.0, 1.0]])
    return CameraModel(c.get("width", shape[1]), c.get("height", shape[0]), K, np.zeros(5), "plumb_bob", frame_id,
                       topic, stamp_ns)


def find_camera_file(folder: Path) -> Path | None:
    for d in (folder, folder.parent):
        for name in CAMERA_NAMES:
            if (d / name).is_file():
                return d / name
    return None


class ImageFolder(LogReader):
    """Depth images in a folder, as a log with one depth topic and one camera info."""

    format = "depth image folder"

    def __init__(self, path: str | Path, camera_file: str | Path | None = None, depth_scale: float | None = None,
                 fps: float = 30.0, frame_id: str = FRAME_ID, pattern: str | None = None) -> None:
        super().__init__(Path(path))
        if not self.path.is_dir():
            raise LogError(f"{self.path} is not a folder of depth images")
        self.files, named = depth_files(self.path, pattern)
        if not self.files:
            what = f"no file matching --glob {pattern}" if pattern else \
                f"no depth images ({', '.join(IMAGE_SUFFIXES)}, not named {NOT_DEPTH.pattern})"
            raise LogError(f"{self.path} has {what}, nor a depth/ subfolder with them")
        if named:
            self._warn(f"skipped {len(named)} images named as colour, labels or masks (e.g. {named[0].name}); "
                       f"--glob PATTERN selects the depth images explicitly")
        self.not_depth: list[str] = []  # images skipped when read: 8-bit or colour, not depth
        cf = Path(camera_file) if camera_file else find_camera_file(self.path)
        self.camera_file = cf
        self.intrinsics: dict | None = None
        self.depth_scale = 1000.0
        if cf is not None:
            self.intrinsics, self.depth_scale = read_camera_file(cf)
        if depth_scale is not None:  # an explicit scale beats the camera file's
            self.depth_scale = check_depth_scale(float(depth_scale), "depth scale")
        if cf is None:
            self._warn(f"no camera file in {self.path}: using the field-of-view model and depth in "
                       f"{scale_words(self.depth_scale)} (give --camera FILE with fx, fy, cx, cy, depth_scale)")
        if not (math.isfinite(fps) and fps > 0):
            raise LogError(f"a frame rate of {fps} fps is no rate; give the camera's frames per second (e.g. 30)")
        self.fps = fps
        self.frame_id = frame_id
        self.timed = False  # True when the file names are the frames' times, False when they play at fps
        self.stamps_ns = self._stamps()

    def _stamps(self) -> list[int]:
        """Nanoseconds from names like 1305031102.160407 (parsed exactly, not through a float), else at fps."""
        vals = [_name_ns(p.stem) for p in self.files]
        if all(v is not None for v in vals) and len(set(vals)) == len(vals):
            self.timed = True
            return vals  # type: ignore[return-value]
        return [seconds_to_ns(i / self.fps) for i in range(len(self.files))]

    def info(self) -> LogInfo:
        topics = [TopicInfo(DEPTH_TOPIC, T.IMAGE, len(self.files))]
        if self.intrinsics is not None:
            topics.append(TopicInfo(INFO_TOPIC, T.CAMERA_INFO, 1))
        notes = [f"camera file {self.camera_file}, depth_scale {self.depth_scale:g} per metre"] if self.camera_file else []
        return LogInfo(self.path, self.format, self.stamps_ns[0], self.stamps_ns[-1], topics, notes=notes)

    def read_image(self, path: Path) -> np.ndarray | None:
        import cv2

        try:
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        except cv2.error as e:  # e.g. a header claiming more pixels than OpenCV decodes (2^30)
            raise LogError(f"cannot read depth image {path} ({str(e).strip().splitlines()[-1]}); check the file") from e
        if img is None:
            raise LogError(f"cannot read depth image {path}; it must be a 16-bit PNG or PGM")
        if img.ndim != 2 or img.dtype not in (np.uint16, np.float32):  # 8-bit or colour: not depth, skipped
            if not self.not_depth:
                self._warn(f"skipping images that are not depth (8-bit or colour), first {path.name} "
                           f"({img.dtype}, shape {img.shape}); --glob PATTERN selects the depth images")
            self.not_depth.append(path.name)
            return None
        return img

    def camera(self, shape: tuple[int, int]) -> CameraModel | None:
        if self.intrinsics is None:
            return None
        return camera_model(self.intrinsics, shape, self.frame_id, INFO_TOPIC, self.stamps_ns[0])

    def read(self, topics: Iterable[str] | None = None) -> Iterator[DepthFrame | CameraModel]:
        want = set(topics) if topics is not None else {DEPTH_TOPIC, INFO_TOPIC}
        sent_info = False
        for path, t in zip(self.files, self.stamps_ns):
            img = self.read_image(path)
            if img is None:
                if len(self.not_depth) == len(self.files):
                    raise LogError(f"{self.path}: {path.name} is not a single-channel 16-bit depth image, nor is any "
                                   f"other of its {len(self.files)} images; give the folder of depth images or --glob")
                continue
            if not sent_info and INFO_TOPIC in want:
                cam = self.camera(img.shape)
                if cam is not None:
                    yield cam
                sent_info = True
            if DEPTH_TOPIC not in want:
                break
            if img.dtype == np.uint16 and self.depth_scale == 1000.0:
                yield DepthFrame(t, img, "16UC1", self.frame_id, DEPTH_TOPIC)
            else:
                m = img.astype(np.float32) / np.float32(self.depth_scale if img.dtype == np.uint16 else 1.0)
                yield DepthFrame(t, m, "32FC1", self.frame_id, DEPTH_TOPIC)
