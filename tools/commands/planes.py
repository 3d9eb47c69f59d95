"""`kosmap planes LOG|FOLDER --out DIR`: FSPF+ (or FSPF) over every depth frame, with Table 5.2 statistics,
plane points and normals (npz and MCAP), processed depth PNGs and Fig. 5.2-style figures."""

from __future__ import annotations

import csv
import itertools
import json
import os
import re
import shutil
import tempfile
from collections.abc import Generator, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer
from scipy.spatial.transform import Rotation

from kosmap.frontend.camera import (OPTICAL_ROTATION, camera_for, camera_mount, config_mount, gravity_up, lookup_static,
                                    mount_is_default)
from kosmap.frontend.gravity import GravityTracker, drop_classes, floor_height, imu_up, read_gravity_file, reclassify
from kosmap.frontend.mountcal import MountCalibrator
from kosmap.frontend.errors import KosmapError, LogError
from kosmap.frontend.fspf import filter_planes, frame_seed, warmup
from kosmap.frontend.logs.images import camera_model, check_depth_scale, read_camera_file
from kosmap.frontend.planes import Planes
from kosmap.mapping.runtime.outdir import check_out
from kosmap.frontend.records import CameraModel, DepthFrame, Imu, Transform, Transforms
from kosmap.tools import options as O

CLOUD_TOPIC = "/kosmap/planes/points"
NORMALS_TOPIC = "/kosmap/planes/normals"
STATS_COLUMNS = ("frame", "source", "stamp", "ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct",
                 "unexamined_pct", "remaining", "planes", "elapsed_ms")
STAGE_PREFIX = ".kosmap-planes-"  # the hidden folder in --out that a run writes into until it succeeds


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
class Override:
    """What --camera and --depth-scale say, read and checked before any work; None leaves the source's own."""

    camera_file: Path | None = None
    intrinsics: dict | None = None  # fx, fy, cx, cy[, width, height] of the camera file
    depth_scale: float | None = None  # image units per metre: --depth-scale, else the camera file's depth_scale
    scale_from: str = ""  # which option gave depth_scale, for the warnings

    def camera(self, shape: tuple[int, int], frame_id: str) -> CameraModel | None:
        """The camera file's model for an image of `shape`, or None without --camera."""
        return None if self.intrinsics is None else camera_model(self.intrinsics, shape, frame_id, "")


def _override(camera_file: Path | None, depth_scale: float | None) -> Override:
    """Read --camera and check --depth-scale up front: a missing file or a scale ≤ 0 stops the run in one line."""
    depth_scale = check_depth_scale(depth_scale)  # as image units per metre, whichever convention was given
    if camera_file is None:
        return Override(None, None, depth_scale, f"--depth-scale {depth_scale:g}" if depth_scale is not None else "")
    intrinsics, file_scale = read_camera_file(camera_file, default_scale=None)
    if depth_scale is not None:
        return Override(camera_file, intrinsics, depth_scale, f"--depth-scale {depth_scale:g}")
    return Override(camera_file, intrinsics, file_scale,
                    f"depth_scale {file_scale:g} of --camera {camera_file}" if file_scale is not None else "")


def _note(warnings: list[str], text: str) -> None:
    """Add a warning once."""
    if text not in warnings:
        warnings.append(text)


def _log_meters(rec: DepthFrame, ov: Override, warnings: list[str]) -> np.ndarray:
    """A log's depth frame in metres: 16-bit images at the explicit depth scale if any (else millimetres)."""
    if ov.depth_scale is None:
        return rec.meters()
    if rec.encoding != "16UC1":
        _note(warnings, f"{ov.scale_from} does not apply to {rec.topic}, whose {rec.encoding} images are in metres")
        return rec.meters()
    return np.divide(rec.image, np.float32(ov.depth_scale), dtype=np.float32)


