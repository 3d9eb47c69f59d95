"""The robot's true motion along a path, and wheel odometry that drifts with distance and rotation.

The robot stops at each waypoint, turns in place to the next leg and drives it straight, with trapezoidal
speed profiles (bounded acceleration); each leg's cruise speed is drawn from [speed_min, speed_max]. The
true pose is analytic, so any sensor stamp gets its exact pose (per beam for the laser).
Odometry is a differential drive's dead reckoning: each true increment (distance d, turn dθ) is split into
the two wheels' arcs d ∓ dθ·B/2, each wheel's arc is scaled by its own radius error (Borenstein & Feng 1996,
UMBmark: unequal wheel diameters make a heading drift per metre), the arcs are recombined with a wheel base
that is off by `rot_scale_error`, a further heading bias per metre is added, and zero-mean noise whose variance
grows with the distance and angle of the increment (Thrun et al., Probabilistic Robotics §5.4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.tools.simulate.world import PathSpec, World, WorldError


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


def _profile_va(tau, v_peak, acc, t_acc, dur):
    """Speed and acceleration along the profile at times tau (the derivatives of `_profile_s`)."""
    up, down = tau < t_acc, tau >= dur - t_acc
    v = np.where(up, acc * tau, np.where(down, acc * np.maximum(dur - tau, 0.0), v_peak))
    a = np.where(up, acc, np.where(down, -acc, 0.0))
    inside = (tau > 0.0) & (tau < dur)
    return np.where(inside, v, 0.0), np.where(inside, a, 0.0)


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

    def rates(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """True body rates at times t: forward speed (m/s), yaw rate (rad/s), forward acceleration (m/s²) and
        yaw acceleration (rad/s²), the derivatives of `pose` (zero while standing)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if not self._rows:
            z = np.zeros(len(t))
            return z, z.copy(), z.copy(), z.copy()
        R = np.array(self._rows)
        i = np.clip(np.searchsorted(R[:, 0], t, side="right") - 1, 0, len(R) - 1)
        r = R[i]
        tau = t - r[:, 0]
        v, a = _profile_va(tau, r[:, 8], r[:, 9], r[:, 10], r[:, 1])
        turn = r[:, 2] == 0
        return (np.where(turn, 0.0, v), np.where(turn, r[:, 6] * v, 0.0), np.where(turn, 0.0, a),
                np.where(turn, r[:, 6] * a, 0.0))

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
    """Wheel odometry errors: per-wheel radius errors, a wheel-base error and a heading bias (systematic), plus
    noise growing with motion.

    With wheel errors e_L, e_R, wheel base B, common error s and wheel-base error k, a true increment (d, dθ)
    is measured as
        d' = (1 + s)·[(1 + ē)·d + (e_R − e_L)·B/4·dθ]                       (ē = (e_L + e_R)/2)
        dθ' = (1 + k)·[(1 + ē)·dθ + (e_R − e_L)/B·d] + heading_bias·d
    so driving straight, odometry distance is `distance_scale()` × the true distance and its heading drifts by
    `heading_drift_deg_per_m()`; turning in place, it turns `rotation_scale()` × the true angle. With
    e_L = e_R = 0, `scale_error` and `rot_scale_error` keep their old meaning (translation and rotation scale).
    """

    scale_error: float = 0.0  # common translation scale error on top of the wheels' (fraction)
    rot_scale_error: float = 0.005  # wheel base error: rotation scale on top of the wheels' (fraction)
    heading_bias_deg_per_m: float = 0.1  # heading drift per metre driven, on top of the wheels' (deg/m)
    trans_noise: float = 0.01  # σ of translation per √m driven (m/√m)
    rot_noise_deg: float = 1.0  # σ of rotation per √rad turned (deg/√rad)
    rot_noise_per_m_deg: float = 0.5  # σ of rotation per √m driven (deg/√m)
    scale_error_left: float = 0.010  # left wheel's radius error: it reports this fraction more than it rolled
    scale_error_right: float = 0.011  # right wheel's radius error
    wheel_base: float = 0.5  # distance between the wheels (m)

    @property
    def _mean_wheel(self) -> float:
        return 0.5 * (self.scale_error_left + self.scale_error_right)

    def distance_scale(self) -> float:
        """The true factor by which odometry distance exceeds true distance when driving straight."""
        return (1.0 + self.scale_error) * (1.0 + self._mean_wheel)

    def rotation_scale(self) -> float:
        """The true factor by which odometry's angle exceeds the true angle when turning in place."""
        return (1.0 + self.rot_scale_error) * (1.0 + self._mean_wheel)

    def heading_drift_deg_per_m(self) -> float:
        """Heading odometry gains per metre driven straight (deg/m, > 0 = to the left): wheels and bias."""
        wheels = (1.0 + self.rot_scale_error) * (self.scale_error_right - self.scale_error_left) / self.wheel_base
        return math.degrees(wheels) + self.heading_bias_deg_per_m

    def truth(self) -> dict:
        """The systematic errors and what they amount to, for scoring an estimate (JSON-ready)."""
        return {"distance_scale": self.distance_scale(), "rotation_scale": self.rotation_scale(),
                "heading_drift_deg_per_m": self.heading_drift_deg_per_m(),
                "scale_error_left": self.scale_error_left, "scale_error_right": self.scale_error_right,
                "wheel_base": self.wheel_base, "scale_error": self.scale_error,
                "rot_scale_error": self.rot_scale_error, "heading_bias_deg_per_m": self.heading_bias_deg_per_m}


