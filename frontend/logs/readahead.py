"""Reading a log ahead on a thread: the next messages are read and decompressed while the caller works on these.

zstd and lz4 decompression release the GIL, so on the second core they run beside the caller's Python. On a
Kinect log that is most of reading it: the MCAP's zstd chunks cost `kosmap build`'s main process ~0.04 CPU s per
second of log, on the thread that also feeds the frame pool and the SLAMs (docs/bench/pipeline.md).

Do not fork while a read-ahead runs (a forked child would inherit its locks held): the build and `kosmap scan`
start their worker processes before they read.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator

_END = object()


class _Raised:
    """An exception raised on the thread, queued to be raised again by the reader."""

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


def read_ahead(items: Iterable, size: Callable[[object], int] = lambda _: 1, batch: int = 1 << 20,
               depth: int = 4) -> Iterator:
    """The items of `items`, in order, produced on a thread up to `depth` batches ahead (a batch: items whose
    `size` adds up to `batch`). An exception on the thread is raised here, after the items before it. Closing
    this generator stops the thread; it is joined before `close()` returns."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(x) -> bool:
        while not stop.is_set():
            try:
                q.put(x, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        buf: list = []
        n = 0
        try:
            for item in items:
                buf.append(item)
                n += size(item)
                if n >= batch or len(buf) >= 4096:
                    if not put(buf):
                        return
                    buf, n = [], 0
            if put(buf):
                put(_END)
        except BaseException as e:  # noqa: BLE001 - handed to the reader, which raises it
            if put(buf):
                put(_Raised(e))
        finally:
            close = getattr(items, "close", None)
            if close is not None:  # a generator is closed on the thread that ran it
                close()

    th = threading.Thread(target=produce, name="kosmap-read-ahead", daemon=True)
    th.start()
    try:
        while True:
            got = q.get()
            if got is _END:
                return
            if isinstance(got, _Raised):
                raise got.exc
            yield from got
    finally:
        stop.set()
        th.join()
