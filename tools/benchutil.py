"""Helpers the benchmark scripts share."""

from __future__ import annotations

import os


def pin_one_core() -> str:
    """Run this process on one core (the last), so per-frame times are single-core times; says what it did."""
    try:
        cores = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cores[-1]})
        return f"pinned to core {cores[-1]} of {len(cores)}"
    except (AttributeError, OSError):
        return "not pinned"
