"""FramePool: the process pool (frames through shared-memory slots) gives exactly the serial results, for raw
uint16 millimetre frames and float32 metre frames, over more frames than the ring has slots."""

import dataclasses
import sys
import threading

import numpy as np
import pytest

from kosmap.frontend.camera import DepthConfig, config_mount
from kosmap.frontend.depthstream import DepthItem
from kosmap.frontend.fspf import FspfConfig
from kosmap.frontend.kos import KosConfig, bearings_for
from kosmap.frontend.records import CameraModel
from kosmap.mapping.runtime.framepool import FramePool


def _items(n: int) -> list[DepthItem]:
    """A floor and a wall in front of a 64×48 camera, with seeded noise, some as uint16 mm and some in metres."""
    rng = np.random.default_rng(5)
    cam = CameraModel.from_fov(64, 48, np.radians(70.0), np.radians(60.0), "camera_optical_frame")
    mount = config_mount(DepthConfig())
    rows = np.arange(48, dtype=np.float32)[:, None]
    items = []
    for i in range(n):
        wall = 2.0 + 0.1 * (i % 5)
        floor = np.where(rows > cam.cy + 1, 0.4 * cam.fy / np.maximum(rows - cam.cy, 1.0), np.inf)
        d = np.minimum(np.full((48, 64), wall, np.float32), floor).astype(np.float32)
        d += rng.normal(0.0, 0.004, d.shape).astype(np.float32)
        d[rng.random(d.shape) < 0.05] = 0.0
        if i % 2 == 0:  # raw 16UC1, as mapping/kosstream.py passes it
            depth = np.round(np.clip(d, 0.0, 60.0) * 1000.0).astype(np.uint16)
        else:
            depth = (np.round(np.clip(d, 0.0, 60.0) * 1000.0) * np.float32(0.001)).astype(np.float32)
        items.append(DepthItem(i, 1_000_000_000 + i * 33_000_000, depth, cam, mount, "/depth", cam.frame_id))
    return items


def _run(items, workers: int):
    fspf, depth, kos = FspfConfig(n_min=20), DepthConfig(), KosConfig()
    bearings = bearings_for([(items[0].camera, items[0].mount)], kos.angle_increment_deg)
    out = []
    with FramePool(fspf, depth, kos, workers, in_flight=2) as pool:  # a ring of 4 slots for 11 frames
        for it in items:
            pool.submit(it, bearings, keep_planes=it.index % 3 == 0, tag=it.index, cloud_points=50 * (it.index % 2))
            out += list(pool.results())
        out += list(pool.results(wait_all=True))
    return out


def test_pool_equals_serial():
    items = _items(11)
    serial, parallel = _run(items, 0), _run(items, 2)
    assert [t for _, t in serial] == [t for _, t in parallel] == list(range(11))
    for (a, _), (b, _) in zip(serial, parallel):
        assert a.index == b.index and a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.ranges, b.ranges)
        assert dataclasses.astuple(a.stats)[:6] == dataclasses.astuple(b.stats)[:6]
        assert (a.planes is None) == (b.planes is None)
        if a.planes is not None:
            np.testing.assert_array_equal(a.planes.points, b.planes.points)
        assert (a.cloud is None) == (b.cloud is None) == (a.index % 2 == 0)
        if a.cloud is not None:  # at most 50 of the frame's plane points, the same ones either way
            np.testing.assert_array_equal(a.cloud[0], b.cloud[0])
            np.testing.assert_array_equal(a.cloud[1], b.cloud[1])
            assert 0 < len(a.cloud[0]) <= 50
        if a.planes is not None and a.cloud is not None:  # the cloud: the frame's seeded choice of its plane points
            n = len(a.planes.points)
            pick = np.sort(np.random.default_rng(a.index).choice(n, 50, replace=False)) if n > 50 else np.arange(n)
            np.testing.assert_array_equal(a.cloud[0], a.planes.points[pick])
            np.testing.assert_array_equal(a.cloud[1], a.planes.point_classes()[pick])
    assert sum(np.isfinite(f.ranges).sum() for f, _ in serial) > 0  # the frames saw something


def test_uint16_is_millimetres():
    """A raw uint16 frame gives the same result as the same depth in metres (DepthFrame.meters)."""
    items = _items(2)
    raw = items[0]
    metres = dataclasses.replace(raw, depth=raw.depth.astype(np.float32) * np.float32(0.001))
    a, b = _run([raw], 0)[0][0], _run([metres], 0)[0][0]
    np.testing.assert_array_equal(a.ranges, b.ranges)


def test_a_frames_error_comes_back_and_the_workers_then_serve_other_jobs():
    """A frame that fails in a worker raises its own error here, in its place in the order; after the frames, the
    same workers run other jobs (the build's grids and comparisons)."""
    import pytest

    items = _items(4)
    bad = dataclasses.replace(items[2], depth=np.zeros((7, 9), np.float32))  # not the camera's 64×48
    fspf, depth, kos = FspfConfig(n_min=20), DepthConfig(), KosConfig()
    bearings = bearings_for([(items[0].camera, items[0].mount)], kos.angle_increment_deg)
    with FramePool(fspf, depth, kos, 2, in_flight=2) as pool:
        for it in items[:2] + [bad] + items[3:]:
            pool.submit(it, bearings, tag=it.index)
        got = []
        with pytest.raises(ValueError, match="camera is 64×48 but the depth image is 9×7"):
            for f, tag in pool.results(wait_all=True):
                got.append(tag)
        assert got == [0, 1]
        pool.drop()
        assert sorted(pool.executor.map(abs, [-3, -1, 2])) == [1, 2, 3]
        with pytest.raises(RuntimeError, match="after its executor"):
            pool.submit(items[0], bearings)


