"""Entry points: the `kosmap` CLI, the log simulator, converters and benchmarks."""

import kosmap.frontend  # noqa: F401  (sets where numba caches kernels: frontend/numbacache.py)