def _log_frames(path: Path, cfg, ov: Override, every: int, limit: int | None,
                pattern: str | None = None) -> tuple[int, Generator[Item, None, None], list[str]]:
    """Frames of a log (MCAP, bag) or of a folder of depth images; --camera and --depth-scale replace its own."""
    from kosmap.frontend.logs import detect_topics, open_log
    from kosmap.frontend.logs.images import ImageFolder

    gravity_file = None
    if path.is_dir():  # the folder reader applies the camera file and the scale itself
        log = ImageFolder(path, ov.camera_file, ov.depth_scale, pattern=pattern)
        ov = Override()
        gravity_file = read_gravity_file(path)
    elif pattern:
        raise KosmapError(f"--glob {pattern} applies to a folder of depth images; {path} is a log")
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
        _note(warnings, f"--camera {ov.camera_file} replaces the camera info of "
                        f"{', '.join(i for i in det.info.values() if i)}")

    def gen() -> Iterator[Item]:
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
                    up_imu = _imu_gravity(imu, statics, rec.frame_id, warnings)
                    grav = gravity_source(cfg.depth, src, gravity_file is not None, up_imu is not None)
                    up = {"file": gravity_file[0] if gravity_file else None, "imu": up_imu}.get(grav)
                    yield Item(k, rec.stamp_ns, depth, cam, mount, rec.topic, rec.frame_id or "camera", grav, up)
                    done += 1
        finally:
            skipped = getattr(log, "not_depth", None)
            if skipped:
                _note(warnings, f"{len(skipped)} images of {path} were not depth (8-bit or colour) and were skipped")
            log.close()

    return total, gen(), warnings


def _dataset_depth(s, ov: Override, warnings: list[str]) -> np.ndarray:
    """A dataset frame in metres at the explicit depth scale if any, else at the dataset's own (SOURCES.md)."""
    if ov.depth_scale is None or ov.depth_scale == s.units:
        return s.depth
    if s.units is None:
        _note(warnings, f"{ov.scale_from} does not apply to the frames of {s.dataset} stored as disparity or as a "
                        f"point cloud (not in image units); their own decoding is used")
        return s.depth
    _note(warnings, f"{ov.scale_from} replaces {s.dataset}'s own depth scale ({s.units:g} image units per metre)")
    return s.depth * np.float32(s.units / ov.depth_scale)


def _dataset_frames(folders: list[Path], cfg, ov: Override, every: int,
                    limit: int | None) -> tuple[int, Generator[Item, None, None], list[str]]:
    """Frames of the known datasets (tools.datasets); --camera and --depth-scale replace their own, with a warning."""
    from kosmap.tools.datasets import iter_dataset

    total = sum(sum(1 for _ in _names(f, every, limit)) for f in folders)
    warnings: list[str] = []

    def gen() -> Iterator[Item]:
        for f in folders:
            for j, s in enumerate(iter_dataset(f, limit, every)):
                k = j * every  # the frame's index in its dataset, as a log's frames are numbered before --every
                depth = _dataset_depth(s, ov, warnings)
                own = ov.camera(depth.shape, "camera")
                if own is not None and not np.allclose(own.K, s.camera.K):
                    _note(warnings, f"--camera {ov.camera_file} replaces the intrinsics of {s.dataset}")
                cam = camera_for(depth.shape, own or s.camera, cfg.depth)
                yield Item(k, int(round(s.stamp * 1e9)), depth, cam, config_mount(cfg.depth, "camera"),
                           f"{s.dataset}/{s.name}", "camera", gravity_source(cfg.depth, "config", False))

    return total, gen(), warnings


def _names(folder: Path, every: int, limit: int | None) -> list[str]:
    """The frame names of a dataset folder without decoding them (for the progress bar)."""
    n = folder.name
    if n == "tum_fr1_xyz":
        names = [ln for ln in (folder / "depth_included.txt").read_text().splitlines() if ln.strip()]
    elif n == "open3d_rgbd_formats":
        names = ["TUM", "SUN", "NYU"]
    elif n == "slambook2_ch5_rgbd":
        names = [p.name for p in (folder / "depth").glob("*.pgm")]
    elif n == "cape_tunnel_frame":
        names = ["depth_0"]
    else:
        names = [p.name for p in folder.glob("*.pcd")]
    return names[::every][:limit]


