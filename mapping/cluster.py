"""The Dask side of `kosmap batch`: a cluster to run the builds on, and the tasks' results as they finish.

By default a `LocalCluster` of worker processes on this machine; with an address, an existing cluster (`dask
scheduler` on one machine, `dask worker tcp://HOST:8786` on each of the others, all seeing the logs and DIR under
the same paths). A build starts processes of its own (FSPF+/KOS workers, one per SLAM): the local workers are
started non-daemonic (`distributed.worker.daemon: False`) so that they may; a daemonic worker of an existing
cluster builds serially instead (mapping/batch.py). Dask is the optional extra `kosmap[cluster]`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from kosmap.frontend.errors import KosmapError
from kosmap.mapping.batch import BatchTask, LogRecord, run_task

BUILD_MEMORY_GB = 1.5  # one build's peak resident memory over its processes, with headroom (docs/scale.md)


class ClusterError(KosmapError):
    """Dask missing, or a scheduler that cannot be reached."""


@dataclass(frozen=True)
class Sizing:
    """How a local cluster shares this machine: `workers` builds at once, each with `build_workers` processes."""

    workers: int
    build_workers: int


def machine_sizing(cores: int, memory_gb: float | None, workers: int | None = None) -> Sizing:
    """Builds at once and processes per build for a machine: a build keeps about two cores busy (its reading
    process and its frame workers), so one build per two cores, no more than the memory holds at BUILD_MEMORY_GB
    each; `workers` given: that many builds, the cores shared among them."""
    cores = max(1, int(cores))
    if workers is None:
        workers = max(1, cores // 2)
        if memory_gb:
            workers = max(1, min(workers, int(memory_gb // BUILD_MEMORY_GB)))
    workers = max(1, int(workers))
    return Sizing(workers, max(1, cores // workers))


def _memory_gb() -> float | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e9
    except (ValueError, OSError, AttributeError):
        return None


def local_sizing(workers: int | None) -> Sizing:
    return machine_sizing(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1,
                          _memory_gb(), workers)


def check_dask() -> None:
    """ClusterError (saying how to install it) when dask.distributed is missing."""
    _import_distributed()


def _import_distributed():
    try:
        import dask
        import distributed
    except ImportError as e:
        raise ClusterError("kosmap batch runs on Dask, which is not installed; install it with "
                           "pip install 'kosmap[cluster]' (or pip install 'dask[distributed]')") from e
    return dask, distributed


@contextmanager
def client(scheduler: str | None, sizing: Sizing) -> Iterator[object]:
    """A dask.distributed Client: on a new LocalCluster of `sizing.workers` single-threaded, non-daemonic worker
    processes, or connected to `scheduler` (tcp://host:8786)."""
    import logging

    dask, distributed = _import_distributed()
    if scheduler:
        try:
            c = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise ClusterError(f"--scheduler {scheduler}: no Dask scheduler answers there ({e}); start one with "
                               f"`dask scheduler` or leave --scheduler out for a local cluster") from e
        try:
            yield c
        finally:
            c.close()
        return
    with dask.config.set({"distributed.worker.daemon": False, "distributed.scheduler.allowed-failures": 0,
                          "logging.distributed": "error"}):
        cluster = distributed.LocalCluster(n_workers=sizing.workers, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.ERROR)
        try:
            with distributed.Client(cluster) as c:
                yield c
        finally:
            cluster.close()


def run_tasks(c, tasks: list[BatchTask], on_done: Callable[[LogRecord], None] | None = None) -> list[LogRecord]:
    """Every task on the cluster (each once, no retries: a build that killed its worker is not run again);
    `on_done` sees each record as it finishes; the records come back in the tasks' order."""
    import uuid

    from distributed import as_completed

    run = uuid.uuid4().hex[:8]  # a key per batch run, so a re-run is computed again, never served from before
    futures = [c.submit(run_task, t, key=f"kosmap-build-{t.name}-{run}", pure=False, retries=0) for t in tasks]
    by_key = {f.key: (k, t) for k, (f, t) in enumerate(zip(futures, tasks))}
    records: list[LogRecord | None] = [None] * len(tasks)
    for fut in as_completed(futures):
        k, t = by_key[fut.key]
        try:
            rec = fut.result()
        except Exception as e:  # the worker died under it (killed, out of memory): the others go on
            rec = LogRecord(t.name, str(t.log), "failed",
                            error=f"the Dask worker building it died ({type(e).__name__}: {e})")
        records[k] = rec
        if on_done is not None:
            on_done(rec)
    return [r for r in records if r is not None]
