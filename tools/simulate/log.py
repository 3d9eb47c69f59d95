"""Write a simulated robot log: the robot drives the path, every sensor fires at its own rate, MCAP out.

Topics as kinect2_bridge, hokuyo_node and a wheel base name theirs (docs/design.md): depth images (16UC1 mm)
with CameraInfo per camera, /scan, /odom (odom → base_link, drifting), the true pose on /ground_truth/odom
(map → base_link, 100 Hz), a MEMS IMU on /imu (sensor_msgs/Imu, 200 Hz, frame imu_link: an identity mount
on base_link) and /tf_static for the mounts; optionally each depth frame's surface ids. The effective settings
and the truths a calibration should recover (odometry scale, gyro bias) are written as MCAP metadata
"kosmap.simulation" (read them with `simulation_truth(log)`).
Every random draw comes from a stream seeded by (seed, stream), consumed in a fixed order, and the MCAP
writer records no wall-clock time, so the same seed gives a byte-identical file.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.records import DepthFrame, Imu, Odometry, Scan, Transform, Transforms
from kosmap.tools.simulate.config import SimConfig
from kosmap.tools.simulate.imu import ImuStream, imu_stream, imu_truth
from kosmap.tools.simulate.motion import Trajectory, check_path, odometry, plan, wrap
from kosmap.tools.simulate.render import pose_matrix, render_depth_geometry, render_laser_geometry
from kosmap.tools.simulate.sensors import apply_laser_noise, depth_noise_mm
from kosmap.tools.simulate.world import PathSpec, World, WorldError

# phase of each stream within its period (s), so that streams interleave as in a real log
_PHASE = {"gt": 0.0, "odom": 0.001, "depth": 0.004, "scan": 0.009, "imu": 0.002}
_DEPTH, _SCAN, _ODOM, _GT, _IMU = 0, 1, 2, 3, 4
METADATA = "kosmap.simulation"  # MCAP metadata record: {"config": JSON, "truth": JSON}


def trajectory(world: World, cfg: SimConfig, path: PathSpec | None = None) -> Trajectory:
    """The robot's true motion for this world, path and config (checked against the world)."""
    path = path if path is not None else world.path
    if path is None:
        raise WorldError(f"world {world.name} has no bundled path; give one with --path")
    check_path(world, path, cfg.robot_radius)
    return plan(path, cfg.speed_min, cfg.speed_max, cfg.accel, math.radians(cfg.turn_rate_deg),
                math.radians(cfg.turn_accel_deg), np.random.default_rng([cfg.seed, 0]))


def check_sensors(world: World, cfg: SimConfig, traj: Trajectory, duration: float) -> None:
    """Refuse mounts that put a sensor outside the building, below the floor, above the ceiling or inside a
    solid anywhere along the trajectory."""
    poses = traj.pose(np.arange(0.0, duration + 0.05, 0.1))
    sensors = [(f"camera {ns}", key, m) for (ns, m), key in zip(cfg.cameras(), cfg.camera_settings())]
    if cfg.laser:
        sensors.append(("laser", "laser_xyz", cfg.laser_mount()))
    for name, key, mount in sensors:
        off = mount.translation
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        pts = np.column_stack((poses[:, 0] + c * off[0] - s * off[1], poses[:, 1] + s * off[0] + c * off[1],
                               np.full(len(poses), off[2])))
        bad = ~world.inside_bounds(pts[:, :2]) | (pts[:, 2] <= 0) | (pts[:, 2] >= world.wall_height)
        where = "outside the world"
        if not bad.any():
            inside = world.solid_at(pts)
            hits = [k for k, sol in enumerate(inside) if sol is not None]
            if hits:
                bad[hits[0]] = True
                where = f"inside {inside[hits[0]].name}"
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            x0, y0, x1, y1 = world.bounds
            raise WorldError(f"the {name} would be {where} at ({pts[k, 0]:.2f}, {pts[k, 1]:.2f}, {pts[k, 2]:.2f}) at "
                             f"t = {k * 0.1:.1f} s (world {x0:.1f}..{x1:.1f} × {y0:.1f}..{y1:.1f} m, height "
                             f"{world.wall_height} m); check {key}")


