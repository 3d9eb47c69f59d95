"""What a configuration value may sensibly be, beyond each stage's own bounds (frontend/params.py): every number
finite, and no length, rate, count or cell size so large (or a cell size so small) that a run would allocate or loop
without end. Each limit comes from what the sensors and buildings are, and is named in the refusal."""

from __future__ import annotations

import math
from typing import Any

from kosmap.frontend.errors import ConfigError

# By unit: (lowest, highest, why). A length beyond a kilometre is no building's; a rate beyond 1 kHz no range
# sensor's (lasers and depth cameras run at 5-100 Hz); an angle beyond a turn means nothing.
BY_UNIT: dict[str, tuple[float | None, float | None, str]] = {
    "m": (-1000.0, 1000.0, "a kilometre is larger than any building a robot maps"),
    "deg": (-360.0, 360.0, "a full turn"),
    "px": (None, 10000.0, "wider than any depth image"),
    "Hz": (None, 1000.0, "faster than any depth camera or laser (they run at 5-100 Hz)"),
    "s": (None, 3600.0, "an hour"),
    "m/m": (None, 10.0, "ten times the distance travelled"),
    "m/s": (None, 10.0, "faster than any robot indoors"),
    "m/s²": (None, 50.0, "five times gravity"),
    "deg/s": (None, 3600.0, "ten turns a second"),
    "deg/s²": (None, 36000.0, "ten turns a second, reached in a tenth of a second"),
    "rad/rad": (None, 10.0, "ten times the rotation"),
}

# Per key, where the sensor or the data say more than the unit does.
BY_KEY: dict[str, tuple[float | None, float | None, str]] = {
    "depth.min_depth": (None, 50.0, "no depth camera measures farther (Kinect v2: 4.5 m, stereo cameras: 20-40 m)"),
    "depth.max_depth": (None, 50.0, "no depth camera measures farther (Kinect v2: 4.5 m, stereo cameras: 20-40 m)"),
    "depth.mount_xyz": (-10.0, 10.0, "a camera mounted on the robot"),
    "kos.levels": (-10.0, 10.0, "heights within a storey"),
    "kos.obstacle_min": (-10.0, 10.0, "heights within a storey"),
    "kos.obstacle_max": (-10.0, 10.0, "heights within a storey"),
    "kos.band": (None, 10.0, "the height of a storey"),
    "kos.angle_increment_deg": (None, 45.0, "eight bins in a full turn"),
    "odometry.max_range": (None, 300.0, "no 2D laser scanner measures farther"),
    "odometry.min_range": (None, 300.0, "no 2D laser scanner measures farther"),
    "localize.max_range": (None, 300.0, "no 2D laser scanner measures farther"),
    "localize.min_range": (None, 300.0, "no 2D laser scanner measures farther"),
    "graph.loop_search_range": (None, 300.0, "no 2D laser scanner measures farther"),
    "grid.no_return_clear": (None, 300.0, "no 2D laser scanner measures farther"),
    "grid.max_range": (None, 300.0, "no 2D laser scanner measures farther"),
    "fspf.seed": (None, 2 ** 32 - 1, "the largest 32-bit seed"),
    "compare.seed": (None, 2 ** 32 - 1, "the largest 32-bit seed"),
    "localize.seed": (None, 2 ** 32 - 1, "the largest 32-bit seed"),
    "fspf.n_min": (None, 10 ** 7, "more points than a depth image has"),
    "fspf.ransac_subset": (None, 10 ** 6, "more points than a search window holds"),
    "fspf.ransac_max_iter": (None, 10 ** 6, "a million hypotheses per plane"),
    "fspf.planes_per_window": (None, 1000, "more planes than a window can hold"),
    "fspf.fspf_max_points": (None, 10 ** 8, "more points than a depth image has"),
    "fspf.fspf_max_neighborhoods": (None, 10 ** 8, "more neighbourhoods than a depth image has pixels"),
    "fspf.fspf_local_samples": (None, 10 ** 6, "more samples than a neighbourhood has pixels"),
    "odometry.submap_keyframes": (None, 10 ** 6, "a million keyframes"),
    "odometry.gn_iterations": (None, 10 ** 4, "ten thousand iterations per level"),
    "odometry.min_points": (None, 10 ** 6, "more returns than a scan has"),
    "graph.submap_nodes": (None, 10 ** 6, "a million nodes"),
    "graph.loop_max_candidates": (None, 10 ** 4, "ten thousand candidates per node"),
    "graph.loop_field_cache": (None, 10 ** 4, "ten thousand fields in memory"),
    "compare.max_points": (None, 10 ** 8, "a hundred million cells"),
    "compare.max_canvas_cells": (None, 2 * 10 ** 8, "as many cells as a grid may have (mapping/grid.py MAX_CELLS)"),
    "build.mcap_plane_points": (None, 10 ** 7, "more points than a depth image has"),
    "build.in_flight": (None, 10 ** 4, "ten thousand depth frames in memory"),
    "localize.min_particles": (None, 10 ** 7, "ten million particles"),
    "localize.max_particles": (None, 10 ** 7, "ten million particles"),
    "localize.global_max_particles": (None, 10 ** 7, "ten million particles"),
    "localize.global_density": (None, 10 ** 5, "ten particles per square centimetre"),
    "localize.max_beams": (None, 10 ** 5, "more beams than a scan has"),
    "localize.mcap_particles": (None, 10 ** 7, "ten million particles"),
    "localize.converged_updates": (None, 10 ** 6, "a million updates"),
    "localize.resample_interval": (None, 10 ** 6, "a million updates"),
    "localize.min_points": (None, 10 ** 6, "more returns than a scan has"),
    "simulate.start_time": (None, 4.1e9, "the year 2100"),
    "simulate.duration": (None, 7 * 86400.0, "a week"),
    "simulate.depth_max_range": (None, 50.0, "no depth camera measures farther"),
    "simulate.laser_range_max": (None, 300.0, "no 2D laser scanner measures farther"),
    "simulate.laser_beams": (None, 10 ** 4, "more beams than any 2D laser scanner (a UTM-30LX has 1081)"),
    "simulate.seed": (None, 2 ** 32 - 1, "the largest 32-bit seed"),
}