def normal_quaternions(normals: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) turning the x axis onto each normal (arrows in Foxglove's PoseArray)."""
    n = np.asarray(normals, float)
    q = np.column_stack((np.zeros(len(n)), -n[:, 2], n[:, 1], 1.0 + n[:, 0]))
    bad = q[:, 3] < 1e-9  # normal along −x: half a turn about z
    q[bad] = [0.0, 0.0, 1.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _save_npz(path: Path, planes: Planes, item: Item) -> None:
    np.savez_compressed(path, points=planes.points, plane=planes.plane.astype(np.int32),
                        pixels=planes.pixels.astype(np.uint16), normals=planes.normals, offsets=planes.offsets,
                        classes=planes.classes, counts=planes.counts, stamp_ns=np.int64(item.stamp_ns),
                        shape=np.array(planes.shape), frame_id=np.array(item.frame_id), source=np.array(item.source),
                        K=item.camera.K, mount=item.mount.matrix())


def _write_mcap(writer, planes: Planes, item: Item, max_points: int, seed: int) -> None:
    from kosmap.frontend.logs import convert

    p, idx = planes.points, planes.plane
    if len(p) > max_points:
        sel = np.sort(np.random.default_rng(seed).choice(len(p), max_points, replace=False))
        p, idx = p[sel], idx[sel]
    cls = planes.classes[idx] if len(idx) else np.zeros(0)
    t = item.stamp_ns
    writer.write_pointcloud(CLOUD_TOPIC, t, item.frame_id, p,
                            {"plane": idx.astype(np.float32), "class": cls.astype(np.float32), "depth": p[:, 2]})
    centroids = np.zeros((len(planes), 3))
    if len(planes):
        for k in range(3):
            centroids[:, k] = np.bincount(planes.plane, planes.points[:, k], minlength=len(planes))
        centroids /= np.maximum(planes.counts, 1)[:, None]
    msg = convert.pose_array_msg(writer.ts, t, item.frame_id, centroids, normal_quaternions(planes.normals))
    writer.write_msg(NORMALS_TOPIC, "geometry_msgs/msg/PoseArray", msg, t)


GRAVITY_WORDS = {"tf_static": "the mount in /tf_static", "config": "the [depth] mount_xyz / mount_rpy_deg",
                 "file": "the folder's gravity file", "imu": "the log's IMU (on the depth camera's rigid body)",
                 "frames": "the frames (the dominant level plane family, tracked over the sequence)"}


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


def _imu_gravity(imu: list, statics: list, frame_id: str, warnings: list[str]) -> np.ndarray | None:
    """Up in the depth frame from the recent IMU samples, when /tf_static ties the IMU's frame to the depth
    camera's (the same rigid body); None (with a warning, once) when it does not."""
    if not imu:
        return None
    last = imu[-1]
    same = not last.frame_id or last.frame_id.lstrip("/") == frame_id.lstrip("/")
    tf = None if same else lookup_static(statics, frame_id, last.frame_id)
    if tf is None and not same:
        _note(warnings, f"the IMU's frame {last.frame_id} is not tied to the depth frame {frame_id} in /tf_static: "
                        f"it is not used for gravity")
        return None
    R = np.eye(3) if tf is None else tf.matrix()[:3, :3]
    has_q = last.orientation_cov[0] != -1 and np.linalg.norm(last.orientation) > 0.5
    return imu_up(np.array([s.linear_acceleration for s in imu]), last.orientation if has_q else None, R)


def no_eligible_cause(depth_m: np.ndarray, min_depth: float, max_depth: float) -> str:
    """Why a frame has no pixel within [min_depth, max_depth]: the likely cause, in one sentence."""
    d = np.asarray(depth_m, np.float64)
    valid = d[np.isfinite(d) & (d > 0)]
    if not valid.size:
        return "it holds no depth at all (every pixel 0 or NaN)"
    med = float(np.median(valid))
    if med > max_depth:
        return (f"its median depth reads {med:.3g} m, beyond [depth] max_depth {max_depth:g} m: the depth scale is "
                f"likely too small (--depth-scale is image units per metre, or below 1 metres per unit)")
    return (f"its median depth reads {med:.3g} m, nearer than [depth] min_depth {min_depth:g} m: the depth scale is "
            f"likely too large (an image already in metres read as millimetres?), or lower depth.min_depth")


def _shares(planes: Planes) -> dict:
    """The frame's Table 5.2 columns plus the share never examined, so that the five shares add up to 100 %."""
    return {**planes.stats.row(), "unexamined_pct": planes.stats.unexamined_pct}


def _summary_row(rows: list[dict]) -> dict:
    out: dict = {"frame": "summary", "source": f"{len(rows)} frames", "stamp": ""}
    for c in STATS_COLUMNS[3:]:
        vals = np.array([r[c] for r in rows], float)
        out[c] = float(vals.mean()) if len(vals) else 0.0
    return out


def _check_args(path: Path, every: int, limit: int | None, figures: int) -> None:
    """Refuse a missing input and nonsense counts before anything is read or written."""
    if not path.exists():
        raise KosmapError(f"{path} does not exist; give a log (.mcap, .bag), a folder of depth images, or a dataset folder")
    if every < 1:
        raise KosmapError(f"--every {every} must be at least 1")
    if limit is not None and limit < 1:
        raise KosmapError(f"--max-frames {limit} must be at least 1; leave it out to filter every frame")
    if figures < 0:
        raise KosmapError(f"--figures {figures} must be 0 or more")


def _first_frame(path: Path, frames: Iterator[Item]) -> Iterator[Item]:
    """Read the first frame before writing anything (an unreadable first image or no frame at all fails here)."""
    first = next(frames, None)
    if first is None:
        raise KosmapError(f"{path} yielded no depth frames; check --every/--max-frames and the depth topic")
    return itertools.chain([first], frames)


def _stage(out: Path) -> tuple[Path, Path | None]:
    """A fresh hidden folder in `out` for this run's files, and the outermost folder this call created (if any)."""
    made = None
    p = out.absolute()
    while not p.exists():
        made, p = p, p.parent
    try:
        out.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=STAGE_PREFIX, suffix=".partial", dir=out)), made
    except OSError as e:
        raise KosmapError(f"--out {out}: cannot write there ({e.strerror}); give another folder") from e


