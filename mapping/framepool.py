"""The per-frame stage on several cores: `kos_frame` over depth frames in a process pool, results in order.

A frame's result is a pure function of the frame and the configs (frontend/kosframe.py: its seed comes from its
index), so the pool gives exactly what a serial run gives. `workers = 0` runs each frame in this process at
`submit`, through the same queue, so the serial and parallel paths share every line but the call itself. At
most `in_flight` frames are outstanding (each ~0.9 MB of depth), so memory does not grow with the log.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from frontend.camera import DepthConfig
from frontend.depthstream import DepthItem
from frontend.errors import KosmapError
from frontend.fspf import FspfConfig, warmup
from frontend.kos import Bearings, KosConfig
from frontend.kosframe import KosFrame, kos_frame

_CONFIGS: tuple | None = None  # (fspf, depth, kos) configs of this worker process


def _init_worker(configs: tuple) -> None:
    """Worker start: Ctrl-C is the parent's to handle (it writes the partial outputs); load the numba kernels."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    global _CONFIGS
    _CONFIGS = configs
    warmup()


def _ping() -> int:
    return os.getpid()


def _work(item: DepthItem, bearings: Bearings, keep_planes: bool) -> KosFrame:
    fspf_cfg, depth_cfg, kos_cfg = _CONFIGS  # type: ignore[misc]
    return kos_frame(item, fspf_cfg, depth_cfg, kos_cfg, bearings, keep_planes=keep_planes)


def default_workers() -> int:
    """All the cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


class FramePool:
    """FSPF+ → KOS per frame, serial (`workers = 0`) or in `workers` processes; results come back in submission
    order with the tag given at submission."""

    def __init__(self, fspf_cfg: FspfConfig, depth_cfg: DepthConfig, kos_cfg: KosConfig, workers: int = 0,
                 in_flight: int | None = None) -> None:
        if workers < 0:
            raise KosmapError(f"--workers {workers} must be 0 (serial) or more")
        self.configs = (fspf_cfg, depth_cfg, kos_cfg)
        self.workers = int(workers)
        self.in_flight = max(1, in_flight if in_flight is not None else 3 * max(1, self.workers))
        self._queue: deque[tuple[Any, Any]] = deque()
        self._ex: ProcessPoolExecutor | None = None
        warmup()  # compile (or load) the kernels here once: forked workers inherit them instead of compiling each
        if self.workers > 0:
            ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
            self._ex = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_init_worker,
                                           initargs=(self.configs,))
            # start every worker now, before the caller starts threads (a progress bar): forking a process
            # with other threads running can copy a held lock
            for f in [self._ex.submit(_ping) for _ in range(self.workers)]:
                f.result()

    def submit(self, item: DepthItem, bearings: Bearings, keep_planes: bool = False, tag: Any = None) -> None:
        if self._ex is None:
            f = kos_frame(item, *self.configs, bearings, keep_planes=keep_planes)
            self._queue.append((f, tag))
        else:
            self._queue.append((self._ex.submit(_work, item, bearings, keep_planes), tag))

    def __len__(self) -> int:
        return len(self._queue)

    def results(self, wait_all: bool = False) -> Iterator[tuple[KosFrame, Any]]:
        """(frame, tag) of the finished frames at the head of the queue, in order; waits for the head while more
        than `in_flight` are outstanding, or for everything with `wait_all`."""
        while self._queue:
            head, tag = self._queue[0]
            if isinstance(head, Future):
                if not (wait_all or len(self._queue) > self.in_flight or head.done()):
                    return
                try:
                    head = head.result()
                except BrokenProcessPool as e:
                    raise KosmapError("a worker process died (out of memory?); rerun with fewer --workers or --workers 0") from e
            self._queue.popleft()
            yield head, tag

    def close(self, cancel: bool = False) -> None:
        """Stop the workers (dropping queued frames when `cancel`)."""
        self._queue.clear() if cancel else None
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=cancel)
            self._ex = None

    def __enter__(self) -> FramePool:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(cancel=exc_type is not None)
