"""JSON-safe copies of result dicts: NaN/inf → null, numpy scalars and arrays → Python, paths → strings."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def json_safe(o):
    """A copy of `o` that `json.dumps` writes as strict JSON (no NaN)."""
    if isinstance(o, dict):
        return {str(k): json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, np.ndarray):
        return json_safe(o.tolist())
    if isinstance(o, (np.floating, float)):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    return o
