"""The per-frame stage on several cores: `kos_frame` over depth frames in a process pool, results in order.

A frame's result is a pure function of the frame and the configs (frontend/kosframe.py: its seed comes from its
index), so the pool gives exactly what a serial run gives. `workers = 0` runs each frame in this process at
`submit`, through the same queue, so the serial and parallel paths share every line but the call itself. At
most `in_flight` frames are outstanding, so memory does not grow with the log.

With workers, a frame's depth goes through a ring of shared-memory slots (an anonymous shared mapping made before
the workers fork): the main process copies the image as it came (uint16 mm, 434 KB for a Kinect frame) into a
slot and sends its number; the worker converts to metres there. Pickling the float32 image through a pipe cost
both sides ~1 ms per frame (docs/bench/pipeline.md). A slot is reused only after its frame's result came back.
"""

from __future__ import annotations

import dataclasses
import mmap
import multiprocessing as mp
import os
import signal
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from frontend.camera import DepthConfig
from frontend.depthstream import DepthItem
from frontend.errors import KosmapError
from frontend.fspf import FspfConfig, warmup
from frontend.kos import Bearings, KosConfig
from frontend.kosframe import KosFrame, kos_frame
from frontend.records import DepthFrame

_CONFIGS: tuple | None = None  # (fspf, depth, kos) configs of this worker process
_SLOTS: mmap.mmap | None = None  # the shared depth slots (inherited at fork)
SLOT_BYTES = 8 << 20  # one slot: up to 8 MB (a 1920×1080 uint16 image is 4 MB); larger frames are pickled


def _init_worker(configs: tuple) -> None:
    """Worker start: Ctrl-C is the parent's to handle (it writes the partial outputs); load the numba kernels."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    global _CONFIGS
    _CONFIGS = configs
    warmup(configs[0].method)


def _ping() -> int:
    return os.getpid()


def in_meters(item: DepthItem) -> DepthItem:
    """The item with its depth in metres: a uint16 image is raw 16UC1 millimetres (mapping/kosscan.py leaves the
    conversion to the frame stage, DepthFrame.meters)."""
    if item.depth.dtype == np.uint16:
        return dataclasses.replace(item, depth=DepthFrame(item.stamp_ns, item.depth, "16UC1").meters())
    return item


def _work(item: DepthItem, bearings: Bearings, keep_planes: bool, cloud_points: int, slot: tuple | None = None) -> KosFrame:
    fspf_cfg, depth_cfg, kos_cfg = _CONFIGS  # type: ignore[misc]
    if slot is not None:  # (slot, dtype, shape): the depth is in shared memory
        k, dtype, shape = slot
        view = np.ndarray(shape, dtype, buffer=_SLOTS, offset=k * SLOT_BYTES)  # type: ignore[arg-type]
        item = dataclasses.replace(item, depth=view.copy() if view.dtype != np.uint16 else view)
    item = in_meters(item)  # a uint16 view becomes a new float32 array: nothing keeps the slot
    return kos_frame(item, fspf_cfg, depth_cfg, kos_cfg, bearings, keep_planes, cloud_points)


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
        self._slots: mmap.mmap | None = None
        self._n_slots = self.in_flight + 2  # results() leaves at most in_flight + 1 frames outstanding
        self._next_slot = 0
        warmup(fspf_cfg.method)  # compile (or load) the kernels here once: forked workers inherit them instead of compiling each
        if self.workers > 0:
            fork = "fork" in mp.get_all_start_methods()
            ctx = mp.get_context("fork") if fork else None
            if fork:  # anonymous and shared: the forked workers see the same pages; untouched pages cost nothing
                global _SLOTS
                self._slots = _SLOTS = mmap.mmap(-1, self._n_slots * SLOT_BYTES)
            self._ex = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_init_worker,
                                           initargs=(self.configs,))
            # start every worker now, before the caller starts threads (a progress bar): forking a process
            # with other threads running can copy a held lock
            for f in [self._ex.submit(_ping) for _ in range(self.workers)]:
                f.result()

    def submit(self, item: DepthItem, bearings: Bearings, keep_planes: bool = False, tag: Any = None,
               cloud_points: int = 0) -> None:
        """Queue one frame (its depth in metres, or raw uint16 millimetres); `keep_planes`, `cloud_points`: what
        of its planes comes back (frontend/kosframe.py kos_frame)."""
        if self._ex is None:
            f = kos_frame(in_meters(item), *self.configs, bearings, keep_planes, cloud_points)
            self._queue.append((f, tag))
            return
        d = item.depth
        slot = None
        if self._slots is not None and len(self._queue) < self._n_slots and d.nbytes <= SLOT_BYTES:
            # the ring's slots free in order: with fewer than n_slots outstanding, the next one is free
            k = self._next_slot
            self._next_slot = (k + 1) % self._n_slots
            np.ndarray(d.shape, d.dtype, buffer=self._slots, offset=k * SLOT_BYTES)[...] = d
            slot = (k, d.dtype.str, d.shape)
            item = dataclasses.replace(item, depth=np.zeros((0,), d.dtype))
        self._queue.append((self._ex.submit(_work, item, bearings, keep_planes, cloud_points, slot), tag))

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

    @property
    def executor(self) -> ProcessPoolExecutor | None:
        """The worker processes (None when serial): mapping/pipeline.py runs its grid and comparison jobs there
        after the frames, instead of forking new workers from a process that has grown meanwhile."""
        return self._ex

    def drop(self) -> None:
        """Forget the queued frames (Ctrl-C): those not started are cancelled, the running ones finish unread; the
        workers stay."""
        for f, _ in self._queue:
            if isinstance(f, Future):
                f.cancel()
        self._queue.clear()

    def close(self, cancel: bool = False) -> None:
        """Stop the workers (dropping queued frames when `cancel`)."""
        self._queue.clear() if cancel else None
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=cancel)
            self._ex = None
        if self._slots is not None:
            self._slots.close()
            self._slots = None

    def __enter__(self) -> FramePool:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(cancel=exc_type is not None)


def peak_rss_mb() -> float:
    """Peak resident memory so far of this process, MB."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def executor_peak_rss_mb(ex: ProcessPoolExecutor | None) -> float:
    """The largest peak resident memory (VmHWM) of a process pool's live workers, MB (0 when none, or not Linux):
    read from /proc while they live, as getrusage(RUSAGE_CHILDREN) sees only children that have ended (and would
    count the SLAM processes too)."""
    peak = 0
    for pid in list(getattr(ex, "_processes", None) or {}):
        try:
            with open(f"/proc/{pid}/status") as fh:
                peak = max([peak] + [int(x.split()[1]) for x in fh if x.startswith("VmHWM:")])
        except (OSError, ValueError, IndexError):
            continue
    return peak / 1024