def _commit(stage: Path, out: Path) -> None:
    """Move the run's files into `out`, replacing a previous run's of the same name; summary.json goes last. In the
    per-frame folders (planes/, depth/, figures/) a previous run's frames this run did not write go too: a longer
    run's 000002.npz must not sit beside a summary of one frame."""
    for p in sorted(stage.iterdir(), key=lambda p: (p.name == "summary.json", p.name)):
        dest = out / p.name
        if p.is_dir() and dest.is_dir():
            new = {q.name for q in p.iterdir()}
            for old in dest.iterdir():
                if old.name not in new and re.fullmatch(r"\d{6}\.(npz|png)", old.name) and old.is_file():
                    old.unlink()
            for q in p.iterdir():
                os.replace(q, dest / q.name)
        else:
            os.replace(p, dest)
    shutil.rmtree(stage)


def _discard(stage: Path, out: Path, made: Path | None) -> None:
    """Remove what a failed run wrote: its hidden folder, and the folders it created for `out` (if left empty)."""
    shutil.rmtree(stage, ignore_errors=True)
    if made is None:
        return
    p = out.absolute()
    while True:
        try:
            p.rmdir()  # only an empty folder: files the user put there meanwhile stay
        except OSError:
            return
        if p == made:
            return
        p = p.parent


def run_planes(path: Path, out: Path, cfg, *, camera_file: Path | None = None, depth_scale: float | None = None,
               save_depth: bool = False, figures: int = 3, every: int = 1, limit: int | None = None,
               mcap: bool = True, npz: bool = True, mcap_points: int = 30000, progress: bool = True,
               pattern: str | None = None) -> dict:
    """Filter every frame of `path` into `out`; returns the summary (also written as summary.json).

    Options, the camera file, `out` and the first frame are checked before anything is written; the outputs go
    to a hidden folder in `out` and are moved into place only when the run succeeds, so a failure leaves none."""
    from kosmap.tools.datasets import detect

    _check_args(path, every, limit, figures)
    ov = _override(camera_file, depth_scale)
    check_out(out)
    folders = detect(path) if path.is_dir() and not pattern else []
    if folders:
        total, frames, warnings = _dataset_frames(folders, cfg, ov, every, limit)
    else:
        total, frames, warnings = _log_frames(path, cfg, ov, every, limit, pattern)
    stage, made = None, None
    try:
        checked = _first_frame(path, frames)
        stage, made = _stage(out)
        summary = _filter_frames(path, stage, cfg, total, checked, warnings, save_depth=save_depth, figures=figures,
                                 mcap=mcap, npz=npz, mcap_points=mcap_points, progress=progress)
        _commit(stage, out)
    except BaseException:
        frames.close()  # the log reader, if the frames stopped early
        if stage is not None:
            _discard(stage, out, made)
        raise
    return summary


