"""`kosmap batch LOG… | DIR | --list FILE --out DIR`: every log through `kosmap build` on a Dask cluster, then the
runs merged into one map and compared for changes (mapping/batchrun.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.frontend.errors import KosmapError
from kosmap.tools import options as O


def status_line(r) -> str:
    """One log's line as it finishes."""
    if not r.ok:
        return f"FAILED  {r.name}: {r.error}"
    f1 = " ".join(f"F1 {m} {v:.3f}" for m, v in list(r.f1.items())[:2])
    rt = f", {r.realtime_factor:.1f}× real time" if r.realtime_factor else ""
    what = "built  " if r.status == "built" else "skipped"
    tail = f" (unchanged; {r.check_s:.1f} s to check)" if r.status == "skipped" else f" in {r.build_s:.1f} s{rt}"
    note = f" [{r.worker_note}]" if r.worker_note else ""
    return f"{what} {r.name}{tail}" + (f"; {f1}" if f1 else "") + note


def register(app: typer.Typer) -> None:
    @app.command()
    def batch(
        logs: Annotated[Optional[list[Path]], typer.Argument(help="Logs (.mcap, .bag, .clf), or folders searched for them.")] = None,
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder: one build folder per log, batch.html/.md/.json, the merged and change maps.")] = Path("batch_out"),
        list_file: Annotated[Optional[Path], typer.Option("--list", help="A text file naming one log a line (relative to the file; # comments).")] = None,
        blueprint: Annotated[Optional[Path], typer.Option("--blueprint", help="Floor blueprint (map_server .yaml, or an image with --blueprint-scale): every build compares with it and the runs are aligned onto it.")] = None,
        blueprint_scale: Annotated[Optional[float], typer.Option("--blueprint-scale", help="Metres per pixel of a plain-image blueprint.")] = None,
        scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="An existing Dask scheduler (tcp://host:8786); default: a local cluster on this machine.")] = None,
        workers: Annotated[Optional[int], typer.Option("--workers", "-j", help="Builds at once on the local cluster (default: one per two cores, as memory allows); the cores are shared among them.")] = None,
        map_name: Annotated[Optional[str], typer.Option("--map", help="The map merged and compared across runs, e.g. kos_obstacle (default: the laser map when every run has one, else the KOS map SLAM ran on).")] = None,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or status lines.")] = False,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, depth_topic: O.DepthTopicOpt = None,
        info_topic: O.InfoTopicOpt = None, scan_topic: O.ScanTopicOpt = None, odom_topic: O.OdomTopicOpt = None,
        imu_topic: O.ImuTopicOpt = None,
    ) -> None:
        """Every log through `kosmap build` (DIR/<log name>/ holds what it writes) as tasks on Dask; a re-run skips
        the logs whose inputs, config and outputs are unchanged. Then the runs' maps are aligned (onto the blueprint
        or the first run), merged, and compared for changes. Exit code 1 when a log failed (the others are built)."""
        from kosmap.mapping.batchrun import BatchOptions, run_batch

        if not logs and list_file is None:
            raise KosmapError("give logs, a folder of logs, or --list FILE")
        if blueprint_scale is not None and blueprint is None:
            raise KosmapError("--blueprint-scale belongs to --blueprint (a plain image's metres per pixel)")
        if workers is not None and workers < 1:
            raise KosmapError(f"--workers {workers}: give 1 or more builds at once")
        if workers is not None and scheduler:
            raise KosmapError("--workers sizes the local cluster; an existing cluster (--scheduler) has its own workers")
        cfg = O.make_config(config, set_, depth_topic, info_topic, scan_topic, odom_topic, imu_topic)
        opt = BatchOptions(blueprint, blueprint_scale, scheduler, workers, map_name, () if config is None else (config,))
        from kosmap.tools.progress import count_bar

        say = (lambda m: None) if quiet else (lambda m: print(m, file=sys.stderr))
        with count_bar("batch", "logs", quiet) as bar:
            def on_start(n: int, where: str) -> None:
                bar.start(n)
                bar.say(f"{n} log(s) on {where}")

            def on_done(r) -> None:
                bar.advance(status_line(r))

            res = run_batch(list(logs or []), list_file, out, cfg, opt, on_start, on_done)
        fl = res.doc["fleet"]
        if fl.get("error"):
            say(f"no merged map: {fl['error']}")
        else:
            f1 = f", F1 {fl['merged']['f1']:.3f} against the blueprint" if "f1" in fl["merged"] else ""
            say(f"merged {fl['merged']['runs']} run(s) of {fl['map']}{f1}; {len(fl['changes']['regions'])} changed region(s)")
        say(f"report: {out / 'batch.html'} (and batch.md, batch.json; map_merged.*, changes.* in {out})")
        if res.failed:
            raise typer.Exit(1)
