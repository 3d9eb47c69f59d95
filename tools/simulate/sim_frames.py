"""Simulated Kinect v2 frames for benchmarks and tests of later stages (e.g. tools/bench_planes.py)."""

from __future__ import annotations

import numpy as np

from kosmap.tools.simulate.config import SimConfig
from kosmap.tools.simulate.log import trajectory
from kosmap.tools.simulate.render import camera_mount, kinect_v2_model, render_depth_geometry
from kosmap.tools.simulate.sensors import DepthNoise, apply_depth_noise
from kosmap.tools.simulate.world import load_world


def bench_frames(n: int, world: str = "office", seed: int = 0, pitch_deg: float = 0.0):
    """(label, depth float32 m H×W, CameraModel, mount base_link ← optical) of n noisy frames spread evenly
    along the world's bundled path (default mount: 1.0 m high, level)."""
    w = load_world(world)
    cfg = SimConfig(seed=seed)
    traj = trajectory(w, cfg)
    mount = camera_mount((0.1, 0.0, 1.0), (0.0, np.radians(pitch_deg), 0.0))
    model = kinect_v2_model(mount.child)
    noise = DepthNoise()
    rng = np.random.default_rng([seed, 99])
    out = []
    for k, t in enumerate(np.linspace(0.0, traj.duration, n, endpoint=False)):
        pose = traj.pose(t)[0]
        z, sid, cs = render_depth_geometry(w, pose, mount, model, noise.max_range)
        depth, _ = apply_depth_noise(z, sid, cs, noise, rng)
        out.append((f"{world} t={t:.1f}s", np.ascontiguousarray(depth), model, mount))
    return out