def _stamps(rate: float, phase: str, duration: float) -> np.ndarray:
    period = 1.0 / rate
    t = np.arange(_PHASE[phase] * min(period, 1.0), duration + 1e-9, period)
    return t[t <= duration + 1e-9]


def _streams(cfg: SimConfig, duration: float, imu: ImuStream | None) -> dict[int, np.ndarray]:
    """Each stream's message times (s since the start); the IMU's without the samples inside its gaps."""
    streams = {_DEPTH: _stamps(cfg.depth_rate, "depth", duration), _ODOM: _stamps(cfg.odom_rate, "odom", duration),
               _GT: _stamps(cfg.gt_rate, "gt", duration)}
    if cfg.laser:
        streams[_SCAN] = _stamps(cfg.laser_rate, "scan", duration)
    if imu is not None:
        streams[_IMU] = imu.t[imu.keep]
    return streams


def _events(streams: dict[int, np.ndarray]) -> list[tuple[int, int]]:
    """(stream, index) of every message in time order; ties by stream, then index."""
    ev_t = np.concatenate([np.round(streams[k] * 1e9).astype(np.int64) for k in streams])
    ev_kind = np.concatenate([np.full(len(streams[k]), k) for k in streams])
    ev_idx = np.concatenate([np.arange(len(streams[k])) for k in streams])
    order = np.lexsort((ev_idx, ev_kind, ev_t))
    return list(zip(ev_kind[order].tolist(), ev_idx[order].tolist()))


