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
