"""`kosmap batch`: many logs, each through the same build as `kosmap build`, skipped when nothing changed.

A log is one task (`BatchTask`). `run_task` runs on whichever process the scheduler gives it (a Dask worker,
mapping/cluster.py, or this process) and returns a `LogRecord`: built, skipped or failed, with the numbers of its
metrics.json. Its folder `DIR/<name>/` holds exactly what `kosmap build` writes there; what the batch needs to
skip it next time lives apart, in `DIR/.kosmap-batch/<name>.json` (`BuildState`): content hashes (SHA-256) of
the log, the blueprint, the effective config and every output file. A re-run skips a log whose inputs and
config hash the same and whose outputs are all there with the hashes they had; anything else is built again.
One log's failure is its record's error line, never the batch's.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from kosmap.frontend.errors import KosmapError
from kosmap.mapping.config import Config, config_dict
from kosmap.mapping.runtime.outdir import MANIFEST

LOG_SUFFIXES = (".mcap", ".bag", ".clf")
STATE_DIR = ".kosmap-batch"  # in DIR: one BuildState per log
TOL = "0.10"  # the tolerance of the table's F1 (the build's headline tolerance)


class BatchError(KosmapError):
    """Logs a batch cannot take (none found, two of one name, a list naming a missing file)."""


@dataclass(frozen=True)
class BatchTask:
    """One log to build into `out` (DIR/<name>), with what the build needs; pickled to the worker."""

    name: str
    log: Path
    out: Path
    state: Path  # DIR/.kosmap-batch/<name>.json
    cfg: Config
    blueprint: Path | None = None
    blueprint_scale: float | None = None
    reads: tuple[Path, ...] = ()  # --config: read by the build, never an output
    workers: int | None = None  # the build's frame workers (None: every core of the machine it runs on)


@dataclass
class BuildState:
    """What a finished build of one log was made from and what it wrote (content hashes)."""

    inputs: dict[str, str]  # "log", "blueprint", "config" → SHA-256
    outputs: dict[str, str]  # file name in DIR/<name> → SHA-256


@dataclass
class LogRecord:
    """One log's line in the batch table."""

    name: str
    log: str
    status: str  # "built", "skipped" (unchanged since the last batch) or "failed"
    error: str | None = None  # the one-line error of a failed log
    duration_s: float | None = None  # of log
    build_s: float | None = None  # wall time of the build (as its report says; of the last one when skipped)
    check_s: float | None = None  # hashing the inputs and outputs (of a skipped log: all the work it cost)
    realtime_factor: float | None = None
    f1: dict[str, float] = field(default_factory=dict)  # "<map>" → F1 at 0.10 m against the blueprint
    f1_seen: dict[str, float] = field(default_factory=dict)  # the same over the walls the run saw
    ate: dict[str, float] = field(default_factory=dict)  # "kos" / "laser" → ATE RMSE (m), with ground truth
    warnings: list[str] = field(default_factory=list)
    maps: list[str] = field(default_factory=list)  # the maps the build made (map_<name>.yaml)
    worker_note: str | None = None  # how the build ran when it could not start its own processes

    @property
    def ok(self) -> bool:
        return self.status != "failed"

    def as_dict(self) -> dict:
        return asdict(self)


# ---- the logs of a batch ------------------------------------------------------------------------------------------

