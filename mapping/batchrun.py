"""`kosmap batch` from end to end: the logs, their builds on a Dask cluster (mapping/cluster.py), then the fleet's
merged map, change map and table (mapping/batchreport.py).

DIR holds one folder per log, exactly as `kosmap build` leaves it, the skip state in DIR/.kosmap-batch/ (mapping/
batch.py), and the batch's own files (batchreport.BATCH_FILES), which a re-run replaces like `kosmap build`
replaces its own (mapping/runtime/outdir.py, command "batch").
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from kosmap.mapping.batch import STATE_DIR, BatchTask, LogRecord, find_logs, task_names
from kosmap.mapping.batchreport import BATCH_FILES, fleet_map_name, fleet_outputs, summary, write_batch_report
from kosmap.mapping.config import Config
from kosmap.mapping.runtime.outdir import check_out, previous_outputs, writing


@dataclass
class BatchResult:
    records: list[LogRecord]
    doc: dict  # what batch.json holds

    @property
    def failed(self) -> list[LogRecord]:
        return [r for r in self.records if not r.ok]


@dataclass(frozen=True)
class BatchOptions:
    blueprint: Path | None = None
    blueprint_scale: float | None = None
    scheduler: str | None = None  # tcp://host:8786; None: a LocalCluster
    workers: int | None = None  # builds at once on a LocalCluster (None: sized to the machine)
    map_name: str | None = None  # the map merged and compared (None: the KOS SLAM map, else the laser map)
    reads: tuple[Path, ...] = ()  # --config


def plan(items: list[Path], list_file: Path | None, out: Path, cfg: Config, opt: BatchOptions,
         build_workers: int | None) -> list[BatchTask]:
    """One task per log, every path absolute (the workers may run elsewhere in the tree)."""
    logs = find_logs(items, list_file, exclude=out)
    state = out.absolute() / STATE_DIR
    bp = None if opt.blueprint is None else Path(opt.blueprint).absolute()
    return [BatchTask(n, p.absolute(), out.absolute() / n, state / f"{n}.json", cfg, bp, opt.blueprint_scale,
                      tuple(Path(r).absolute() for r in opt.reads), build_workers)
            for n, p in zip(task_names(logs), logs)]


def run_batch(items: list[Path], list_file: Path | None, out: Path, cfg: Config, opt: BatchOptions,
              on_start: Callable[[int, str], None] | None = None,
              on_done: Callable[[LogRecord], None] | None = None) -> BatchResult:
    """Build every log (skipping the unchanged), then merge and compare the runs and write the table.
    `on_start(n_logs, where)` once the cluster is up; `on_done(record)` as each log finishes."""
    from kosmap.mapping.cluster import check_dask, client, local_sizing, run_tasks

    t0 = time.perf_counter()
    check_dask()  # before any work: without Dask there is nothing to run the builds on
    out = check_out(out)
    previous_outputs(out, "batch")  # another command's folder: refused before any work
    bp_grid = None
    if opt.blueprint is not None:
        from kosmap.mapping.mapio import read_blueprint

        bp_grid = read_blueprint(opt.blueprint, opt.blueprint_scale, cfg.compare.blueprint_dark)
    sizing = local_sizing(opt.workers)
    tasks = plan(items, list_file, out, cfg, opt, None if opt.scheduler else sizing.build_workers)
    inputs = tuple(t.log for t in tasks) + tuple(x for x in (opt.blueprint, *opt.reads) if x is not None)
    # the cluster first: a scheduler that does not answer leaves nothing behind in DIR
    with client(opt.scheduler, sizing) as c, writing(out, BATCH_FILES, inputs=inputs, command="batch") as stage:
        dest = Path(stage) if stage is not None else out  # the batch's own files, put in place when all are written
        where = (f"the Dask scheduler {opt.scheduler}" if opt.scheduler else f"a local Dask cluster of "
                 f"{sizing.workers} worker(s), {sizing.build_workers} process(es) per build")
        if on_start is not None:
            on_start(len(tasks), where)
        records = run_tasks(c, tasks, on_done)
        map_name = fleet_map_name(records, cfg, opt.map_name)
        doc = {"kosmap": "batch", "summary": summary(records), "logs": [r.as_dict() for r in records],
               "cluster": {"scheduler": opt.scheduler or "local", "where": where,
                           "workers": None if opt.scheduler else sizing.workers,
                           "build_workers": None if opt.scheduler else sizing.build_workers},
               "fleet": fleet_outputs(out, dest, records, bp_grid, cfg, map_name)}
        doc["wall_s"] = time.perf_counter() - t0
        write_batch_report(dest, doc)
    return BatchResult(records, doc)
