"""The log simulator: a building, Kinect v2 depth cameras, a Hokuyo laser, drifting wheel odometry and a MEMS
IMU, written as MCAP with exact ground truth (`kosmap simulate`).

API for tests and other stages (nothing here writes files unless asked):
    World.load("office" | "room" | path.yaml) → World (solids, `surfaces` with class and plane, blueprint())
    render_depth(world, pose_xyyaw, camera_mount, camera_model, rng=None) → (depth_m, surface_id)
    render_laser(world, pose_xyyaw, laser_mount, laser_model=None, rng=None) → ranges
    simulate(world, SimConfig(...), "out.mcap") → summary dict (its "truth": odometry scale, gyro bias)
    simulation_truth("out.mcap") → {"config": {...}, "truth": {"odometry": {...}, "imu": {...} or None}}
"""

from kosmap.tools.simulate.api import render_depth, render_laser
from kosmap.tools.simulate.config import SimConfig
from kosmap.tools.simulate.imu import ImuNoise
from kosmap.tools.simulate.log import simulate, simulation_truth, trajectory
from kosmap.tools.simulate.motion import OdometryNoise
from kosmap.tools.simulate.render import LaserModel, camera_mount, kinect_v2_model, laser_mount
from kosmap.tools.simulate.sensors import DepthNoise, LaserNoise
from kosmap.tools.simulate.world import FLYING_ID, NO_SURFACE, Surface, World, WorldError, load_path, load_world

__all__ = ["World", "Surface", "WorldError", "load_world", "load_path", "render_depth", "render_laser", "simulate",
           "trajectory", "SimConfig", "LaserModel", "DepthNoise", "LaserNoise", "camera_mount", "laser_mount",
           "kinect_v2_model", "FLYING_ID", "NO_SURFACE", "ImuNoise", "OdometryNoise", "simulation_truth"]
