"""A synthetic laser world with exact ground truth: a corridor ring with side rooms, a robot driving twice round
it, 180° scans (Intel-like: 181 beams, 5 Hz, 1 cm noise) and drifting wheel odometry. Independent of
tools/simulate (its own segment ray caster), so the SLAM tests check against geometry computed here."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.records import Odometry, Scan, Transform, Transforms

T0 = 1_700_000_000_000_000_000


def world_segments() -> np.ndarray:
    """Wall segments (M×4: x0 y0 x1 y1) of a 20 × 12 m block with a 2.5 m corridor ring and clutter."""
    segs = []

    def box(x0, y0, x1, y1):
        segs.extend([(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)])

    box(0, 0, 20, 12)  # outer wall
    box(2.5, 2.5, 17.5, 9.5)  # inner block (the ring corridor lies between)
    # inner block wall has niches and pillars so that corridors are not featureless
    for x in (5.0, 9.0, 13.0, 16.0):
        box(x, 0.0, x + 0.4, 0.5)
        box(x - 1.0, 11.5, x - 0.6, 12.0)
    for y in (3.5, 7.0):
        box(0.0, y, 0.4, y + 0.6)
        box(19.6, y + 0.5, 20.0, y + 1.0)
    box(6.0, 2.5, 7.0, 2.9)
    box(11.0, 9.1, 12.0, 9.5)
    box(2.5, 5.0, 2.9, 5.8)
    box(17.1, 6.0, 17.5, 6.5)
    return np.array(segs, dtype=float)


def cast(segs: np.ndarray, origin: np.ndarray, angles: np.ndarray, max_range: float) -> np.ndarray:
    """Range to the nearest segment along each ray (inf beyond max_range)."""
    d = np.column_stack((np.cos(angles), np.sin(angles)))  # R×2
    p = segs[:, :2]
    e = segs[:, 2:] - segs[:, :2]  # M×2
    w = p - origin  # M×2
    den = d[:, 0:1] * e[None, :, 1] - d[:, 1:2] * e[None, :, 0]  # R×M
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
        u = (w[None, :, 0] * d[:, 1:2] - w[None, :, 1] * d[:, 0:1]) / den
    ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
    r = np.where(ok, t, np.inf).min(axis=1)
    return np.where(r <= max_range, r, np.inf)


def ring_path(laps: int = 2, speed: float = 0.5, rate: float = 5.0, turn_rate: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """(times s, N×3 poses) driving the corridor ring (centre line 1.25 m from the walls) `laps` times:
    straight legs at `speed`, turns in place at `turn_rate` rad/s."""
    corners = [(1.25, 1.25), (18.75, 1.25), (18.75, 10.75), (1.25, 10.75)]
    poses = []
    dt = 1.0 / rate
    x, y, th = corners[0][0], corners[0][1], 0.0
    for _ in range(laps):
        for k in range(4):
            gx, gy = corners[(k + 1) % 4]
            dist = math.hypot(gx - x, gy - y)
            n = max(int(dist / (speed * dt)), 1)
            for i in range(n):
                poses.append((x + (gx - x) * i / n, y + (gy - y) * i / n, th))
            x, y = gx, gy
            n = int(round((math.pi / 2) / (turn_rate * dt)))
            for i in range(n):
                poses.append((x, y, th + (math.pi / 2) * i / n))
            th = th + math.pi / 2
    poses.append((x, y, th))
    p = np.array(poses)
    p[:, 2] = se2.wrap(p[:, 2])
    return np.arange(len(p)) * dt, p


@dataclass
class LaserLog:
    stamps_ns: np.ndarray
    truth: np.ndarray  # N×3 base_link poses
    scans: list[Scan]
    odom: np.ndarray  # N×3 drifting odometry at the scan stamps
    mount: np.ndarray  # laser in base_link


def make_log(seed: int = 0, laps: int = 2, beams: int = 181, fov_deg: float = 180.0, noise: float = 0.01,
             max_range: float = 30.0, mount=(0.1, 0.0, 0.0), odom_scale: float = 0.02, odom_yaw_per_m_deg: float = 0.5) -> LaserLog:
    """Scans and odometry along the ring; the odometry has a scale error and a heading random walk."""
    rng = np.random.default_rng(seed)
    segs = world_segments()
    t, truth = ring_path(laps)
    mount = np.asarray(mount, dtype=float)
    inc = math.radians(fov_deg) / (beams - 1)
    amin = -math.radians(fov_deg) / 2
    angles = amin + np.arange(beams) * inc
    scans = []
    stamps = (T0 + np.round(t * 1e9)).astype(np.int64)
    for ts, pose in zip(stamps, truth):
        lp = se2.compose(pose, mount)
        r = cast(segs, lp[:2], lp[2] + angles, max_range)
        r = np.where(np.isfinite(r), r + rng.normal(0, noise, beams), r).astype(np.float32)
        scans.append(Scan(int(ts), r, amin, inc, 0.1, max_range, "laser", "/scan"))
    # odometry: increments with a scale error and a heading random walk
    odom = [truth[0].copy()]
    for a, b in zip(truth[:-1], truth[1:]):
        d = se2.between(a, b)
        dist = math.hypot(d[0], d[1])
        d = np.array([d[0] * (1 + odom_scale), d[1] * (1 + odom_scale),
                      d[2] + rng.normal(0, math.radians(odom_yaw_per_m_deg) * math.sqrt(dist + 1e-3) + 0.002)])
        odom.append(se2.compose(odom[-1], d))
    return LaserLog(stamps, truth, scans, np.array(odom), mount)


def records(log: LaserLog, odom_rate_factor: int = 1) -> list:
    """Time-ordered records for a log file: tf_static, then scans and odometry (odometry 1 µs after each scan)."""
    out = [Transforms(int(log.stamps_ns[0]) - 1000, (Transform.from_xyz_rpy("base_link", "laser", [log.mount[0], log.mount[1], 0.3],
                                                                            [0, 0, log.mount[2]]),), True, "/tf_static")]
    for ts, scan, o, g in zip(log.stamps_ns, log.scans, log.odom, log.truth):
        out.append(scan)
        out.append(Odometry(int(ts) + 1000, float(o[0]), float(o[1]), float(o[2]), "odom", "base_link", "/odom"))
        out.append(Odometry(int(ts) + 2000, float(g[0]), float(g[1]), float(g[2]), "map", "base_link", "/ground_truth/odom"))
    return out
