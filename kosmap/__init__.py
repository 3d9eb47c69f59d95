"""kosmap: 2D maps from depth-camera robot logs (FSPF+, the Kinect Obstacle Scan, scan-matching SLAM).

The subpackages live in the repository's top-level folders and are installed under this namespace
(pyproject.toml's package-dir): `kosmap.frontend` (per-frame sensor work), `kosmap.backend` (pose graph,
loops, metrics), `kosmap.mapping` (config, grids, the build) and `kosmap.tools` (the CLI, the simulator,
benchmarks).
"""

__version__ = "0.1.0"
