"""The per-frame stage on several cores: `kos_frame` over depth frames in a process pool, results in order.

A frame's result is a pure function of the frame and the configs (frontend/kosframe.py: its seed comes from its
index), so the pool gives exactly what a serial run gives. `workers = 0` runs each frame in this process at
`submit`, through the same queue, so the serial and parallel paths share every line but the call itself. At
most `in_flight` frames are outstanding, so memory does not grow with the log.

With workers, a frame's depth goes through a ring of shared-memory slots (an anonymous shared mapping made before
the workers fork): the main process copies the image as it came (uint16 mm, 434 KB for a Kinect frame) into a
slot and sends its number; the worker converts to metres there. Pickling the float32 image through a pipe cost
both sides ~1 ms per frame (docs/bench/pipeline.md). A slot is reused only after its frame's result came back.

The frames and their results go through one pipe per worker, served by a long task of that worker's
(`_frame_loop`): the executor's path (a Future, its manager and feeder threads, two shared queues with their
locks) cost ~2 CPU s per 6000 frames measured alone, its two threads ~3 CPU s of the 10-minute office build. The
executor keeps the workers for pass 2's jobs.
"""

from __future__ import annotations

import dataclasses
import mmap
import multiprocessing as mp
import os
import pickle
import signal
import traceback
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from kosmap.frontend.camera import DepthConfig
from kosmap.frontend.depthstream import DepthItem
from kosmap.frontend.errors import KosmapError
from kosmap.frontend.fspf import FspfConfig, warmup
from kosmap.frontend.kos import Bearings, KosConfig
from kosmap.frontend.kosframe import KosFrame, kos_frame
from kosmap.frontend.records import DepthFrame
from kosmap.mapping.runtime.childproc import die_with_parent

_CONFIGS: tuple | None = None  # (fspf, depth, kos) configs of this worker process
_SLOTS: mmap.mmap | None = None  # the shared depth slots (inherited at fork)
_PIPES: list | None = None  # (this end, worker's end) of each worker's frame pipe (inherited at fork)
SLOT_BYTES = 8 << 20  # one slot: up to 8 MB (a 1920×1080 uint16 image is 4 MB); larger frames are pickled


