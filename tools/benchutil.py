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


def cpu_model() -> str:
    """The processor's name and widest vector unit (/proc/cpuinfo): the compiled kernels vectorise twice as wide
    with AVX-512, so results from machines of one kind compare, others not."""
    try:
        with open("/proc/cpuinfo") as fh:
            info = fh.read()
    except OSError:
        return "unknown"
    name = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")), "unknown")
    flags = next((ln.split(":", 1)[1].split() for ln in info.splitlines() if ln.startswith("flags")), [])
    vec = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"{name}, {vec}"
