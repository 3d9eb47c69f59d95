"""Keyframes: the scans that become pose-graph nodes, chosen by distance and angle travelled in the front end.

Every other scan is attached to the latest keyframe at or before it, by its front-end pose relative to that
keyframe, so that each scan gets an optimised pose: x_scan = x_key ⊕ (ℓ_key⁻¹ ⊕ ℓ_scan), ℓ the front-end poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.frontend import se2


@dataclass
class Keyframe:
    """A graph node: the scan, its front-end pose and the wheel odometry there (when the log has it)."""

    id: int  # node id in the graph (0, 1, 2, …)
    scan_index: int  # index of the scan in the run
    stamp_ns: int
    local_pose: np.ndarray  # (3,) front-end pose
    points: np.ndarray  # N×2 scan end points in base_link (backend/slam.py empties it once the loop closer has its copy)
    odom_pose: np.ndarray | None = None  # (3,) wheel odometry
    score: float = float("nan")  # front-end match score
    cov: np.ndarray | None = None  # (3, 3) covariance of the front-end match, map frame (None: unknown)


# Keyframe spacing from the sensor and the measured odometry (docs/benchmarks.md, "How the settings follow"):
# - turn: a keyframe after the scan has turned FOV_SHARE of its field of view (a SICK's 180°: 7.5°, so each keeps
#   ≥ 96 % of the previous one's bearings; a 70° KOS scan: 2.9°), never more than 180° × FOV_SHARE (a wider scan
#   keeps its overlap, but every wall's incidence, hence how its beams sample it, still changes by the full turn),
#   never less than MIN_STEPS beam steps (a turn finer than the beams adds no new bearing);
# - travel: a keyframe after KEY_CELLS cells of the fine likelihood field (5 cm: 0.15 m), so consecutive keyframes
#   sample every wall at points a few cells apart; shortened to where the wheel odometry's own uncertainty over the
#   step (its measured random walk and scale error, backend/odomnoise.py) reaches one cell of the coarse field (10 cm,
#   where matching starts from the prediction), so a step the matcher holds to the odometry (a corridor) errs by no
#   more than that field resolves. One fine cell is too tight: Intel's odometry, measured at up to 16 cm/√m and
#   −13 % over a stretch, then shortened the steps to 9 cm there and measured 0.0177 m against 0.0175 m.
# Graph nodes use the same rule with NODE_CELLS (0.2 m) and NODE_FOV_SHARE of a 180° scan (10°) whatever the field of
# view: the front end's keyframes already keep a narrow scan's overlap, and nodes at 1/18 of a 70° KOS scan (3.7°)
# measured worse on the simulated office (ATE 0.021 → 0.041 m seed 1, 0.051 → 0.061 m seed 0; 25 % more nodes), while
# the keyframes at 1/24 of it improved it (0.033 → 0.021 m, 0.052 → 0.051 m against 7.5°).
FOV_SHARE = 1.0 / 24.0
NODE_FOV_SHARE = 1.0 / 18.0
KEY_CELLS = 3.0
NODE_CELLS = 4.0
MIN_STEPS = 3.0
MAX_FOV = math.pi  # the turn bound stops growing beyond a 180° scan (the incidence argument above)
MIN_FOV_POINTS = 20  # a scan with fewer returns does not measure the field of view


@dataclass(frozen=True)
class Spacing:
    """Travel (m) and turn (rad) after which the next keyframe or node is made."""

    distance: float
    angle: float


def derived_spacing(fov: float, angle_step: float, resolution: float, cells: float, fov_share: float,
                    noise=None, odom_tolerance: float | None = None) -> Spacing:
    """The rule above: `fov` and `angle_step` (rad) the scan's field of view and beam step, `resolution` the fine
    field's cell (m), `noise` the odometry's measured OdomNoise (None: no odometry, or not yet measured) and
    `odom_tolerance` the coarse field's cell (m; None: 2 × resolution) its σ over a step may reach."""
    tol = 2.0 * resolution if odom_tolerance is None else odom_tolerance
    angle = max(min(fov, MAX_FOV) * fov_share, MIN_STEPS * max(angle_step, 0.0))
    distance = round(cells * resolution, 12)  # (3 × 0.05 is 0.15000000000000002 in floating point)
    if noise is not None and noise.translation_sigma(distance) > tol:
        # σ(d)² = σ_t²·d + (s·d)² = r²: the positive root of s²·d² + σ_t²·d − r² = 0
        a, b, c = noise.scale_error ** 2, noise.trans_sigma ** 2, -tol ** 2
        distance = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a) if a > 1e-12 else tol ** 2 / b
    return Spacing(float(distance), float(angle))


