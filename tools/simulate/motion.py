"""The robot's true motion along a path, and wheel odometry that drifts with distance and rotation.

The robot stops at each waypoint, turns in place to the next leg and drives it straight, with trapezoidal
speed profiles (bounded acceleration); each leg's cruise speed is drawn from [speed_min, speed_max]. The
true pose is analytic, so any sensor stamp gets its exact pose (per beam for the laser).
Odometry follows the odometry motion model of Thrun et al., Probabilistic Robotics §5.4: each increment's
translation and rotation are scaled by systematic errors (wheel radius, wheel base), a heading bias per metre
is added, and zero-mean noise whose variance grows with the distance and angle of the increment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tools.simulate.world import PathSpec, World, WorldError


def wrap(a):
    """Angles into (−π, π]."""
    return np.mod(np.asarray(a) + np.pi, 2 * np.pi) - np.pi


@dataclass(frozen=True)
class Profile:
    """A trapezoidal profile over `length` (> 0) with cruise speed `vmax` and acceleration `acc`."""

    length: float
    vmax: float
    acc: float

    @property
    def t_acc(self) -> float:
        return min(self.vmax / self.acc, math.sqrt(self.length / self.acc))

    @property
    def v_peak(self) -> float:
        return self.acc * self.t_acc

    @property
    def duration(self) -> float:
        d_acc = 0.5 * self.acc * self.t_acc ** 2
        return 2 * self.t_acc + (self.length - 2 * d_acc) / self.v_peak


def _profile_s(tau, length, v_peak, acc, t_acc, dur):
    """Distance covered at times tau (arrays, one profile per element)."""
    d_acc = 0.5 * acc * t_acc ** 2
    s_up = 0.5 * acc * tau ** 2
    s_cruise = d_acc + v_peak * (tau - t_acc)
    s_down = length - 0.5 * acc * (dur - tau) ** 2
    return np.where(tau < t_acc, s_up, np.where(tau < dur - t_acc, s_cruise, s_down))


class Trajectory:
    """Piecewise motion: turns in place and straight drives; `pose(t)` for any t (s from the start)."""

    def __init__(self, start: tuple[float, float, float]) -> None:
        self.start = start
        self._rows: list[tuple] = []  # (t0, dur, kind 0 turn / 1 drive, x0, y0, yaw0, sign, length, v_peak, acc, t_acc)
        self._end = start
        self.duration = 0.0
        self.distance = 0.0
        self.rotation = 0.0

    def turn(self, yaw_to: float, rate: float, acc: float) -> None:
        x, y, yaw = self._end
        delta = float(wrap(yaw_to - yaw))
        if abs(delta) < 1e-6:
            return
        p = Profile(abs(delta), rate, acc)
        self._rows.append((self.duration, p.duration, 0, x, y, yaw, math.copysign(1.0, delta), p.length, p.v_peak,
                           acc, p.t_acc))
        self.duration += p.duration
        self.rotation += abs(delta)
        self._end = (x, y, float(wrap(yaw + delta)))

    def drive(self, to_xy, speed: float, acc: float) -> None:
        x, y, yaw = self._end
        length = math.hypot(to_xy[0] - x, to_xy[1] - y)
        if length < 1e-6:
            return
        p = Profile(length, speed, acc)
        self._rows.append((self.duration, p.duration, 1, x, y, yaw, 1.0, length, p.v_peak, acc, p.t_acc))
        self.duration += p.duration
        self.distance += length
        self._end = (x + length * math.cos(yaw), y + length * math.sin(yaw), yaw)

    @property
    def end(self) -> tuple[float, float, float]:
        return self._end

    def pose(self, t) -> np.ndarray:
        """True (x, y, yaw) at times t (s since the start; after the end the robot stands at its end)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if not self._rows:
            return np.tile(np.asarray(self.start, float), (len(t), 1))
        R = np.array(self._rows)
        i = np.clip(np.searchsorted(R[:, 0], t, side="right") - 1, 0, len(R) - 1)
        r = R[i]
        tau = np.clip(t - r[:, 0], 0.0, r[:, 1])
        s = _profile_s(tau, r[:, 7], r[:, 8], r[:, 9], r[:, 10], r[:, 1])
        turn = r[:, 2] == 0
        x = np.where(turn, r[:, 3], r[:, 3] + s * np.cos(r[:, 5]))
        y = np.where(turn, r[:, 4], r[:, 4] + s * np.sin(r[:, 5]))
        yaw = np.where(turn, r[:, 5] + r[:, 6] * s, r[:, 5])
        return np.column_stack((x, y, wrap(yaw)))

    def legs(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The straight drives as (start xy, end xy)."""
        out = []
        for row in self._rows:
            if row[2] == 1:
                a = np.array([row[3], row[4]])
                out.append((a, a + row[7] * np.array([math.cos(row[5]), math.sin(row[5])])))
        return out


def plan(path: PathSpec, speed_min: float, speed_max: float, accel: float, turn_rate: float, turn_accel: float,
         rng: np.random.Generator) -> Trajectory:
    """Stop, turn in place, drive straight, for every waypoint after the first."""
    wps = np.asarray(path.waypoints, float)
    first = wps[1] - wps[0]
    yaw0 = path.start_yaw if path.start_yaw is not None else math.atan2(first[1], first[0])
    traj = Trajectory((float(wps[0, 0]), float(wps[0, 1]), float(wrap(yaw0))))
    for k in range(1, len(wps)):
        d = wps[k] - np.asarray(traj.end[:2])
        if np.hypot(*d) < 1e-6:
            continue
        traj.turn(math.atan2(d[1], d[0]), turn_rate, turn_accel)
        traj.drive(wps[k], float(rng.uniform(speed_min, speed_max)), accel)
    if traj.duration <= 0:
        raise WorldError("the path has no length: give at least two distinct waypoints")
    return traj


def check_path(world: World, path: PathSpec, clearance: float) -> None:
    """Refuse a path whose legs pass through (or within `clearance` of) a solid the robot would touch, or
    leave the building."""
    wps = np.asarray(path.waypoints, float)
    if len(wps) < 2:
        raise WorldError("the path needs at least two waypoints")
    outside = np.flatnonzero(~world.inside_bounds(wps))
    if len(outside):
        k = int(outside[0])
        x0, y0, x1, y1 = world.bounds
        raise WorldError(f"waypoint {k} ({wps[k, 0]:.2f}, {wps[k, 1]:.2f}) is outside the world "
                         f"({x0:.1f}..{x1:.1f} × {y0:.1f}..{y1:.1f} m); move it inside")
    for k in range(len(wps) - 1):
        a, b = wps[k], wps[k + 1]
        n = max(int(math.ceil(np.hypot(*(b - a)) / 0.02)), 1)
        pts = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)
        for s in world.solids:
            cx, cy, r = s.bounding_circle()
            near = _segment_point_distance(a, b, np.array([cx, cy])) <= r + clearance
            if not near:
                continue
            d = s.footprint_distance(pts)
            j = int(np.argmin(d))
            if d[j] < clearance:
                what = "through" if d[j] <= 0 else f"{d[j]:.2f} m from (closer than the robot's radius {clearance:.2f} m)"
                raise WorldError(f"path leg {k} ({a[0]:.2f}, {a[1]:.2f}) → ({b[0]:.2f}, {b[1]:.2f}) passes {what} "
                                 f"{s.name} at ({pts[j, 0]:.2f}, {pts[j, 1]:.2f}); move the waypoints")


def _segment_point_distance(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> float:
    ab = b - a
    t = float(np.clip((p - a) @ ab / max(float(ab @ ab), 1e-18), 0.0, 1.0))
    return float(np.hypot(*(p - a - t * ab)))


@dataclass(frozen=True)
class OdometryNoise:
    """Wheel odometry errors: systematic scale errors and heading bias, plus noise growing with motion."""

    scale_error: float = 0.01  # translation scale error (fraction; wheel radius)
    rot_scale_error: float = 0.015  # rotation scale error (fraction; wheel base)
    heading_bias_deg_per_m: float = 0.1  # heading drift per metre driven (deg/m)
    trans_noise: float = 0.01  # σ of translation per √m driven (m/√m)
    rot_noise_deg: float = 1.0  # σ of rotation per √rad turned (deg/√rad)
    rot_noise_per_m_deg: float = 0.5  # σ of rotation per √m driven (deg/√m)


def odometry(true_poses: np.ndarray, noise: OdometryNoise, rng: np.random.Generator) -> np.ndarray:
    """Odometry poses (N×3) in the `odom` frame, starting at (0, 0, 0), from true poses at the odometry stamps:
    each true increment (robot frame) is corrupted and integrated."""
    P = np.asarray(true_poses, float)
    n = len(P)
    # increments in the robot frame of the previous pose
    d = np.diff(P[:, :2], axis=0)
    c, s = np.cos(P[:-1, 2]), np.sin(P[:-1, 2])
    lx, ly = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    dth = wrap(np.diff(P[:, 2]))
    dist = np.hypot(lx, ly)
    z = rng.standard_normal((max(n - 1, 0), 2))
    scale = 1.0 + noise.scale_error + noise.trans_noise * np.sqrt(dist) * z[:, 0] / np.maximum(dist, 1e-12)
    scale = np.where(dist > 1e-12, scale, 1.0)
    rot_sigma = np.sqrt(math.radians(noise.rot_noise_deg) ** 2 * np.abs(dth)
                        + math.radians(noise.rot_noise_per_m_deg) ** 2 * dist)
    dth_o = dth * (1.0 + noise.rot_scale_error) + math.radians(noise.heading_bias_deg_per_m) * dist + rot_sigma * z[:, 1]
    lx_o, ly_o = lx * scale, ly * scale
    out = np.zeros((n, 3))
    yaw = np.concatenate(([0.0], np.cumsum(dth_o)))
    # the measured chord, expressed in the robot frame of the previous odometry pose
    cm, sm = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    out[1:, 0] = np.cumsum(cm * lx_o - sm * ly_o)
    out[1:, 1] = np.cumsum(sm * lx_o + cm * ly_o)
    out[:, 2] = wrap(yaw)
    return out