def _init_worker(configs: tuple, parent_pid: int) -> None:
    """Worker start: Ctrl-C is the parent's to handle (it writes the partial outputs); die with the parent (a
    build killed outright must not leave its workers waiting for ever); load the numba kernels."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid)
    global _CONFIGS
    _CONFIGS = configs
    warmup(configs[0].method)


def _ping() -> int:
    return os.getpid()


def in_meters(item: DepthItem) -> DepthItem:
    """The item with its depth in metres: a uint16 image is raw 16UC1 millimetres (mapping/kosstream.py leaves the
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


def sendable_error(e: BaseException) -> BaseException:
    """`e` if it survives a pickle round trip (a child process sends it to the parent, which re-raises it), else a
    RuntimeError holding its traceback as text."""
    try:
        pickle.loads(pickle.dumps(e))
        return e
    except Exception:  # noqa: BLE001 - e.g. an __init__ that wants other arguments than its args
        return RuntimeError("".join(traceback.format_exception(e)))


def _frame_loop(k: int) -> int:
    """Worker k's pass-1 task: frames from its pipe, each result (or the error it raised) back through it in
    order, until None."""
    pipes = _PIPES or []
    conn = pipes[k][1]
    for j, (mine, theirs) in enumerate(pipes):  # inherited copies: the parent's ends, the other workers' ends
        mine.close()
        if j != k:
            theirs.close()
    conn.send(("ready", k))  # the parent waits for this from every loop (FramePool._start)
    bearings = None
    while True:
        try:
            msg = conn.recv()
        except EOFError:  # the parent is gone
            break
        if msg is None:
            break
        item, b, keep, cloud, slot = msg
        bearings = b if b is not None else bearings  # sent when it changes
        try:
            out: tuple = ("ok", _work(item, bearings, keep, cloud, slot))
        except Exception as e:  # noqa: BLE001 - the frame's error is the parent's to raise
            out = ("error", sendable_error(e))
        conn.send(out)  # (a closed parent end: BrokenPipeError ends the task)
    conn.close()
    return k


def check_workers(workers: int) -> int:
    """`workers` when it is 0 or more and at most 4 × the cores this process may use (more processes only share the
    same cores, each with its own memory); KosmapError otherwise."""
    most = 4 * default_workers()
    if workers < 0:
        raise KosmapError(f"--workers {workers} must be 0 (serial, in this process) or more")
    if workers > most:
        raise KosmapError(f"--workers {workers} is more than 4 × the {default_workers()} core(s) this process may use: "
                          f"give at most {most}")
    return int(workers)


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
        check_workers(workers)
        self.configs = (fspf_cfg, depth_cfg, kos_cfg)
        self.workers = int(workers)
        self.in_flight = max(1, in_flight if in_flight is not None else 3 * max(1, self.workers))
        self._queue: deque[list] = deque()  # [worker or None, result or None, tag], in submission order
        self._ex: ProcessPoolExecutor | None = None
        self._slots: mmap.mmap | None = None
        self._n_slots = self.in_flight + 2  # results() leaves at most in_flight + 1 frames outstanding
        self._next_slot = 0
        self._conns: list = []  # this end of each worker's frame pipe
        self._waiting: list[deque[list]] = []  # per worker: the queue entries whose results it has not sent yet
        self._loops: list[Future] = []  # the workers' _frame_loop tasks
        self._bearings: list = []  # per worker: the Bearings it was last sent
        warmup(fspf_cfg.method)  # compile (or load) the kernels here once: forked workers inherit them instead of compiling each
        if self.workers > 0:
            try:
                self._start()
            except BaseException:
                global _PIPES
                for pair in _PIPES or []:
                    for c in pair:
                        c.close()
                _PIPES = None
                self.close(cancel=True)
                raise

    def _start(self) -> None:
        """Fork the workers (with the slots and their frame pipes) and start their frame loops."""
        fork = "fork" in mp.get_all_start_methods()
        ctx = mp.get_context("fork") if fork else None
        if fork:  # anonymous and shared: the forked workers see the same pages; untouched pages cost nothing
            global _SLOTS, _PIPES
            self._slots = _SLOTS = mmap.mmap(-1, self._n_slots * SLOT_BYTES)
            _PIPES = [ctx.Pipe() for _ in range(self.workers)]  # before the fork: every worker inherits them
        self._ex = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_init_worker,
                                       initargs=(self.configs, os.getpid()))
        # start every worker now, before the caller starts threads (a progress bar): forking a process
        # with other threads running can copy a held lock
        for f in [self._ex.submit(_ping) for _ in range(self.workers)]:
            f.result()
        if fork:
            pipes, _PIPES = _PIPES, None
            for mine, theirs in pipes:
                theirs.close()  # (a worker that dies then ends its pipe: recv raises EOFError here)
                self._conns.append(mine)
                self._waiting.append(deque())
                self._bearings.append(None)
            # each worker blocks in its loop, so the k-th task goes to a worker of its own
            self._loops = [self._ex.submit(_frame_loop, k) for k in range(self.workers)]
            # and every loop is running, its copies of the other pipes' ends closed, before a frame is sent: a loop
            # still queued when a close cancels it would leave its worker holding a copy of another loop's parent
            # end, and that loop would never see its pipe's end (a hang seen in CI, when one worker had answered
            # both pings while the other was still starting)
            for k, c in enumerate(self._conns):
                try:
                    ready = c.recv()
                except EOFError:
                    raise KosmapError(f"frame worker {k} died while starting (out of memory?)") from None
                assert ready == ("ready", k), ready

    def submit(self, item: DepthItem, bearings: Bearings, keep_planes: bool = False, tag: Any = None,
               cloud_points: int = 0) -> None:
        """Queue one frame (its depth in metres, or raw uint16 millimetres); `keep_planes`, `cloud_points`: what
        of its planes comes back (frontend/kosframe.py kos_frame)."""
        if self._ex is None:
            f = kos_frame(in_meters(item), *self.configs, bearings, keep_planes, cloud_points)
            self._queue.append([None, ("ok", f), tag])
            return
        if not self._conns:  # no fork (not Linux): the executor's own path
            self._queue.append([None, self._ex.submit(_work, item, bearings, keep_planes, cloud_points), tag])
            return
        if not self._loops:
            raise RuntimeError("FramePool.submit after its executor was taken for other jobs")
        d = item.depth
        slot = None
        if self._slots is not None and len(self._queue) < self._n_slots and d.nbytes <= SLOT_BYTES:
            # the ring's slots free in order: with fewer than n_slots outstanding, the next one is free
            k = self._next_slot
            self._next_slot = (k + 1) % self._n_slots
            np.ndarray(d.shape, d.dtype, buffer=self._slots, offset=k * SLOT_BYTES)[...] = d
            slot = (k, d.dtype.str, d.shape)
            item = dataclasses.replace(item, depth=np.zeros((0,), d.dtype))
        w = min(range(self.workers), key=lambda j: len(self._waiting[j]))  # the least busy worker
        if slot is None:  # the image itself goes through the pipe: the worker must be reading, not blocked
            self._collect(w, len(self._waiting[w]))  # in sending a large result to us, so take its results first
        b = None if self._bearings[w] is bearings else bearings
        entry = [w, None, tag]
        try:
            self._conns[w].send((item, b, keep_planes, cloud_points, slot))
        except OSError as e:
            raise self._died() from e
        self._bearings[w] = bearings
        self._waiting[w].append(entry)
        self._queue.append(entry)

    def __len__(self) -> int:
        return len(self._queue)

    def results(self, wait_all: bool = False) -> Iterator[tuple[KosFrame, Any]]:
        """(frame, tag) of the finished frames at the head of the queue, in order; waits for the head while more
        than `in_flight` are outstanding, or for everything with `wait_all`."""
        while self._queue:
            head = self._queue[0]
            w, res = head[0], head[1]
            if isinstance(res, Future):
                if not (wait_all or len(self._queue) > self.in_flight or res.done()):
                    return
                try:
                    res = ("ok", res.result())
                except BrokenProcessPool as e:
                    raise self._died() from e
            elif res is None:
                if not (wait_all or len(self._queue) > self.in_flight or self._conns[w].poll()):
                    return
                self._collect(w, 1)
                res = head[1]
            self._queue.popleft()
            status, value = res
            if status == "error":
                raise value
            yield value, head[2]

    def _collect(self, w: int, n: int) -> None:
        """Read worker w's next n results into their queue entries (waiting for them). An entry leaves the
        worker's list before its read, so that a read that fails never leaves the two out of step."""
        for _ in range(n):
            entry = self._waiting[w].popleft()
            try:
                entry[1] = self._conns[w].recv()
            except (EOFError, OSError) as e:
                raise self._died() from e
            except Exception as e:  # noqa: BLE001 - a result that does not unpickle here: that frame's error
                entry[1] = ("error", e)

    @staticmethod
    def _died() -> KosmapError:
        return KosmapError("a worker process died (out of memory?); rerun with fewer --workers or --workers 0")

    def _stop_loops(self) -> None:
        """End the workers' frame loops (their outstanding results read first, so none blocks in sending): the
        executor is then free for other jobs."""
        if not self._loops:
            return
        loops, self._loops = self._loops, []
        try:
            for w in range(len(self._conns)):
                self._collect(w, len(self._waiting[w]))
                self._conns[w].send(None)
            for f in loops:
                f.result()
        except (OSError, BrokenProcessPool) as e:
            raise self._died() from e

    @property
    def executor(self) -> ProcessPoolExecutor | None:
        """The worker processes (None when serial), their frame loops ended: the build (mapping/build/jobs.py) runs its grid and
        comparison jobs there after the frames, instead of forking new workers from a process that has grown
        meanwhile. Frames cannot be submitted after this."""
        self._stop_loops()
        return self._ex

    def drop(self) -> None:
        """Forget the queued frames (Ctrl-C): the ones already sent to a worker finish (a few ms) and are read and
        dropped; the workers stay."""
        for w in range(len(self._conns)):
            self._collect(w, len(self._waiting[w]))
        for _, f, _ in self._queue:
            if isinstance(f, Future):
                f.cancel()
        self._queue.clear()

    def close(self, cancel: bool = False) -> None:
        """Stop the workers (dropping queued frames when `cancel`)."""
        self._queue.clear() if cancel else None
        try:
            # the frame loops end at their pipes' EOF (or in sending to a closed end): nothing is read here, so a
            # dead worker or an interrupted read cannot make this wait
            for c in self._conns:
                c.close()
            self._conns, self._loops = [], []
            if self._ex is not None:
                self._ex.shutdown(wait=True, cancel_futures=cancel)
                self._ex = None
        finally:
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