def _classes(planes: Planes, item: Item, cfg, tracker: GravityTracker, calibrator: MountCalibrator) -> Planes:
    """The frame's plane classes from its gravity source, then its dropped classes removed; a mount's frames also
    feed the mount calibration (their floor planes)."""
    if item.gravity == "frames":
        up = tracker.update(planes)
        return reclassify(planes, up, tracker.height, cfg.fspf)
    if item.gravity in ("file", "imu"):
        h = floor_height(planes.normals, planes.offsets, planes.counts, item.up)
        tracker.height = h if np.isfinite(h) else tracker.height
        return reclassify(planes, item.up, tracker.height, cfg.fspf)
    calibrator.add(planes.normals, planes.offsets, planes.counts, gravity_up(item.mount))
    return drop_classes(planes, cfg.fspf)


def _mount_estimate(calibrator: MountCalibrator, first: tuple[Transform, str] | None, cfg,
                    warnings: list[str]) -> dict | None:
    """The mount seen from the floor planes beside the given one (a warning when they differ by > 1° or 2 cm),
    with the [depth] lines and a /tf_static command that set it."""
    if first is None:
        return None
    mount, src = first
    est = calibrator.estimate(gravity_up(mount), float(mount.translation[2]), src)
    if est is None:
        return None
    # x, y and yaw (not seen from the floor) stay the given mount's: camera_link ← base_link of its rotation
    xyz = [float(v) for v in mount.translation]
    link = mount.matrix()[:3, :3] @ OPTICAL_ROTATION.T
    rpy = [float(v) for v in np.degrees(Rotation.from_matrix(link).as_euler("xyz"))]
    if est.differs:
        _note(warnings, f"the floor planes of {est.frames} frames put the depth camera at pitch {est.pitch_deg:.2f}°, "
                        f"roll {est.roll_deg:.2f}°, {est.height_m:.3f} m above the floor; the mount from "
                        f"{GRAVITY_WORDS[src]} says pitch {est.given_pitch_deg:.2f}°, roll {est.given_roll_deg:.2f}°, "
                        f"{est.given_height_m:.3f} m (more than 1° or 2 cm apart): see mount.toml")
    return est.as_dict() | {"given_xyz": xyz, "given_yaw_deg": rpy[2], "config": est.config_lines(xyz, rpy),
                            "tf_static": est.tf_static_command(xyz, rpy[2])}


