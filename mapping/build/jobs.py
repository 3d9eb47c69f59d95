"""The job pool of pass 2: independent jobs (one grid, one comparison) in the frame pool's forked worker
processes, in a pool of their own for a log without depth, or here when the build is serial."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from kosmap.frontend.records import Scan
from kosmap.mapping.grid import GridBuilder
from kosmap.mapping.runtime.childproc import die_with_parent


def _init_job_worker(parent_pid: int) -> None:
    """A grid or comparison worker of a log without depth: Ctrl-C is the parent's; it dies with the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid)


class Jobs:
    """Independent jobs (one grid, one comparison) in `workers` forked processes (the frame pool's `executor` when
    given: not shut down here), or here when workers = 0; results in submission order. The jobs read the spill
    from disk, so nothing large is copied to them."""

    def __init__(self, workers: int, executor=None) -> None:
        self.ex = executor if workers > 0 else None
        self.own = False
        if workers > 0 and self.ex is None:
            self.own = True
            ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
            self.ex = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_job_worker,
                                          initargs=(os.getpid(),))

    def submit(self, fn, *args):
        if self.ex is None:
            return Done(fn(*args))
        return self.ex.submit(fn, *args)

    def close(self) -> None:
        if self.ex is not None and self.own:
            self.ex.shutdown(wait=True, cancel_futures=True)


class Done:
    """A job run here (workers = 0): its result, as a finished future."""

    def __init__(self, v) -> None:
        self.v = v

    def done(self) -> bool:
        return True

    def result(self):
        return self.v


def warm_grid() -> None:
    """Compile (or load) the grid kernel here, before forking: the jobs inherit it instead of compiling each."""
    GridBuilder().add(np.zeros(3), Scan(0, np.array([1.0, np.inf], np.float32), 0.0, 0.1, 0.1, 10.0))

