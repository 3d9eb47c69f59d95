"""The planes run's first stage: the depth frames of a log (MCAP, bag), of a folder of depth images or of a known
dataset, each as an `Item` with its camera, its mount and where its plane classes take gravity from; --camera and
--depth-scale replace the source's own."""

from __future__ import annotations

import math
from collections.abc import Generator, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.frontend.camera import camera_for, camera_mount, config_mount, lookup_static, mount_is_default
from kosmap.frontend.errors import KosmapError, LogError
from kosmap.frontend.gravity import imu_up, read_gravity_file
from kosmap.frontend.logs.images import camera_model, check_depth_scale, read_camera_file
from kosmap.frontend.records import CameraModel, DepthFrame, Imu, Transform, Transforms

GRAVITY_WORDS = {"tf_static": "the mount in /tf_static", "config": "the [depth] mount_xyz / mount_rpy_deg",
                 "file": "the folder's gravity file", "imu": "the log's IMU (on the depth camera's rigid body)",
                 "frames": "the frames (the dominant level plane family, tracked over the sequence)"}


@dataclass
class Item:
    """One depth frame to filter, with everything it needs."""

    index: int
    stamp_ns: int
    depth: np.ndarray  # metres
    camera: CameraModel
    mount: Transform
    source: str  # topic, or dataset/name
    frame_id: str
    gravity: str = "tf_static"  # where the classes take gravity from: tf_static, config, file, frames
    up: np.ndarray | None = None  # up in the optical frame, from a gravity file


@dataclass
class FrameSource:
    """The frames of a run: how many to expect (for progress), the frames as they are read, and the warnings the
    reading adds to (the list grows while the frames are read)."""

    total: int
    frames: Generator[Item, None, None]
    warnings: list[str]


@dataclass
class Override:
    """What --camera and --depth-scale say, read and checked before any work; None leaves the source's own."""

    camera_file: Path | None = None
    intrinsics: dict | None = None  # fx, fy, cx, cy[, width, height] of the camera file
    depth_scale: float | None = None  # image units per metre: --depth-scale, else the camera file's depth_scale
    scale_from: str = ""  # which option gave depth_scale, for the warnings
    fps: float | None = None  # --fps: the rate of a folder whose file names are no times

    def camera(self, shape: tuple[int, int], frame_id: str) -> CameraModel | None:
        """The camera file's model for an image of `shape`, or None without --camera."""
        return None if self.intrinsics is None else camera_model(self.intrinsics, shape, frame_id, "")


def read_override(camera_file: Path | None, depth_scale: float | None, fps: float | None = None) -> Override:
    """Read --camera and check --depth-scale and --fps up front: a missing file, a scale ≤ 0 or a rate ≤ 0 stops
    the run in one line."""
    depth_scale = check_depth_scale(depth_scale)  # as image units per metre, whichever convention was given
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise KosmapError(f"--fps {fps} is no frame rate; give the camera's frames per second (e.g. 30)")
    if camera_file is None:
        return Override(None, None, depth_scale, f"--depth-scale {depth_scale:g}" if depth_scale is not None else "",
                        fps)
    intrinsics, file_scale = read_camera_file(camera_file, default_scale=None)
    if depth_scale is not None:
        return Override(camera_file, intrinsics, depth_scale, f"--depth-scale {depth_scale:g}", fps)
    return Override(camera_file, intrinsics, file_scale,
                    f"depth_scale {file_scale:g} of --camera {camera_file}" if file_scale is not None else "", fps)


def note(warnings: list[str], text: str) -> None:
    """Add a warning once."""
    if text not in warnings:
        warnings.append(text)


def _log_meters(rec: DepthFrame, ov: Override, warnings: list[str]) -> np.ndarray:
    """A log's depth frame in metres: 16-bit images at the explicit depth scale if any (else millimetres)."""
    if ov.depth_scale is None:
        return rec.meters()
    if rec.encoding != "16UC1":
        note(warnings, f"{ov.scale_from} does not apply to {rec.topic}, whose {rec.encoding} images are in metres")
        return rec.meters()
    return np.divide(rec.image, np.float32(ov.depth_scale), dtype=np.float32)


