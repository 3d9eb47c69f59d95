"""One-call rendering for tests and other stages: exact geometry, plus sensor noise when given an rng."""

from __future__ import annotations

import numpy as np

from kosmap.frontend.records import CameraModel, Transform
from kosmap.tools.simulate import render as _render
from kosmap.tools.simulate.render import LaserModel, kinect_v2_model, render_depth_geometry, render_laser_geometry
from kosmap.tools.simulate.sensors import DepthNoise, LaserNoise, apply_depth_noise, apply_laser_noise
from kosmap.tools.simulate.world import World


def render_depth(world: World, pose_xyyaw, camera_mount: Transform | None = None, camera_model: CameraModel | None = None,
                 rng: np.random.Generator | None = None, noise: DepthNoise | None = None,
                 method: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Depth image (float32 m, H×W, 0 = invalid) and surface ids (uint16, 0 = none) of a camera on a robot at
    planar pose (x, y, yaw) in the world. Without rng: exact depth of everything within the sensor's range
    [min_range, max_range] (no noise, no dropouts); with rng: Kinect v2 noise (sensors.DepthNoise)."""
    mount = camera_mount if camera_mount is not None else _render.camera_mount()
    model = camera_model if camera_model is not None else kinect_v2_model(mount.child)
    noise = noise if noise is not None else DepthNoise()
    z, sid, cos_inc = render_depth_geometry(world, pose_xyyaw, mount, model, noise.max_range, method)
    if rng is None:
        ok = (z >= noise.min_range) & (z > 0)
        return (np.ascontiguousarray(np.where(ok, z, np.float32(0.0))),
                np.ascontiguousarray(np.where(ok, sid, np.uint16(0))))
    z, sid = apply_depth_noise(z, sid, cos_inc, noise, rng)
    return np.ascontiguousarray(z), np.ascontiguousarray(sid)


def render_laser(world: World, pose_xyyaw, laser_mount: Transform | None = None, laser_model: LaserModel | None = None,
                 rng: np.random.Generator | None = None, noise: LaserNoise | None = None,
                 return_ids: bool = False):
    """Ranges (float32, one per beam; +inf = no return) of a laser on a robot at planar pose (x, y, yaw).
    Without rng exact; with rng Hokuyo noise (sensors.LaserNoise). `return_ids` also returns the surface ids."""
    mount = laser_mount if laser_mount is not None else _render.laser_mount()
    model = laser_model if laser_model is not None else LaserModel()
    r, sid, cos_inc = render_laser_geometry(world, pose_xyyaw, mount, model)
    r = np.where(r >= model.range_max, np.inf, r)
    if rng is not None:
        r = apply_laser_noise(r, cos_inc, noise if noise is not None else LaserNoise(), model.range_min,
                              model.range_max, rng)
    r = np.asarray(r, dtype=np.float32)
    return (r, sid.astype(np.uint16)) if return_ids else r