class _Sensors:
    """Renders and writes one message of a stream at a time, counting messages and timing the stages."""

    def __init__(self, world: World, cfg: SimConfig, traj: Trajectory, writer: McapWriter,
                 odom_poses: np.ndarray, gt_poses: np.ndarray, imu: ImuStream | None):
        self.world, self.cfg, self.traj, self.writer = world, cfg, traj, writer
        self.odom_poses, self.gt_poses, self.imu = odom_poses, gt_poses, imu
        self.counts: dict[str, int] = {}
        self.timing = {"render_depth": 0.0, "depth_noise": 0.0, "render_laser": 0.0, "write": 0.0}
        self.cameras = cfg.cameras()
        self.models = [cfg.camera_model(m.child) for _, m in self.cameras]
        self.depth_noise = cfg.depth_noise()
        self.depth_rngs = [np.random.default_rng([cfg.seed, 1, i]) for i in range(len(self.cameras))]
        self.laser_mount, self.laser_model, self.laser_noise = cfg.laser_mount(), cfg.laser_model(), cfg.laser_noise()
        self.laser_rng = np.random.default_rng([cfg.seed, 2])
        self.beam_dt = self.laser_model.scan_time * self.laser_model.angle_increment / (2 * math.pi)
        imu_noise = cfg.imu_noise()
        self.imu_cov = (np.diag([imu_noise.gyro_sigma ** 2] * 3).reshape(9),
                        np.diag([imu_noise.accel_sigma ** 2] * 3).reshape(9),
                        np.array([-1.0] + [0.0] * 8))  # orientation not provided (a raw MEMS stream)
        self.imu_rows = np.flatnonzero(imu.keep) if imu is not None else None
        # the IMU on the front camera: the base's rates and specific force turned into its optical frame (the lever
        # arm's centripetal term, ω²·r ≈ 0.01 m/s² for a camera 0.1 m off the turning axis, is left out)
        self.imu_rot = self.cameras[0][1].matrix()[:3, :3].T if cfg.imu_on_camera else None
        self.imu_frame = self.cameras[0][1].child if cfg.imu_on_camera else cfg.imu_frame

    def put(self, rec, topic: str) -> None:
        t = time.thread_time()
        self.writer.write(rec, topic)
        self.timing["write"] += time.thread_time() - t
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def mounts(self, t0_ns: int) -> None:
        """/tf_static with every sensor's mount (if the config asks for it)."""
        cfg = self.cfg
        mounts = tuple(dataclasses.replace(m, stamp_ns=t0_ns) for _, m in self.cameras)
        if cfg.laser:
            mounts += (dataclasses.replace(self.laser_mount, stamp_ns=t0_ns),)
        if cfg.imu and not cfg.imu_on_camera:
            mounts += (dataclasses.replace(Transform.identity("base_link", cfg.imu_frame), stamp_ns=t0_ns),)
        if cfg.tf_static:
            self.put(Transforms(t0_ns, mounts, True, "/tf_static"), "/tf_static")

    def emit(self, kind: int, i: int, t: float, stamp: int) -> None:
        cfg = self.cfg
        if kind == _IMU:
            k = self.imu_rows[i]
            gyro, accel = self.imu.gyro[k], self.imu.accel[k]
            if self.imu_rot is not None:
                gyro, accel = self.imu_rot @ gyro, self.imu_rot @ accel
            g_cov, a_cov, o_cov = self.imu_cov
            self.put(Imu(stamp, gyro, accel, np.array([0.0, 0.0, 0.0, 1.0]), o_cov, g_cov, a_cov, self.imu_frame),
                     cfg.imu_topic)
        elif kind == _GT:
            x, y, yaw = self.gt_poses[i]
            self.put(Odometry(stamp, float(x), float(y), float(yaw), "map", "base_link"), cfg.gt_topic)
        elif kind == _ODOM:
            x, y, yaw = self.odom_poses[i]
            self.put(Odometry(stamp, float(x), float(y), float(yaw), "odom", "base_link"), cfg.odom_topic)
        elif kind == _SCAN:
            self.scan(t, stamp)
        else:
            self.depth(t, stamp)

    def scan(self, t: float, stamp: int) -> None:
        """One laser scan, each beam cast from the pose at its own time."""
        model, tt = self.laser_model, time.thread_time()
        beam_t = t + np.arange(model.beams) * self.beam_dt if self.beam_dt > 0 else np.array([t])
        r, _, cs = render_laser_geometry(self.world, self.traj.pose(beam_t), self.laser_mount, model)
        ranges = apply_laser_noise(r, cs, self.laser_noise, model.range_min, model.range_max, self.laser_rng)
        self.timing["render_laser"] += time.thread_time() - tt
        self.put(Scan(stamp, ranges, model.angle_min, model.angle_increment, model.range_min, model.range_max,
                      self.laser_mount.child, time_increment=self.beam_dt, scan_time=1.0 / self.cfg.laser_rate),
                 self.cfg.scan_topic)

    def depth(self, t: float, stamp: int) -> None:
        """One depth frame (and its CameraInfo, and optionally its surface ids) per camera."""
        pose = self.traj.pose(t)[0]
        for (cam_ns, mount), model, rng in zip(self.cameras, self.models, self.depth_rngs):
            tt = time.thread_time()
            z, sid, cs = render_depth_geometry(self.world, pose, mount, model, self.depth_noise.max_range)
            t1 = time.thread_time()
            _, sid, mm = depth_noise_mm(z, sid, cs, self.depth_noise, rng)
            self.timing["render_depth"] += t1 - tt
            self.timing["depth_noise"] += time.thread_time() - t1
            self.put(dataclasses.replace(model, stamp_ns=stamp), f"{cam_ns}/camera_info")
            self.put(DepthFrame(stamp, np.ascontiguousarray(mm), "16UC1", mount.child), f"{cam_ns}/image_depth_rect")
            if self.cfg.surface_ids:
                self.put(DepthFrame(stamp, np.ascontiguousarray(sid), "16UC1", mount.child), f"{cam_ns}/surface_id")


