"""The product's core: the build (build/), the SLAM and KOS drivers, the processes and output folders (runtime/),
occupancy grids, map I/O, map comparison and reports."""

import kosmap.frontend  # noqa: F401  (sets where numba caches kernels: frontend/numbacache.py)