def test_a_worker_that_dies_is_a_clear_error_not_a_hang():
    import os
    import signal

    import pytest

    from kosmap.frontend.errors import KosmapError

    items = _items(6)
    fspf, depth, kos = FspfConfig(n_min=20), DepthConfig(), KosConfig()
    bearings = bearings_for([(items[0].camera, items[0].mount)], kos.angle_increment_deg)
    pool = FramePool(fspf, depth, kos, 2, in_flight=4)
    try:
        for pid in list(pool._ex._processes):  # one of the two workers
            os.kill(pid, signal.SIGKILL)
            break
        with pytest.raises(KosmapError, match="worker process died.*--workers 0"):
            for it in items:
                pool.submit(it, bearings, tag=it.index)
            list(pool.results(wait_all=True))
    finally:
        pool.close(cancel=True)  # returns: it reads nothing, and the executor ends the workers of a broken pool


class _Odd(Exception):
    """An exception that does not survive a pickle round trip: it holds a lock (pickling it fails), and its __init__
    wants two arguments where its args hold one (unpickling it fails, unless a library such as tblib, which Dask
    installs, has taught pickle to rebuild exceptions without __init__)."""

    def __init__(self, a, b):
        super().__init__(f"{a}/{b}")
        self.lock = threading.Lock()


def _raise_odd(*args, **kwargs):
    raise _Odd(1, 2)


def test_an_error_that_does_not_unpickle_comes_back_as_its_text_and_close_never_waits(monkeypatch):
    import pytest

    import kosmap.mapping.runtime.framepool as fp

    items = _items(5)
    fspf, depth, kos = FspfConfig(n_min=20), DepthConfig(), KosConfig()
    bearings = bearings_for([(items[0].camera, items[0].mount)], kos.angle_increment_deg)
    monkeypatch.setattr(fp, "_work", _raise_odd)  # before the fork: the workers run it
    with FramePool(fspf, depth, kos, 2, in_flight=2) as pool:
        pool.submit(items[0], bearings)
        with pytest.raises(RuntimeError, match="_Odd: 1/2"):
            list(pool.results(wait_all=True))
    monkeypatch.undo()
    pool = FramePool(fspf, depth, kos, 2, in_flight=4)
    for it in items:  # outstanding, never read
        pool.submit(it, bearings)
    pool.close(cancel=True)  # returns: the loops end at their pipes' EOF
    assert pool.executor is None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_the_workers_die_with_a_build_killed_outright():
    """SIGKILL (the out-of-memory killer) on the main process: its frame workers must not wait for ever."""
    import signal
    import subprocess
    import time
    from pathlib import Path

    script = ("import time\nfrom kosmap.frontend.camera import DepthConfig\nfrom kosmap.frontend.fspf import FspfConfig\n"
              "from kosmap.frontend.kos import KosConfig\nfrom kosmap.mapping.runtime.framepool import FramePool\n"
              "pool = FramePool(FspfConfig(), DepthConfig(), KosConfig(), workers=2)\nprint('ready', flush=True)\n"
              "time.sleep(60)\n")
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                         cwd=Path(__file__).resolve().parents[2])
    try:
        assert p.stdout.readline().strip() == "ready"
        kids = [int(x) for t in Path(f"/proc/{p.pid}/task").iterdir()
                for x in (t / "children").read_text().split()]
        assert len(kids) == 2
        p.send_signal(signal.SIGKILL)
        p.wait()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(Path(f"/proc/{k}").exists() for k in kids):
            time.sleep(0.05)
        alive = [k for k in kids if Path(f"/proc/{k}").exists()
                 and "Z" not in (Path(f"/proc/{k}/stat").read_text().split()[2:3] or [""])[0]]
        assert not alive, f"workers {alive} outlived their killed parent"
    finally:
        p.kill()


def _slow_second_init(configs, parent_pid, count):
    """The pool's worker start, the second worker's half a second late: the first then answers both pings."""
    import time

    import kosmap.mapping.runtime.framepool as fp

    with count.get_lock():
        count.value += 1
        n = count.value
    if n == 2:
        time.sleep(0.5)
    fp._init_worker(configs, parent_pid)


def test_every_frame_loop_runs_before_the_pool_is_used_so_close_never_hangs(monkeypatch):
    """A loop still queued when close(cancel=True) cancels it would leave its worker holding another loop's pipe
    end, and that loop would wait for ever (a hang once seen in CI)."""
    import multiprocessing as mp
    import threading
    from concurrent.futures import ProcessPoolExecutor

    import kosmap.mapping.runtime.framepool as fp

    count = mp.get_context("fork").Value("i", 0)

    class SlowStart(ProcessPoolExecutor):
        def __init__(self, n, mp_context=None, initializer=None, initargs=()):
            super().__init__(n, mp_context=mp_context, initializer=_slow_second_init, initargs=(*initargs, count))

    monkeypatch.setattr(fp, "ProcessPoolExecutor", SlowStart)
    items = _items(3)
    fspf, depth, kos = FspfConfig(n_min=20), DepthConfig(), KosConfig()
    bearings = bearings_for([(items[0].camera, items[0].mount)], kos.angle_increment_deg)
    pool = FramePool(fspf, depth, kos, 2, in_flight=4)
    assert all(f.running() for f in pool._loops)
    for it in items:
        pool.submit(it, bearings)
    t = threading.Thread(target=pool.close, kwargs={"cancel": True}, daemon=True)
    t.start()
    t.join(20)
    assert not t.is_alive(), "close(cancel=True) hung"
