"""`kosmap planes`' run as its stages: the frames (frames.py) → FSPF+ or FSPF (frontend/fspf.py) → their classes
from gravity (classes.py) → the per-frame outputs (outputs.py, figures.py) → stats.csv and summary.json
(stats.py). The outputs are written into a staging folder and replace the previous run's only when the run
completes (mapping/runtime/outdir.py)."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from kosmap.frontend.errors import KosmapError
from kosmap.frontend.fspf import filter_planes, frame_seed, warmup
from kosmap.frontend.planes import Planes
from kosmap.mapping.config import write_config
from kosmap.mapping.planes.classes import Classes
from kosmap.mapping.planes.frames import FrameSource, Item, note
from kosmap.mapping.planes.outputs import PlanesMcap, save_depth_png, save_npz
from kosmap.mapping.planes.stats import StatsTable
from kosmap.mapping.runtime.outdir import writing

# what a run writes: a later run replaces these (and only these) of the previous run's
PLANES_FILES = ("config.toml", "stats.csv", "planes.mcap", "mount.toml", "summary.json", "planes/*.npz",
                "depth/*.png", "figures/*.png")


@dataclass(frozen=True)
class PlanesOptions:
    """What a run writes besides stats.csv, config.toml and summary.json."""

    save_depth: bool = False  # depth/NNNNNN.png: the plane points' depth, 16-bit mm
    figures: int = 3  # how many frames get a Fig. 5.2-style figure (spread over the run)
    mcap: bool = True  # planes.mcap
    npz: bool = True  # planes/NNNNNN.npz
    mcap_points: int = 30000  # at most this many plane points per frame in planes.mcap


def run_planes(path: Path, out: Path, cfg, source: FrameSource, opts: PlanesOptions = PlanesOptions(),
               on_progress: Callable[[int, int], None] | None = None) -> dict:
    """Filter every frame of `source` (read from `path`) into `out`; returns the summary (also summary.json).

    The first frame is read before anything is written; the outputs go to a staging folder in `out` and replace
    the previous run's only when the run succeeds, so a failure leaves none (and the previous run's as they
    were). `on_progress(done, total)` after each frame."""
    try:
        frames = _first_frame(path, source.frames)
        with writing(out, PLANES_FILES, inputs=(path,), command="planes") as stage:
            return _filter_into(path, stage, cfg, replace(source, frames=frames), opts, on_progress)
    finally:
        source.frames.close()  # the log reader, if the frames stopped early


def _first_frame(path: Path, frames: Iterator[Item]) -> Iterator[Item]:
    """Read the first frame before writing anything (an unreadable first image or no frame at all fails here)."""
    first = next(frames, None)
    if first is None:
        raise KosmapError(f"{path} yielded no depth frames; check --every/--max-frames and the depth topic")
    return itertools.chain([first], frames)


class FrameOutputs:
    """The per-frame files of a run: planes/NNNNNN.npz, depth/NNNNNN.png, figures/NNNNNN.png, planes.mcap."""

    def __init__(self, out: Path, cfg, opts: PlanesOptions, total: int) -> None:
        self.out, self.opts = out, opts
        self.depth_range = (cfg.depth.min_depth, cfg.depth.max_depth)
        self.fig_step = max(1, -(-total // opts.figures)) if opts.figures > 0 else 0
        self.mcap = PlanesMcap(out / "planes.mcap", opts.mcap_points) if opts.mcap else None

    def write(self, n: int, planes: Planes, item: Item) -> None:
        name = f"{n:06d}"
        if self.opts.npz:
            (self.out / "planes").mkdir(exist_ok=True)
            save_npz(self.out / "planes" / f"{name}.npz", planes, item)
        if self.opts.save_depth:
            (self.out / "depth").mkdir(exist_ok=True)
            save_depth_png(self.out / "depth" / f"{name}.png", planes)
        if self.fig_step and n % self.fig_step == 0:
            from kosmap.mapping.planes.figures import plane_figure

            plane_figure(planes, self.out / "figures" / f"{name}.png", f"{item.source}", self.depth_range)
        if self.mcap is not None:
            self.mcap.write(planes, item, n)

    def close(self) -> None:
        if self.mcap is not None:
            self.mcap.close()

    def abort(self) -> None:
        if self.mcap is not None:
            self.mcap.abort()


def _filter_into(path: Path, out: Path, cfg, source: FrameSource, opts: PlanesOptions,
                 on_progress: Callable[[int, int], None] | None) -> dict:
    """Filter the frames and write every output into `out` (the run's staging folder); returns the summary."""
    write_config(cfg, out / "config.toml")
    warmup(cfg.fspf.method)
    warnings = source.warnings
    files = FrameOutputs(out, cfg, opts, source.total)
    keep_all = replace(cfg.fspf, drop_classes=[])  # classes are settled after the filter (gravity), then dropped
    classes, table = Classes(cfg), StatsTable()
    empty = 0  # frames without an eligible pixel
    try:
        for n, item in enumerate(source.frames):
            if n == 0:
                warmup(cfg.fspf.method, item.depth.shape)  # elapsed_ms: no compiling, no first touch of buffers
            planes = filter_planes(item.depth, item.camera, keep_all, cfg.depth, item.mount,
                                   seed=frame_seed(cfg.fspf, item.index))
            planes = classes(planes, item)
            if planes.stats.eligible == 0:
                empty += 1
                if empty == 1:
                    note(warnings, f"frame {n:06d} ({item.source}) has no eligible pixel: "
                                   + no_eligible_cause(item.depth, cfg.depth.min_depth, cfg.depth.max_depth))
            table.add(f"{n:06d}", item, planes, classes.floor_m)
            files.write(n, planes, item)
            if on_progress is not None:
                on_progress(n + 1, source.total)
    except BaseException:
        files.abort()
        raise
    files.close()
    if empty > 1:
        note(warnings, f"{empty} of {len(table)} frames had no eligible pixel")
    table.write_csv(out / "stats.csv")
    mount_est = classes.mount_estimate(warnings)
    summary = table.summary(path, cfg, classes.used, mount_est, warnings)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if mount_est is not None:
        (out / "mount.toml").write_text(f"# the depth camera's mount as the floor planes of {path.name} show it\n"
                                        f"# on /tf_static: {mount_est['tf_static']}\n{mount_est['config']}")
    return summary


def no_eligible_cause(depth_m: np.ndarray, min_depth: float, max_depth: float) -> str:
    """Why a frame has no pixel within [min_depth, max_depth]: the likely cause, in one sentence."""
    d = np.asarray(depth_m, np.float64)
    valid = d[np.isfinite(d) & (d > 0)]
    if not valid.size:
        return "it holds no depth at all (every pixel 0 or NaN)"
    med = float(np.median(valid))
    if med > max_depth:
        return (f"its median depth reads {med:.3g} m, beyond [depth] max_depth {max_depth:g} m: the depth scale is "
                f"likely too small (--depth-scale is image units per metre, or below 1 metres per unit)")
    return (f"its median depth reads {med:.3g} m, nearer than [depth] min_depth {min_depth:g} m: the depth scale is "
            f"likely too large (an image already in metres read as millimetres?), or lower depth.min_depth")
