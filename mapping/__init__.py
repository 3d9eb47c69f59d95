"""The product's core: the pipeline, occupancy grids, map I/O, map comparison and reports."""

import kosmap.frontend  # noqa: F401  (sets where numba caches kernels: frontend/numbacache.py)