def _note_rate(log, fps: float | None, from_frames: bool) -> None:
    """Say how a folder's frames are timed where it matters: gravity from the frames tracks the floor with a
    motion model that trusts the times (docs/planes.md)."""
    if log.timed and fps is not None:
        note(log.warnings, f"--fps {fps:g} is not used: the file names of {log.path} are the frames' times")
    elif not log.timed and fps is None and from_frames:
        note(log.warnings, f"the file names of {log.path} are no times: its frames play at {log.fps:g} fps, and "
                           f"gravity from the frames assumes that rate; give --fps RATE if the camera took them at "
                           f"another")


def log_frames(path: Path, cfg, ov: Override, every: int, limit: int | None,
               pattern: str | None = None) -> FrameSource:
    """Frames of a log (MCAP, bag) or of a folder of depth images; --camera and --depth-scale replace its own."""
    from kosmap.frontend.logs import detect_topics, open_log
    from kosmap.frontend.logs.images import ImageFolder

    gravity_file = None
    if path.is_dir():  # the folder reader applies the camera file and the scale itself
        log = ImageFolder(path, ov.camera_file, ov.depth_scale, fps=ov.fps or 30.0, pattern=pattern)
        gravity_file = read_gravity_file(path)
        _note_rate(log, ov.fps, gravity_source(cfg.depth, "config", gravity_file is not None) == "frames")
        ov = Override()
    elif pattern:
        raise KosmapError(f"--glob {pattern} applies to a folder of depth images; {path} is a log")
    elif ov.fps is not None:
        raise KosmapError(f"--fps {ov.fps:g} applies to a folder of depth images; {path} is a log, stamped by itself")
    else:
        log = open_log(path, cfg.topics.on_damage)
    info = log.info()
    det = detect_topics(info.types(), cfg.topics)
    if not det.depth:
        log.close()
        raise LogError(f"{path} has no depth image topic (sensor_msgs/Image with 'depth' in its name); "
                       f"name one with --depth-topic")
    total = sum(len(range(0, info.count(t), every)) for t in det.depth)
    if limit is not None:
        total = min(total, limit)
    wanted = list(det.depth) + [i for i in det.info.values() if i] + ([det.tf_static] if det.tf_static else [])
    if det.imu and not path.is_dir():
        wanted.append(det.imu)
    warnings = log.warnings  # the reader adds to it while reading (e.g. a truncated log)
    if ov.camera_file is not None and any(det.info.values()):
        note(warnings, f"--camera {ov.camera_file} replaces the camera info of "
                       f"{', '.join(i for i in det.info.values() if i)}")
    items = _log_items(path, log, wanted, det, cfg, ov, every, limit, gravity_file, warnings)
    return FrameSource(total, items, warnings)


def _log_items(path: Path, log, wanted: list[str], det, cfg, ov: Override, every: int, limit: int | None,
               gravity_file, warnings: list[str]) -> Generator[Item, None, None]:
    """The log's depth frames as Items (every Nth of each camera, at most `limit`), with the camera infos, the
    mounts in /tf_static and the last half second of IMU samples read on the way; closes the log when done."""
    infos: dict[str, CameraModel] = {}
    statics: list[Transforms] = []
    mounts: dict[str, Transform] = {}
    seen: dict[str, int] = {}
    imu: list[Imu] = []  # the last half second of IMU samples
    done = 0
    try:
        for rec in log.read(wanted):
            if isinstance(rec, Imu):
                imu.append(rec)
                while imu and imu[0].stamp_ns < rec.stamp_ns - 500_000_000:
                    imu.pop(0)
                continue
            if isinstance(rec, Transforms):
                statics.append(rec)
                mounts.clear()
            elif isinstance(rec, CameraModel):
                infos[rec.topic] = rec
            elif isinstance(rec, DepthFrame):
                k = seen.get(rec.topic, 0)  # every Nth frame of each camera
                seen[rec.topic] = k + 1
                if k % every:
                    continue
                if limit is not None and done >= limit:
                    break
                depth = _log_meters(rec, ov, warnings)
                own = ov.camera(depth.shape, rec.frame_id) or infos.get(det.info.get(rec.topic) or "")
                cam = camera_for(depth.shape, own, cfg.depth, rec.frame_id)
                if rec.frame_id not in mounts:
                    mounts[rec.frame_id] = camera_mount(statics, rec.frame_id, cfg.depth)
                mount, src = mounts[rec.frame_id]
                up_imu = imu_gravity(imu, statics, rec.frame_id, warnings)
                grav = gravity_source(cfg.depth, src, gravity_file is not None, up_imu is not None)
                up = {"file": gravity_file[0] if gravity_file else None, "imu": up_imu}.get(grav)
                yield Item(k, rec.stamp_ns, depth, cam, mount, rec.topic, rec.frame_id or "camera", grav, up)
                done += 1
    finally:
        skipped = getattr(log, "not_depth", None)
        if skipped:
            note(warnings, f"{len(skipped)} images of {path} were not depth (8-bit or colour) and were skipped")
        log.close()


