"""One SLAM in a process of its own: its scan matching runs beside the reading instead of on the main thread.

Profiled on the 10-minute office log, the two SLAMs held the main thread ~23 s of pass 1's ~90 s while the two
cores were only ~75 % busy: the main thread (reading, decoding, feeding the frame workers, SLAM) was the
bottleneck. `RemoteFeed` records the calls a `SlamFeed` gets (odometry, gyro, scans, advance) in order and
sends them in batches through a pipe to a forked process that replays them on the same `SlamFeed` in that order:
SLAM sees exactly the inputs it gets in this process, so the maps stay identical to a serial build's. The calls go
as arrays (a kind, a stamp and the numbers of each; `_events` reads them back), the scans and the rest as objects.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
from array import array
from contextlib import contextmanager
from typing import Any

import numpy as np

from kosmap.frontend.errors import KosmapError
from kosmap.mapping.runtime.childproc import die_with_parent, set_name
from kosmap.mapping.runtime.framepool import peak_rss_mb, sendable_error


class SlamProcessError(KosmapError):
    """A SLAM process died, or its input could not be sent whole: the build cannot map that source."""


def _as_child(name: str, parent_pid: int) -> None:
    """Show the process as `name` (tools/bench_pipeline.py tells the SLAM processes from the frame workers by it),
    and die with the parent: the pipe cannot tell (mapping/runtime/childproc.py)."""
    set_name(name)
    die_with_parent(parent_pid)


_WHEEL, _GYRO, _ADVANCE, _OP = 0, 1, 2, 3  # the kinds of recorded call


_WIDTH = np.array([3, 1, 0, 0])  # the numbers each kind of call carries


def _events(batch: tuple):
    """(method, args) of a batch's calls in their order: what RemoteFeed recorded, a run of wheel or gyro samples as
    one `wheel_samples` / `gyro_samples` call with their columns (the same as a call each)."""
    kinds, stamps, values, ops = batch
    k = np.frombuffer(kinds, np.int8)
    t = np.frombuffer(stamps, np.int64)
    v = np.frombuffer(values, np.float64)
    off = np.concatenate(([0], np.cumsum(_WIDTH[k])))
    cut = np.flatnonzero(np.diff(k)) + 1
    for a, b in zip(np.concatenate(([0], cut)).tolist(), np.concatenate((cut, [len(k)])).tolist()):
        kind = int(k[a]) if b > a else -1
        if kind == _WHEEL:
            xyz = v[off[a]:off[b]].reshape(-1, 3)
            yield "wheel_samples", (t[a:b], xyz[:, 0], xyz[:, 1], xyz[:, 2])
        elif kind == _GYRO:
            yield "gyro_samples", (t[a:b], v[off[a]:off[b]])
        elif kind == _ADVANCE:
            for s in t[a:b].tolist():
                yield "advance", (s,)
        elif kind == _OP:
            for j in t[a:b].tolist():
                yield ops[j]


def _serve(feed, conn, parent_end, name: str, parent_pid: int) -> None:
    """The child: replay the parent's calls on `feed`; at "end", send back (status, result or error, scans added,
    scans without odometry, peak RSS MB)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it still asks for the result
    parent_end.close()
    _as_child(f"slam-{name}", parent_pid)  # 15 characters at most
    try:
        while True:
            for name, args in _events(conn.recv()):
                if name == "end":
                    feed.end()
                    try:
                        reply: tuple = ("ok", feed.result())
                    except KosmapError as e:
                        reply = ("error", e)
                    conn.send(reply + (feed.added, feed.no_odom, peak_rss_mb()))
                    return
                getattr(feed, name)(*args)
    except EOFError:  # the parent is gone
        return
    except BaseException as e:  # noqa: BLE001 - anything SLAM raised goes to the parent, which re-raises it
        conn.send(("error", sendable_error(e), feed.added, feed.no_odom, peak_rss_mb()))
    finally:
        conn.close()


@contextmanager
def _sigint_held():
    """A Ctrl-C during the block is handled when the block ends, by the handler it found (the pipeline's sets its
    stop flag, Python's raises KeyboardInterrupt): a KeyboardInterrupt raised inside a pipe write would cut a
    message in half, and the child could only fail on what follows."""
    held: list = []
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGINT, lambda *a: held.append(a))
    try:
        yield
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
    if held:
        if callable(old):
            old(*held[0])
        elif old != signal.SIG_IGN:
            raise KeyboardInterrupt


