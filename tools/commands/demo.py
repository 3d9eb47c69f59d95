"""`kosmap demo` (what `make demo` runs): simulate the bundled office once (cached), build every map, compare them
with the blueprint and with each other, print where the report is and its headline numbers.

The demo log is the bundled office path (140 m, 361 s, two loops) with the Kinect at 5 Hz and the laser at 10 Hz
(the simulator's defaults are 30 and 40 Hz): simulating the default rates takes ~5 min on two cores and
3 GB, building them ~3 min; at these rates both fit in `make demo`'s three minutes on a fresh machine.
The log and its blueprint are cached under .kosmap-cache/demo/ in the repository, keyed by the settings.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.tools import options as O
from kosmap.tools.data import REPO
from kosmap.tools.progress import seconds_bar

DEMO_WORLD = "office"
DEMO_SIM = {"seed": 1, "depth_rate": 5.0, "laser_rate": 10.0, "compression": "lz4"}
CACHE = REPO / ".kosmap-cache" / "demo"


WARM_UP = """
import pathlib, shutil, sys, tempfile
import numpy as np
from kosmap.mapping.build import build
from kosmap.mapping.config import Config
from kosmap.mapping.mapio import write_map_server
from kosmap.tools.simulate import SimConfig, load_world, simulate
from kosmap.tools.simulate.world import PathSpec
d = pathlib.Path(tempfile.mkdtemp(prefix="kosmap-warmup-"))
try:
    w = load_world("room")
    laps = PathSpec(np.vstack([w.path.waypoints[:5]] * 3))  # three laps at 3 Hz: both SLAMs search for loops
    simulate(w, SimConfig(depth_rate=3.0, laser_rate=5.0, speed_min=0.6, speed_max=0.6), d / "room.mcap", laps)
    bp = write_map_server(w.blueprint(0.05), d / "bp.yaml", ".png")
    build(d / "room.mcap", d / "out", Config(), blueprint=bp, workers=0)
finally:
    shutil.rmtree(d, ignore_errors=True)
"""


def warm_up():
    """A small build of the room (three laps, so that both SLAMs search for loops) in another process, so that numba
    compiles (and caches) every kernel of the pipeline while this process simulates the office: on a fresh
    machine compiling costs over a minute of CPU."""
    import subprocess

    return subprocess.Popen([sys.executable, "-c", WARM_UP], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            cwd=str(REPO))


def demo_log(cache: Path | None = None, fresh: bool = False, quiet: bool = False,
             path: str | None = None) -> tuple[Path, Path, float | None]:
    """The demo's log and blueprint, simulated once per settings, path (None: the world's default; or one of its
    named paths, e.g. "survey") and world file into `cache` (default .kosmap-cache/demo); (log, blueprint.yaml,
    seconds spent simulating or None when cached)."""
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    cache = Path(cache) if cache is not None else CACHE

    cfg = SimConfig(**DEMO_SIM)
    world = load_world(DEMO_WORLD)
    way = None if path is None else world.paths[path]
    world_file = Path(__file__).resolve().parents[1] / "simulate" / "worlds" / f"{DEMO_WORLD}.yaml"
    key = hashlib.sha1(json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode()
                       + (world_file.read_bytes() if world_file.is_file() else b"")).hexdigest()[:10]
    stem = DEMO_WORLD if path is None else f"{DEMO_WORLD}_{path}"
    log = cache / f"{stem}-{key}.mcap"
    bp = cache / f"{DEMO_WORLD}-blueprint.yaml"
    if not bp.is_file() or fresh:
        write_map_server(world.blueprint(0.05), bp, ".png")
    if log.is_file() and not fresh:
        return log, bp, None
    cache.mkdir(parents=True, exist_ok=True)
    for old in cache.glob(f"{stem}-*.mcap"):  # a cache of other settings
        old.unlink()
    t0 = time.perf_counter()
    warming = warm_up()
    with seconds_bar(f"simulating the {DEMO_WORLD}", "{task.fields[t]:.0f} s of log", quiet) as tick:
        simulate(world, cfg, log, way, progress=tick)
    warming.wait()  # the build must not compile the same kernels beside it
    return log, bp, time.perf_counter() - t0


def register(app: typer.Typer) -> None:
    @app.command()
    def demo(
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder of the build.")] = Path("demo_out"),
        workers: Annotated[Optional[int], typer.Option("--workers", "-j", help="Processes for FSPF+ and KOS (default: every core).")] = None,
        fresh: Annotated[bool, typer.Option("--fresh", help="Simulate the log again even if it is cached.")] = False,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Only the headline.")] = False,
        survey: Annotated[bool, typer.Option("--survey", help="Drive the office's survey path instead: into every room "
                                             "(23 min of log; ~7 min to simulate and build on 2 cores).")] = False,
    ) -> None:
        """Simulate the bundled office (Kinect + laser + wheel odometry, cached after the first run), build its KOS
        and laser maps, compare them with the blueprint and each other; print where the report is."""
        from kosmap.mapping.build import build
        from kosmap.mapping.config import Config
        from kosmap.tools.commands.build import print_headline
        from kosmap.tools.progress import build_bar

        t0 = time.perf_counter()
        log, bp, sim_s = demo_log(fresh=fresh, quiet=quiet, path="survey" if survey else None)
        if not quiet:
            print(f"log: {log} " + ("(cached)" if sim_s is None else f"(simulated in {sim_s:.0f} s)"), file=sys.stderr)
        with build_bar(quiet) as tick:
            res = build(log, out, Config(), blueprint=bp, workers=workers, on_progress=tick,
                        say=None if quiet else (lambda m: print(m, file=sys.stderr)))
        print(f"kosmap demo: the {DEMO_WORLD}{' survey' if survey else ''} ({res.metrics['log']['duration_s']:.0f} s, Kinect at "
              f"{DEMO_SIM['depth_rate']:g} Hz, laser at {DEMO_SIM['laser_rate']:g} Hz) mapped in "
              f"{time.perf_counter() - t0:.0f} s")
        print_headline(res.metrics, out)
