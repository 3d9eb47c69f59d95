"""Planar rigid transforms as (x, y, yaw) arrays: compose, invert, relative pose, interpolation.

Poses are float64 arrays of shape (3,) or (N, 3); yaw in radians, wrapped to (−π, π].
"""

from __future__ import annotations

import math

import numpy as np


def wrap(a):
    """Angle(s) wrapped to (−π, π]."""
    if isinstance(a, float):
        return math.pi - (math.pi - a) % (2.0 * math.pi)
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)


def _one(p) -> bool:
    return isinstance(p, (tuple, list)) or (isinstance(p, np.ndarray) and p.ndim == 1)


def compose(a, b) -> np.ndarray:
    """a ⊕ b: the pose b, given in the frame of a, expressed in a's parent frame (broadcasts over rows)."""
    if _one(a) and _one(b):  # one pose: scalar math is ~10× faster than the array path
        c, s = math.cos(a[2]), math.sin(a[2])
        return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(float(a[2] + b[2]))])
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack((x, y, wrap(a[..., 2] + b[..., 2])), axis=-1)


def inverse(a) -> np.ndarray:
    """⊖a: the parent frame seen from a."""
    if _one(a):
        c, s = math.cos(a[2]), math.sin(a[2])
        return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap(float(-a[2]))])
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack((x, y, wrap(-a[..., 2])), axis=-1)


def between(a, b) -> np.ndarray:
    """a⁻¹ ⊕ b: pose b expressed in the frame of pose a (a relation in Kümmerle et al.'s sense)."""
    return compose(inverse(a), b)


def transform_points(pose, pts: np.ndarray) -> np.ndarray:
    """N×2 points from the frame of `pose` into its parent frame."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    p = np.asarray(pts, dtype=float)
    return np.column_stack((pose[0] + c * p[:, 0] - s * p[:, 1], pose[1] + s * p[:, 0] + c * p[:, 1]))


def interpolate(times: np.ndarray, poses: np.ndarray, t) -> np.ndarray:
    """Poses at times `t` by linear interpolation of x, y and unwrapped yaw; held constant beyond the ends."""
    times = np.asarray(times, dtype=float)
    poses = np.asarray(poses, dtype=float)
    yaw = np.unwrap(poses[:, 2])
    t = np.asarray(t, dtype=float)
    out = np.stack([np.interp(t, times, poses[:, 0]), np.interp(t, times, poses[:, 1]), np.interp(t, times, yaw)], axis=-1)
    out[..., 2] = wrap(out[..., 2])
    return out