def odometry(true_poses: np.ndarray, noise: OdometryNoise, rng: np.random.Generator) -> np.ndarray:
    """Odometry poses (N×3) in the `odom` frame, starting at (0, 0, 0), from true poses at the odometry stamps:
    each true increment (robot frame) is corrupted (see OdometryNoise) and integrated."""
    P = np.asarray(true_poses, float)
    n = len(P)
    # increments in the robot frame of the previous pose
    d = np.diff(P[:, :2], axis=0)
    c, s = np.cos(P[:-1, 2]), np.sin(P[:-1, 2])
    lx, ly = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    dth = wrap(np.diff(P[:, 2]))
    dist = np.hypot(lx, ly)
    moved = dist > 1e-12
    fwd = np.where(lx < 0, -dist, dist)  # signed distance along the chord (< 0 reversing)
    z = rng.standard_normal((max(n - 1, 0), 2))
    # the wheels' arcs, each scaled by its own radius error, recombined with the nominal wheel base
    B = noise.wheel_base
    arc_l = (fwd - 0.5 * B * dth) * (1.0 + noise.scale_error_left)
    arc_r = (fwd + 0.5 * B * dth) * (1.0 + noise.scale_error_right)
    fwd_o = 0.5 * (arc_l + arc_r) * (1.0 + noise.scale_error) + np.where(moved, noise.trans_noise * np.sqrt(dist) * z[:, 0], 0.0)
    rot_sigma = np.sqrt(math.radians(noise.rot_noise_deg) ** 2 * np.abs(dth)
                        + math.radians(noise.rot_noise_per_m_deg) ** 2 * dist)
    dth_o = ((arc_r - arc_l) / B * (1.0 + noise.rot_scale_error) + math.radians(noise.heading_bias_deg_per_m) * dist
             + rot_sigma * z[:, 1])
    # the measured chord keeps the true chord's direction in the robot frame (ahead when turning in place)
    ux = np.where(moved, lx / np.where(moved, fwd, 1.0), 1.0)
    uy = np.where(moved, ly / np.where(moved, fwd, 1.0), 0.0)
    lx_o, ly_o = ux * fwd_o, uy * fwd_o
    out = np.zeros((n, 3))
    yaw = np.concatenate(([0.0], np.cumsum(dth_o)))
    # the measured chord, expressed in the robot frame of the previous odometry pose
    cm, sm = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    out[1:, 0] = np.cumsum(cm * lx_o - sm * ly_o)
    out[1:, 1] = np.cumsum(sm * lx_o + cm * ly_o)
    out[:, 2] = wrap(yaw)
    return out