def scan_fov(points: np.ndarray) -> tuple[float, float]:
    """The field of view and beam step a scan shows (rad): the span of its returns' bearings from base_link plus one
    step (each beam covers one step, as for a declared sensor: n × angle_increment) and the median gap between
    neighbouring bearings; (0, 0) for a scan too sparse to tell. A sensor mounted off base_link's origin shows a
    narrower span (a SICK 0.1 m forward, walls 3–8 m away: 178°), hence a declared sensor first (Slam.set_sensor)."""
    if len(points) < MIN_FOV_POINTS:
        return 0.0, 0.0
    b = np.sort(np.arctan2(points[:, 1], points[:, 0]))
    gaps = np.diff(b)
    wrap = 2 * math.pi - (b[-1] - b[0])  # the gap across ±180°
    big = int(np.argmax(gaps))
    if wrap >= gaps[big]:
        span = float(b[-1] - b[0])
    else:  # the scan looks backwards: its widest empty sector is inside (−π, π)
        span = float(2 * math.pi - gaps[big])
    pos = gaps[gaps > 1e-9]
    step = float(np.median(pos)) if len(pos) else 0.0
    return min(span + step, 2 * math.pi), step


class KeyframeSelector:
    """Makes a scan a keyframe after `distance` metres or `angle` radians of front-end motion (or the first one)."""

    def __init__(self, distance: float, angle: float, min_points: int = 10) -> None:
        self.distance = distance
        self.angle = angle
        self.min_points = min_points
        self.last: np.ndarray | None = None

    def __call__(self, local_pose: np.ndarray, n_points: int) -> bool:
        if n_points < self.min_points:
            return False
        if self.last is not None:
            d = se2.between(self.last, local_pose)
            if math.hypot(d[0], d[1]) < self.distance and abs(d[2]) < self.angle:
                return False
        self.last = np.array(local_pose, dtype=float)
        return True


def scan_poses(local_poses: np.ndarray, key_of_scan: np.ndarray, key_local: np.ndarray, key_opt: np.ndarray) -> np.ndarray:
    """Optimised pose of every scan from its keyframe's: x_key ⊕ (ℓ_key⁻¹ ⊕ ℓ_scan) (arrays over scans)."""
    k = np.asarray(key_of_scan)
    rel = se2.between(key_local[k], local_poses)
    return se2.compose(key_opt[k], rel)


def relative_covariance(pa: np.ndarray, ca: np.ndarray, pb: np.ndarray, cb: np.ndarray) -> np.ndarray:
    """Covariance of a⁻¹ ⊕ b from independent covariances of a and b (map frame, (x, y, yaw)), expressed as
    gtsam's Pose2 error (the tangent space at the relative pose: translation in b's frame).

    t_rel = R_aᵀ(t_b − t_a), θ_rel = θ_b − θ_a: ∂/∂t_a = −R_aᵀ, ∂/∂θ_a = −R_aᵀ·J·(t_b − t_a) with J the 90°
    rotation, ∂/∂t_b = R_aᵀ, ∂θ_rel = dθ_b − dθ_a; then rotated by R_relᵀ into the tangent at the relative pose.
    """
    ca_, sa = math.cos(pa[2]), math.sin(pa[2])
    RaT = np.array([[ca_, sa], [-sa, ca_]])
    d = np.asarray(pb[:2], dtype=float) - np.asarray(pa[:2], dtype=float)
    Jd = np.array([-d[1], d[0]])
    Ja = np.zeros((3, 3))
    Ja[:2, :2] = -RaT
    Ja[:2, 2] = -RaT @ Jd
    Ja[2, 2] = -1.0
    Jb = np.zeros((3, 3))
    Jb[:2, :2] = RaT
    Jb[2, 2] = 1.0
    c = Ja @ ca @ Ja.T + Jb @ cb @ Jb.T
    th = float(pb[2] - pa[2])
    A = np.eye(3)
    A[:2, :2] = [[math.cos(th), math.sin(th)], [-math.sin(th), math.cos(th)]]
    c = A @ c @ A.T
    return 0.5 * (c + c.T)
