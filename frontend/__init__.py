"""Per-frame sensor work: logs, depth to 3D, plane filtering, the Kinect Obstacle Scan, scan-matching odometry."""

from kosmap.frontend import numbacache

numbacache.ensure()  # before any module of ours imports numba