def simulate(world: World, config: SimConfig, out_path: str | Path, path: PathSpec | None = None,
             progress: Callable[[float, float], None] | None = None) -> dict:
    """Simulate the robot on `path` (default: the world's own) and write an MCAP log; returns a summary.

    Bad parameters raise a KosmapError before any file is opened; an error while writing leaves no file.
    """
    cfg = config
    out = Path(out_path)
    if out.suffix != ".mcap":
        raise WorldError(f"output {out} must end in .mcap (the simulator writes MCAP)")
    traj = trajectory(world, cfg, path)
    duration = cfg.duration if cfg.duration > 0 else traj.duration
    check_sensors(world, cfg, traj, duration)
    t0_ns = int(round(cfg.start_time * 1e9))
    imu_noise = cfg.imu_noise()
    imu = None
    if cfg.imu:
        imu = imu_stream(traj, _stamps(cfg.imu_rate, "imu", duration), imu_noise, np.random.default_rng([cfg.seed, 4]),
                         cfg.imu_gaps, cfg.imu_stuck)
    streams = _streams(cfg, duration, imu)
    odom_true = traj.pose(streams[_ODOM])
    odom_noise = cfg.odometry_noise()
    odom_poses = odometry(odom_true, odom_noise, np.random.default_rng([cfg.seed, 3]))
    truth = {"odometry": odom_noise.truth(), "imu": imu_truth(imu, imu_noise) if imu is not None else None}
    wall0, cpu0 = time.perf_counter(), time.thread_time()
    with McapWriter(out, compression=cfg.compression) as w:
        sensors = _Sensors(world, cfg, traj, w, odom_poses, traj.pose(streams[_GT]), imu)
        sensors.mounts(t0_ns)
        w.write_metadata(METADATA, {"config": json.dumps(dataclasses.asdict(cfg), sort_keys=True),
                                    "truth": json.dumps(truth, sort_keys=True)})
        for kind, i in _events(streams):
            t = float(streams[kind][i])
            sensors.emit(kind, i, t, t0_ns + int(round(t * 1e9)))
            if kind == _DEPTH and progress is not None:
                progress(t, duration)
    wall, cpu = time.perf_counter() - wall0, time.thread_time() - cpu0
    timing = dict(sensors.timing, other=cpu - sum(sensors.timing.values()))
    return {
        "world": world.name, "output": str(out), "seed": cfg.seed, "duration_s": duration,
        "path_duration_s": traj.duration, "distance_m": _distance(traj, min(duration, traj.duration)),
        "messages": sensors.counts, "depth_frames": len(streams[_DEPTH]) * len(sensors.cameras),
        "scans": len(streams.get(_SCAN, [])), "wall_s": wall, "cpu_s": cpu,
        "real_time_factor": duration / wall if wall > 0 else float("inf"),
        "cpu_real_time_factor": duration / cpu if cpu > 0 else float("inf"), "timing_cpu_s": timing,
        **_odometry_drift(odom_true, odom_poses), "bytes": out.stat().st_size, "truth": truth,
    }


def _odometry_drift(odom_true: np.ndarray, odom_poses: np.ndarray) -> dict:
    """Odometry's position and heading error at the end (odom is anchored at the true start pose: map ← odom)."""
    end_odom = pose_matrix(odom_true[0]) @ pose_matrix(odom_poses[-1])
    true_end = odom_true[-1]
    drift = float(np.hypot(end_odom[0, 3] - true_end[0], end_odom[1, 3] - true_end[1]))
    drift_yaw = float(np.degrees(abs(wrap(math.atan2(end_odom[1, 0], end_odom[0, 0]) - true_end[2]))))
    return {"odom_drift_m": drift, "odom_drift_deg": drift_yaw}


def _distance(traj: Trajectory, t_end: float) -> float:
    """Distance driven in the first t_end seconds (m), sampled at 20 Hz."""
    xy = traj.pose(np.linspace(0, t_end, max(int(t_end * 20), 2)))[:, :2]
    return float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))


def simulation_truth(log: str | Path) -> dict | None:
    """The simulator's effective settings and truths of an MCAP log it wrote ({"config": {...}, "truth":
    {"odometry": {"distance_scale", ...}, "imu": {"gyro_bias_initial_dps", ...}}}), or None for other logs."""
    from mcap.reader import make_reader

    with open(log, "rb") as fh:
        for rec in make_reader(fh).iter_metadata():
            if rec.name == METADATA:
                return {k: json.loads(v) for k, v in rec.metadata.items()}
    return None