def find_logs(items: list[Path], list_file: Path | None = None, exclude: Path | None = None) -> list[Path]:
    """The logs named by `items` (log files, or folders searched recursively for .mcap/.bag/.clf) and by
    `list_file` (one path a line, relative to the list's folder; # starts a comment), in that order, each once;
    files under `exclude` (the output folder), and in a folder searched, the outputs of kosmap runs (a folder with
    a kosmap manifest: a build's kosmap.mcap) are left out."""
    found: list[Path] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            found += sorted(q for q in p.rglob("*") if q.suffix in LOG_SUFFIXES and q.is_file()
                            and not (q.parent / MANIFEST).exists())
        elif p.exists():
            found.append(p)
        else:
            raise BatchError(f"{p} does not exist; give log files, a folder of logs, or --list FILE")
    if list_file is not None:
        try:
            lines = Path(list_file).read_text().splitlines()
        except OSError as e:
            raise BatchError(f"--list {list_file}: {e.strerror or e}; give a text file with one log path a line") from e
        for k, line in enumerate(lines, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            p = Path(text) if Path(text).is_absolute() else Path(list_file).parent / text
            if not p.is_file():
                raise BatchError(f"--list {list_file} line {k}: {text} is not a file; fix the line or remove it")
            found.append(p)
    ex = exclude.resolve() if exclude is not None else None
    out, seen = [], set()
    for p in found:
        r = p.resolve()
        if r in seen or (ex is not None and r.is_relative_to(ex)):
            continue
        seen.add(r)
        out.append(p)
    if not out:
        raise BatchError("no logs to build: give .mcap, .bag or .clf files, a folder holding some, or --list FILE")
    return out


def task_names(logs: list[Path]) -> list[str]:
    """Each log's folder name: its file name without the suffix; where two logs share one, their parent folder's
    name is put in front (robot1-run.mcap, robot2-run.mcap). Names that still collide are refused."""
    stems = [p.stem for p in logs]
    names = [f"{p.parent.name}-{p.stem}" if stems.count(p.stem) > 1 else p.stem for p in logs]
    for n in set(names):
        if names.count(n) > 1 or n in (STATE_DIR, "") or n.startswith("."):
            same = [str(p) for p, m in zip(logs, names) if m == n]
            raise BatchError(f"logs {', '.join(same[:3])} would share the output folder {n!r}; rename them so that "
                             f"their names (or their folders' names) differ")
    return names


# ---- content hashes ---------------------------------------------------------------------------------------------

def file_hash(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def config_hash(cfg: Config, blueprint_scale: float | None) -> str:
    """The effective config (every stage's values) and the build's other map-changing argument."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("kosmap")
    except PackageNotFoundError:
        v = "unknown"
    doc = {"config": config_dict(cfg), "blueprint_scale": blueprint_scale, "kosmap": v}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def input_hashes(task: BatchTask) -> dict[str, str]:
    h = {"log": file_hash(task.log), "config": config_hash(task.cfg, task.blueprint_scale)}
    if task.blueprint is not None:
        bp = Path(task.blueprint)
        parts = [file_hash(bp)] + [file_hash(q) for q in (bp.with_suffix(".png"), bp.with_suffix(".pgm"))
                                   if q != bp and q.is_file()]  # a map_server YAML's image
        h["blueprint"] = hashlib.sha256("".join(parts).encode()).hexdigest()
    return h


def output_hashes(out: Path) -> dict[str, str] | None:
    """Hashes of the files the build's manifest lists (and of the manifest); None when it lists none, is
    unreadable, or does not describe one finished, complete build (in progress, being moved in, partial)."""
    try:
        listed = json.loads((out / MANIFEST).read_text())
        names = list(listed["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not names or listed.get("kosmap", "build") != "build" or any(
            listed.get(k) for k in ("in_progress", "committing", "partial")):
        return None
    try:
        return {n: file_hash(out / n) for n in [*names, MANIFEST]}
    except OSError:
        return None


def read_state(path: Path) -> BuildState | None:
    try:
        d = json.loads(Path(path).read_text())
        return BuildState(dict(d["inputs"]), dict(d["outputs"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_state(path: Path, state: BuildState) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(asdict(state), indent=1) + "\n")
    os.replace(tmp, path)


def up_to_date(state: BuildState | None, inputs: dict[str, str], out: Path) -> bool:
    """The last build used these inputs and its outputs are all there, unchanged."""
    return state is not None and state.inputs == inputs and output_hashes(out) == state.outputs


# ---- one task -------------------------------------------------------------------------------------------------------

def summarise(rec: LogRecord, metrics: dict) -> LogRecord:
    """The table's numbers from a build's metrics.json."""
    from kosmap.mapping.report import run_warnings

    t = metrics.get("timing", {})
    rec.duration_s = metrics.get("log", {}).get("duration_s")
    rec.build_s = t.get("total_s")
    rec.realtime_factor = t.get("realtime_factor")
    for key, c in metrics.get("comparisons", {}).items():
        tol = c.get("tolerances", {}).get(TOL)
        if c.get("b") == "blueprint" and tol:
            rec.f1[c["a"]] = tol["f1"]
            if tol.get("f1_observed") is not None:
                rec.f1_seen[c["a"]] = tol["f1_observed"]
    rec.ate = {k: s["ate"]["rmse"] for k, s in metrics.get("slam", {}).items() if s.get("ate")}
    rec.warnings = run_warnings(metrics)
    rec.maps = sorted(metrics.get("maps", {}))
    return rec


def _frame_workers(task: BatchTask) -> tuple[int | None, str | None]:
    """A daemonic process (a Dask worker started without `distributed.worker.daemon: False`) may not start child
    processes: such a build runs serially, with the same maps (mapping/build/), and the record says why."""
    if mp.current_process().daemon and task.workers != 0:
        return 0, ("serial: this worker is a daemonic process, which may not start the build's processes (start dask "
                   "workers with DASK_DISTRIBUTED__WORKER__DAEMON=False)")
    return task.workers, None


def run_task(task: BatchTask) -> LogRecord:
    """Build one log unless its last build is up to date; never raises for the log's own faults."""
    from kosmap.mapping.build import build

    t0 = time.perf_counter()
    rec = LogRecord(task.name, str(task.log), "built")
    try:
        inputs = input_hashes(task)
        state = read_state(task.state)
        if up_to_date(state, inputs, task.out):
            rec = summarise(LogRecord(task.name, str(task.log), "skipped"),
                            json.loads((task.out / "metrics.json").read_text()))
            rec.check_s = time.perf_counter() - t0
            return rec
        Path(task.state).unlink(missing_ok=True)  # whatever happens now, the last build no longer stands
        workers, rec.worker_note = _frame_workers(task)
        res = build(task.log, task.out, task.cfg, blueprint=task.blueprint, workers=workers,
                    say=None, blueprint_scale=task.blueprint_scale, reads=task.reads)
        outputs = output_hashes(task.out)
        if outputs is not None:
            write_state(Path(task.state), BuildState(inputs, outputs))
        return summarise(rec, res.metrics)
    except KosmapError as e:
        rec.status, rec.error = "failed", str(e)
    except OSError as e:  # a path the system refuses: one line, as the CLI says it
        rec.status, rec.error = "failed", f"{e.filename or ''}: {e.strerror or e}".lstrip(": ")
    except Exception as e:  # a fault in the build itself: the other logs go on; its kind and message are kept
        rec.status, rec.error = "failed", f"internal error ({type(e).__name__}: {e}); please report it with the log"
    rec.build_s = time.perf_counter() - t0
    return rec