def _dataset_depth(s, ov: Override, warnings: list[str]) -> np.ndarray:
    """A dataset frame in metres at the explicit depth scale if any, else at the dataset's own (SOURCES.md)."""
    if ov.depth_scale is None or ov.depth_scale == s.units:
        return s.depth
    if s.units is None:
        note(warnings, f"{ov.scale_from} does not apply to the frames of {s.dataset} stored as disparity or as a "
                       f"point cloud (not in image units); their own decoding is used")
        return s.depth
    note(warnings, f"{ov.scale_from} replaces {s.dataset}'s own depth scale ({s.units:g} image units per metre)")
    return s.depth * np.float32(s.units / ov.depth_scale)


def dataset_frames(samples: Iterable[tuple[int, object]], total: int, cfg, ov: Override) -> FrameSource:
    """Frames of known datasets from their decoded samples (index in the dataset, a sample with depth, units,
    camera, stamp, dataset and name); --camera and --depth-scale replace their own, with a warning."""
    warnings: list[str] = []

    def gen() -> Iterator[Item]:
        for k, s in samples:  # k: the frame's index in its dataset, as a log's frames are numbered before --every
            depth = _dataset_depth(s, ov, warnings)
            own = ov.camera(depth.shape, "camera")
            if own is not None and not np.allclose(own.K, s.camera.K):
                note(warnings, f"--camera {ov.camera_file} replaces the intrinsics of {s.dataset}")
            cam = camera_for(depth.shape, own or s.camera, cfg.depth)
            yield Item(k, int(round(s.stamp * 1e9)), depth, cam, config_mount(cfg.depth, "camera"),
                       f"{s.dataset}/{s.name}", "camera", gravity_source(cfg.depth, "config", False))

    return FrameSource(total, gen(), warnings)


def gravity_source(dcfg, mount_source: str, has_file: bool, has_imu: bool = False) -> str:
    """Where a frame's classes take gravity from ([depth] gravity), in this order: the mount in /tf_static or
    set in the config, the log's IMU on the camera's rigid body, a gravity file, the frames."""
    if dcfg.gravity == "frames":
        return "frames"
    if dcfg.gravity == "mount" or mount_source == "tf_static" or not mount_is_default(dcfg):
        return mount_source
    if has_imu:
        return "imu"
    return "file" if has_file else "frames"


def imu_gravity(imu: list, statics: list, frame_id: str, warnings: list[str]) -> np.ndarray | None:
    """Up in the depth frame from the recent IMU samples, when /tf_static ties the IMU's frame to the depth
    camera's (the same rigid body); None (with a warning, once) when it does not."""
    if not imu:
        return None
    last = imu[-1]
    same = not last.frame_id or last.frame_id.lstrip("/") == frame_id.lstrip("/")
    tf = None if same else lookup_static(statics, frame_id, last.frame_id)
    if tf is None and not same:
        note(warnings, f"the IMU's frame {last.frame_id} is not tied to the depth frame {frame_id} in /tf_static: "
                       f"it is not used for gravity")
        return None
    R = np.eye(3) if tf is None else tf.matrix()[:3, :3]
    has_q = last.orientation_cov[0] != -1 and np.linalg.norm(last.orientation) > 0.5
    return imu_up(np.array([s.linear_acceleration for s in imu]), last.orientation if has_q else None, R)