class RemoteFeed:
    """A `SlamFeed` (mapping/slamfeed.py) run in a forked process; the same methods. Fork it before any thread
    starts (the frame pool's, the read-ahead's)."""

    BATCH = 256  # calls per message through the pipe

    def __init__(self, feed, name: str) -> None:
        self.name = name
        self.slam = feed.slam  # this process's copy: its configs only
        self.use_odom, self.use_imu = feed.use_odom, feed.use_imu
        self.added = self.no_odom = 0  # known once the result came back
        self.peak_rss_mb = 0.0
        self._new_batch()
        self._reply: tuple | None = None
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(feed, child, self._conn, name, os.getpid()),
                                 name=f"kosmap-slam-{name}", daemon=True)
        self._proc.start()
        child.close()

    # -- the SlamFeed calls, recorded --------------------------------------------------------------------------
    # The 50 Hz odometry and 200 Hz gyro records go as the numbers SLAM takes of them, in arrays: pickling the
    # records (the Imu's seven numpy arrays) cost the main process ~18 s of the 10-minute office build, and
    # unpickling the SLAM processes ~10 s. A pickled (name, args) tuple per call cost, against arrays (with the
    # samples then replayed ahead of their batch's scans; in order, as now, the child does a little more), in two
    # single builds (±15 % from this machine alone): 21.9 vs 17.7 CPU s on the main thread, 23.3 vs 20.0 in the SLAMs.
    def odom(self, rec) -> None:
        self._record(_WHEEL, rec.stamp_ns, (rec.x, rec.y, rec.yaw))

    def imu(self, rec) -> None:
        if self.use_imu and rec.has_angular_velocity:  # (Slam.add_imu skips a record without)
            self._record(_GYRO, rec.stamp_ns, (rec.yaw_rate,))

    def wheel_samples(self, stamps_ns, x, y, yaw) -> None:
        self._record_many(_WHEEL, stamps_ns, (x, y, yaw))

    def gyro_samples(self, stamps_ns, yaw_rates) -> None:
        if self.use_imu:
            self._record_many(_GYRO, stamps_ns, (yaw_rates,))

    def push(self, stamp_ns: int, points, deskew: tuple | None = None) -> None:
        self._call("push", int(stamp_ns), points, deskew)

    def push_laser(self, scan, mount) -> None:
        self._call("push_laser", scan, mount)

    def advance(self, now_ns: int | None) -> None:
        if now_ns is None:  # the end of the log: never merged (an object call)
            self._call("advance", None)
        elif self._kinds and self._kinds[-1] == _ADVANCE:
            self._stamps[-1] = now_ns  # advance(a) then advance(b ≥ a) is advance(b): the log's time only grows
        else:
            self._record(_ADVANCE, now_ns, ())

    def end(self) -> None:
        """No more input: the child hands SLAM the pending scans and solves (both SLAMs at once, beside this
        process)."""
        self._ops.append(("end", ()))
        self._kinds.append(_OP)
        self._stamps.append(len(self._ops) - 1)
        self._flush()

    def result(self):
        """The child's SlamResult (its graph without the ISAM2 solver), None when no scan reached SLAM; SLAM's
        KosmapError re-raised here."""
        if self._reply is None:
            try:
                self._reply = self._conn.recv()
            except (EOFError, OSError):
                self._died()
            self._proc.join()
        status, value, self.added, self.no_odom, self.peak_rss_mb = self._reply
        if status == "error":
            raise value
        return value

    def close(self) -> None:
        """Stop the child if it still runs (an error elsewhere ended the build)."""
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join()
        self._conn.close()

    # -- plumbing ------------------------------------------------------------------------------------------------
    def _call(self, name: str, *args: Any) -> None:
        self._ops.append((name, args))
        self._record(_OP, len(self._ops) - 1, ())

    def _record(self, kind: int, stamp: int, values: tuple) -> None:
        self._kinds.append(kind)
        self._stamps.append(stamp)
        self._values.extend(values)
        if len(self._kinds) >= self.BATCH:
            self._flush()

    def _record_many(self, kind: int, stamps, columns: tuple) -> None:
        """Samples of one kind: `_record` of each, the numbers of sample i being column[i] of each column."""
        n = len(stamps)
        if not n:
            return
        self._kinds.frombytes(bytes([kind]) * n)
        self._stamps.frombytes(np.ascontiguousarray(stamps, np.int64).tobytes())
        self._values.frombytes(np.column_stack(columns).astype(np.float64).tobytes())
        if len(self._kinds) >= self.BATCH:
            self._flush()

    def _new_batch(self) -> None:
        self._kinds = array("b")  # per call: _WHEEL, _GYRO, _ADVANCE or _OP
        self._stamps = array("q")  # its stamp (log time for an advance; for an _OP its index in _ops)
        self._values = array("d")  # a wheel sample's x, y, yaw; a gyro sample's yaw rate
        self._ops: list[tuple[str, tuple]] = []  # the scans, advance(None), end

    def _batch(self) -> tuple:
        """The recorded calls as one message (`_events` reads it back)."""
        return self._kinds, self._stamps, self._values, self._ops

    def _flush(self) -> None:
        with _sigint_held():  # a batch is sent whole and once, or not at all
            try:
                if not self._conn.poll():  # (the child sends nothing before "end" unless it failed)
                    self._conn.send(self._batch())
                    self._new_batch()
                    return
            except OSError:  # the child is gone: it may have sent its error first
                pass
            self.result()  # raises the child's error, or says that it died
            self._died()

    def _died(self) -> None:
        raise SlamProcessError(f"the {self.name} SLAM process died (out of memory?); rerun with --workers 0 to run "
                               "SLAM in the main process")