def estimate_mount(path: Path, cfg, frames: int = 30) -> tuple[dict | None, int]:
    """The depth camera's mount from the floor planes of ≤ `frames` frames spread over the log (nothing written):
    (the estimate as in summary.json's mount_estimate, or None without a floor; the frames read)."""
    given = replace(cfg.depth, mount="given")
    probe = replace(cfg, depth=given)
    total, items, warnings = _log_frames(path, probe, Override(), 1, None)
    every = max(1, total // frames)
    items.close()
    total, items, warnings = _log_frames(path, probe, Override(), every, frames)
    keep_all = replace(cfg.fspf, drop_classes=[])
    calibrator, first, n = MountCalibrator(), None, 0
    try:
        for item in items:
            planes = filter_planes(item.depth, item.camera, keep_all, given, item.mount,
                                   seed=frame_seed(cfg.fspf, item.index))
            calibrator.add(planes.normals, planes.offsets, planes.counts, gravity_up(item.mount))
            first = first or (item.mount, "tf_static" if item.gravity == "tf_static" else "config")
            n += 1
    finally:
        items.close()
    return _mount_estimate(calibrator, first, probe, warnings), n


def _filter_frames(path: Path, out: Path, cfg, total: int, frames: Iterator[Item], warnings: list[str], *,
                   save_depth: bool, figures: int, mcap: bool, npz: bool, mcap_points: int, progress: bool) -> dict:
    """Filter the frames and write every output into `out` (the run's hidden folder); returns the summary."""
    from kosmap.mapping.config import write_config

    write_config(cfg, out / "config.toml")
    warmup(cfg.fspf.method)
    fig_step = max(1, -(-total // figures)) if figures > 0 else 0
    writer = None
    if mcap:
        from kosmap.frontend.logs.writer import McapWriter

        writer = McapWriter(out / "planes.mcap")
    rows: list[dict] = []
    keep_all = replace(cfg.fspf, drop_classes=[])  # classes are settled after the filter (gravity), then dropped
    tracker, calibrator, gravity_used = GravityTracker(), MountCalibrator(), {}
    first_mount: tuple[Transform, str] | None = None
    empty = 0  # frames without an eligible pixel
    mounts_written: set[str] = set()
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    bar = Progress(TextColumn("planes"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                   TextColumn("{task.fields[ms]}"), disable=not progress, transient=False)
    try:
        with bar:
            task = bar.add_task("planes", total=total, ms="")
            for n, item in enumerate(frames):
                if n == 0:
                    warmup(cfg.fspf.method, item.depth.shape)  # elapsed_ms: no compiling, no first touch of buffers
                    first_mount = (item.mount, item.gravity)
                planes = filter_planes(item.depth, item.camera, keep_all, cfg.depth, item.mount,
                                       seed=frame_seed(cfg.fspf, item.index))
                planes = _classes(planes, item, cfg, tracker, calibrator)
                gravity_used[item.gravity] = gravity_used.get(item.gravity, 0) + 1
                name = f"{n:06d}"
                if planes.stats.eligible == 0:
                    empty += 1
                    if empty == 1:
                        _note(warnings, f"frame {name} ({item.source}) has no eligible pixel: "
                                        + no_eligible_cause(item.depth, cfg.depth.min_depth, cfg.depth.max_depth))
                row = {"frame": name, "source": item.source, "stamp": f"{item.stamp_ns * 1e-9:.6f}", **_shares(planes)}
                rows.append(row)
                if npz:
                    (out / "planes").mkdir(exist_ok=True)
                    _save_npz(out / "planes" / f"{name}.npz", planes, item)
                if save_depth:
                    import cv2

                    (out / "depth").mkdir(exist_ok=True)
                    mm = np.clip(np.round(planes.depth_image() * 1000.0), 0, 65535).astype(np.uint16)
                    cv2.imwrite(str(out / "depth" / f"{name}.png"), mm)
                if fig_step and n % fig_step == 0:
                    from kosmap.tools.plane_figures import plane_figure

                    plane_figure(planes, out / "figures" / f"{name}.png", f"{item.source}",
                                 (cfg.depth.min_depth, cfg.depth.max_depth))
                if writer is not None:
                    if item.frame_id not in mounts_written:
                        tf = Transform(item.mount.parent, item.frame_id, item.mount.translation, item.mount.rotation,
                                       item.stamp_ns)
                        writer.write(Transforms(item.stamp_ns, (tf,), True, "/tf_static"))
                        mounts_written.add(item.frame_id)
                    _write_mcap(writer, planes, item, mcap_points, n)
                bar.update(task, advance=1, ms=f"{planes.stats.elapsed_ms:.1f} ms")
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    if writer is not None:
        writer.close()
    if empty > 1:
        _note(warnings, f"{empty} of {len(rows)} frames had no eligible pixel")
    summary_row = _summary_row(rows)
    with open(out / "stats.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=STATS_COLUMNS)
        w.writeheader()
        for r in rows + [summary_row]:
            w.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()})
    ms = np.array([r["elapsed_ms"] for r in rows])
    mount_est = _mount_estimate(calibrator, first_mount, cfg, warnings)
    summary = {"input": str(path), "method": cfg.fspf.method, "backend": cfg.fspf.backend, "frames": len(rows),
               "median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
               **{k: summary_row[k] for k in STATS_COLUMNS[3:]},
               "gravity": {k: {"frames": v, "from": GRAVITY_WORDS[k]} for k, v in gravity_used.items()},
               "mount_estimate": mount_est, "warnings": list(warnings)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if mount_est is not None:
        (out / "mount.toml").write_text(f"# the depth camera's mount as the floor planes of {path.name} show it\n"
                                        f"# on /tf_static: {mount_est['tf_static']}\n{mount_est['config']}")
    return summary


def register(app: typer.Typer) -> None:
    @app.command()
    def planes(
        source: Annotated[Path, typer.Argument(help="Log (.mcap, .bag), a folder of depth PNGs with a camera file, "
                                                     "or a folder of ../shared/data/depth datasets.")],
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder.")],
        method: Annotated[Optional[str], typer.Option("--method", help="fspf+ (thesis, default) or fspf (Biswas).")] = None,
        save_depth: Annotated[bool, typer.Option("--save-depth", help="Write the processed depth (plane points only) as 16-bit PNG (mm).")] = False,
        camera: Annotated[Optional[Path], typer.Option("--camera", help="Camera file (YAML/JSON: fx, fy, cx, cy[, depth_scale]); replaces the intrinsics of the folder, dataset or log.")] = None,
        depth_scale: Annotated[Optional[float], typer.Option("--depth-scale", help="Scale of 16-bit depth, either convention: 1 or more is image units per metre (1000 = mm, 5000 = TUM), below 1 metres per unit (0.001 = mm, RealSense); overrides the camera file and the dataset's own.")] = None,
        glob: Annotated[Optional[str], typer.Option("--glob", help="The depth images of a folder, by pattern (e.g. '*_depth.png'); without it images named rgb, color, label, mask or seg and 8-bit or colour images are skipped and counted.")] = None,
        figures: Annotated[int, typer.Option("--figures", help="How many frames get a Fig. 5.2-style figure (spread over the run).")] = 3,
        every: Annotated[int, typer.Option("--every", help="Process every Nth depth frame.")] = 1,
        max_frames: Annotated[Optional[int], typer.Option("--max-frames", help="Stop after this many frames.")] = None,
        seed: Annotated[Optional[int], typer.Option("--seed", help="Random seed: frame i (its index in the log or folder, counted before --every and --max-frames) uses seed + i, so a frame's planes are the same whatever --every; the same seed, the same planes.")] = None,
        no_mcap: Annotated[bool, typer.Option("--no-mcap", help="Do not write planes.mcap.")] = False,
        no_npz: Annotated[bool, typer.Option("--no-npz", help="Do not write planes/NNNNNN.npz.")] = False,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, depth_topic: O.DepthTopicOpt = None,
        info_topic: O.InfoTopicOpt = None,
    ) -> None:
        """Plane filtering (FSPF+ or FSPF) of every depth frame: stats.csv (thesis Table 5.2), planes, figures."""
        sets = list(set_ or [])
        if method is not None:
            if method not in ("fspf+", "fspf"):
                raise KosmapError(f"--method {method} is not fspf+ or fspf")
            sets.append(f'fspf.method="{method}"')
        if seed is not None:
            sets.append(f"fspf.seed={seed}")
        cfg = O.make_config(config, sets, depth_topic, info_topic)
        s = run_planes(source, out, cfg, camera_file=camera, depth_scale=depth_scale, save_depth=save_depth,
                       figures=figures, every=every, limit=max_frames, mcap=not no_mcap, npz=not no_npz, pattern=glob)
        for g in s["gravity"].values():
            print(f"gravity: {g['from']} ({g['frames']} frames)")
        m = s["mount_estimate"]
        if m is not None:
            print(f"mount from the floor ({m['frames']} frames): pitch {m['pitch_deg']:.2f}°, roll {m['roll_deg']:.2f}°, "
                  f"height {m['height_m']:.3f} m; given: pitch {m['given_pitch_deg']:.2f}°, roll {m['given_roll_deg']:.2f}°, "
                  f"height {m['given_height_m']:.3f} m ({out}/mount.toml)")
        print(f"{s['frames']} frames, {s['method']} ({s['backend']}): median {s['median_ms']:.2f} ms, p90 {s['p90_ms']:.2f} ms "
              f"per frame; of the pixels: ineligible {s['ineligible_pct']:.1f} %, inliers {s['inlier_pct']:.1f} %, "
              f"dropped {s['dropped_pct']:.1f} %, outliers {s['outlier_pct']:.1f} %, "
              f"not examined {s['unexamined_pct']:.1f} %; {s['planes']:.1f} planes per frame")
        for w in s["warnings"]:
            print(f"warning: {w}")
        print(f"wrote {out}/stats.csv, config.toml, summary.json" + ("" if no_npz else ", planes/")
              + ("" if no_mcap else ", planes.mcap") + (", depth/" if save_depth else "") + (", figures/" if figures else "") + (", mount.toml" if m is not None else ""))