# Cell sizes: a grid of cells finer than a millimetre resolves nothing a range sensor measures (laser and depth
# noise are centimetres) and would need more memory than any machine has for a room.
CELL_KEYS = ("grid.resolution", "odometry.resolution", "odometry.coarse_resolution", "odometry.voxel_size",
             "graph.loop_resolution", "localize.bin_xy", "odometry.search_linear_step")
MIN_CELL_M = 0.001
MAX_LEVELS = 64  # KOS levels: each is a scan per frame and a map (the thesis used 3)
MAX_COUNT = 10 ** 9  # a whole-number key without a limit of its own (compiled kernels take 64-bit integers)
MAX_LIST = 1000  # any list-valued key (topics, tolerances, simulated IMU faults...)
MAX_SUBMAP_CELLS = 10 ** 8  # one likelihood field of a submap: 400 MB of float32


def check_value(section: str, key: str, unit: str, value: Any, count: bool = False) -> None:
    """ConfigError when `value` (a number, or a list of numbers) is not finite or lies beyond its limit. `count`: a
    whole-number key (a count, a period in nodes...), never above MAX_COUNT unless its own limit says otherwise."""
    dotted = f"{section}.{key}"
    items = value if isinstance(value, (list, tuple)) else [value]
    if dotted == "kos.levels" and len(items) > MAX_LEVELS:
        raise ConfigError(f"config [kos] levels has {len(items)} heights: at most {MAX_LEVELS} (each level is a scan "
                          f"per depth frame and a map)")
    if isinstance(value, (list, tuple)) and len(value) > MAX_LIST:
        raise ConfigError(f"config [{section}] {key} has {len(value)} values: at most {MAX_LIST}")
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue  # the stage's own check says what type it must be
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"config [{section}] {key} = {_short(value)} is not a finite number; give a number")
        lo, hi, why = BY_KEY.get(dotted) or BY_UNIT.get(unit) or (
            (None, MAX_COUNT, "a billion: more than any run counts") if count else (None, None, ""))
        if dotted in CELL_KEYS and 0 < v < MIN_CELL_M:
            raise ConfigError(f"config [{section}] {key} = {v:g} m is too fine: the smallest cell is {MIN_CELL_M:g} m "
                              f"(range sensors measure to centimetres)")
        if hi is not None and v > hi:
            raise ConfigError(f"config [{section}] {key} = {v:g} is too large: at most {hi:g}{_unit(unit)} ({why})")
        if lo is not None and v < lo:
            raise ConfigError(f"config [{section}] {key} = {v:g} is too small: at least {lo:g}{_unit(unit)} ({why})")


def check_config(cfg) -> None:
    """Limits that join several keys: a bearing bin so narrow that a scan has millions of bins; a submap whose
    likelihood field would have more than MAX_SUBMAP_CELLS cells."""
    inc = cfg.kos.angle_increment_deg
    if 0 < inc < 0.01:
        raise ConfigError(f"config [kos] angle_increment_deg = {inc:g} is too fine: at least 0.01° (36 000 bins in a "
                          f"turn, far finer than a depth image's columns), or 0 for one bin per image column")
    o = cfg.odometry
    for key in ("resolution", "coarse_resolution"):
        cells = (o.submap_size / getattr(o, key)) ** 2
        if cells > MAX_SUBMAP_CELLS:
            finest = o.submap_size / math.sqrt(MAX_SUBMAP_CELLS)
            raise ConfigError(f"config [odometry] {key} = {getattr(o, key):g} m makes a submap of {o.submap_size:g} m "
                              f"{cells:.3g} cells (at most {MAX_SUBMAP_CELLS:.0e}): give {key} ≥ {finest:.3g} m or a "
                              f"smaller submap_size")


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _short(value: Any) -> str:
    """A value as the user gave it, shortened to a line."""
    text = repr(value)
    if len(text) <= 80:
        return text
    return text[:60] + (f"… ({len(value)} values)" if isinstance(value, (list, tuple)) else "…")
