"""mapping/runtime/slamproc.py: a SLAM fed in its own process gives exactly the in-process result; its failures reach the
parent as errors that say what happened."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from kosmap.frontend.errors import KosmapError
from kosmap.frontend.records import Odometry
from kosmap.mapping.config import load_config
from kosmap.backend.slam import Slam
from kosmap.mapping.slamfeed import SlamFeed
from kosmap.mapping.runtime.slamproc import RemoteFeed, _events


def _corridor_scan(x: float, rng) -> np.ndarray:
    """End points (base_link) of a 360-beam scan in a 3 m wide corridor with cross walls every 4 m, seen from x."""
    ang = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    c, s = np.cos(ang), np.sin(ang)
    with np.errstate(divide="ignore"):
        r_side = np.where(s != 0, 1.5 / np.abs(s), np.inf)
        nxt = np.where(c > 0, 4.0 * np.floor(x / 4.0 + 1) - x, x - 4.0 * np.floor(x / 4.0) + 0.5)
        r_end = np.where(c != 0, nxt / np.abs(c), np.inf)
    r = np.minimum(np.minimum(r_side, r_end), 8.0) + rng.normal(0, 0.01, 360)
    return np.column_stack((r * c, r * s))


def _calls(n: int = 60):
    """(method, args) of a robot driving 5 cm a step along the corridor, odometry at twice the scan rate."""
    rng = np.random.default_rng(3)
    for i in range(n):
        t = int(i * 1e8)
        for k in (0, 1):
            yield "odom", (Odometry(t + k * 50_000_000, 0.05 * i + 0.025 * k, 0.0, 0.0, "odom", "base_link", "/odom"),)
        yield "push", (t, _corridor_scan(0.05 * i, rng))
        yield "advance", (t + 50_000_000,)


def _feed_calls(feed, n: int = 60) -> None:
    for name, args in _calls(n):
        getattr(feed, name)(*args)
    feed.end()


def _feed(use_odom: bool = True) -> SlamFeed:
    cfg = load_config(None, [])
    return SlamFeed(Slam(cfg.odometry, cfg.graph), use_odom)


def test_remote_feed_gives_the_in_process_result():
    local = _feed()
    _feed_calls(local)
    want = local.result()
    remote = RemoteFeed(_feed(), "laser")
    try:
        _feed_calls(remote)
        got = remote.result()
    finally:
        remote.close()
    assert len(want.poses) == 60 and np.ptp(want.poses[:, 0]) > 2.5  # it drove ~3 m
    assert np.array_equal(got.stamps_ns, want.stamps_ns)
    assert np.array_equal(got.poses, want.poses)  # bit for bit: the same calls in the same order
    assert np.array_equal(got.odom_poses, want.odom_poses, equal_nan=True)
    assert len(got.keyframes) == len(want.keyframes) and len(got.graph.edges) == len(want.graph.edges)
    assert got.graph.isam is None  # the solver stays in the child; the rest of the graph came back
    assert remote.added == local.added == 60 and remote.no_odom == local.no_odom
    assert remote.peak_rss_mb > 0


def test_an_error_in_the_child_is_raised_in_the_parent():
    remote = RemoteFeed(_feed(use_odom=False), "kos")
    try:
        with pytest.raises(Exception) as e:
            remote.push(0, np.full((5, 3, 2), np.nan))  # not N×2 points: SLAM fails on it in the child
            remote.advance(None)
            for i in range(5000):  # the parent goes on sending (batches) after the child has stopped
                remote.odom(Odometry(i, 0.0, 0.0, 0.0))
            remote.end()
            remote.result()
        assert "died" not in str(e.value)  # SLAM's own error, not a lost process
    finally:
        remote.close()


def test_no_scan_gives_no_result_and_a_dead_child_a_clear_error():
    remote = RemoteFeed(_feed(), "kos")
    remote.end()
    assert remote.result() is None
    remote.close()
    remote = RemoteFeed(_feed(), "laser")
    try:
        os.kill(remote._proc.pid, signal.SIGKILL)
        remote._proc.join()
        with pytest.raises(KosmapError, match="laser SLAM process died.*--workers 0"):
            _feed_calls(remote)
            remote.result()
    finally:
        remote.close()


def _run(feed, calls) -> None:
    for name, args in calls:
        getattr(feed, name)(*args)
    feed.end()


def _gyro_feed() -> SlamFeed:
    """A SlamFeed with wheel odometry and the gyro."""
    cfg = load_config(None, [])
    return SlamFeed(Slam(cfg.odometry, cfg.graph), True, use_imu=True)


def _calls_in(batch) -> int:
    """The calls one batch carries (samples, scans, advances: one kind each)."""
    return len(batch[0])


def test_a_ctrl_c_during_a_send_is_held_until_the_batch_is_whole():
    """SIGINT arriving while a batch is written is handled after it (here Python's handler: KeyboardInterrupt), and
    the batch is neither cut nor sent twice: fed on to the end, SLAM gives exactly the in-process result."""
    local = _feed()
    _feed_calls(local)
    want = local.result()
    remote = RemoteFeed(_feed(), "laser")
    remote.BATCH = 50  # several batches in the 240 calls (the batch size does not change what SLAM gets)
    real_send = remote._conn.send
    sent = []

    def send_with_ctrl_c(obj):
        if not sent:
            os.kill(os.getpid(), signal.SIGINT)  # arrives while the first batch is being sent
        sent.append(_calls_in(obj))
        real_send(obj)

    remote._conn.send = send_with_ctrl_c
    interrupts = 0
    prev = signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own (an xdist worker may ignore SIGINT)
    try:
        for name, args in _calls():
            try:
                getattr(remote, name)(*args)
            except KeyboardInterrupt:  # after the call's batch went whole
                interrupts += 1
        remote.end()
        got = remote.result()
    finally:
        signal.signal(signal.SIGINT, prev)
        remote.close()
    assert interrupts == 1 and sent[0] == 50 and len(sent) > 3
    assert np.array_equal(got.poses, want.poses) and remote.added == local.added


def test_advance_to_the_end_is_never_merged_away():
    remote = RemoteFeed(_feed(), "kos")
    try:
        remote.advance(5)
        remote.advance(7)  # merged: advance(5) then advance(7) is advance(7)
        remote.advance(None)
        remote.advance(9)  # not merged into the end
        remote.odom(Odometry(9, 1.0, 0.0, 0.0))
        remote.advance(11)  # a sample between: not merged either
        events = [(name, tuple(np.asarray(a).tolist() for a in args)) for name, args in _events(remote._batch())]
        assert events == [("advance", (7,)), ("advance", (None,)), ("advance", (9,)),
                          ("wheel_samples", ([9], [1.0], [0.0], [0.0])), ("advance", (11,))]
    finally:
        remote.close()


def test_a_slam_process_killed_while_solving_fails_the_build_and_one_killed_with_its_parent_goes_too(tmp_path):
    from kosmap.mapping.runtime.slamproc import SlamProcessError

    remote = RemoteFeed(_feed(), "laser")
    try:
        _feed_calls(remote)  # sends "end": the child is solving
        os.kill(remote._proc.pid, signal.SIGKILL)
        with pytest.raises(SlamProcessError, match="died"):
            remote.result()
    finally:
        remote.close()
    # a parent killed outright (out of memory) takes its SLAM process with it
    import subprocess
    import sys
    import time

    code = ("import time; from kosmap.mapping.config import load_config; from kosmap.mapping.slamfeed import SlamFeed; "
            "from kosmap.backend.slam import Slam; from kosmap.mapping.runtime.slamproc import RemoteFeed; "
            "c = load_config(None, []); "
            "r = RemoteFeed(SlamFeed(Slam(c.odometry, c.graph), False), 'laser'); print(r._proc.pid, flush=True); "
            "time.sleep(60)")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(p.stdout.readline())
    p.kill()
    p.wait()

    def alive(pid: int) -> bool:
        try:
            with open(f"/proc/{pid}/status") as fh:
                return not any(line.startswith("State:") and "Z" in line for line in fh)
        except FileNotFoundError:
            return False

    deadline = time.monotonic() + 20
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(child)


def test_samples_go_as_arrays_and_give_the_in_process_result():
    """Wheel and gyro samples reach the child as numbers in arrays (not a pickled tuple or record each), replayed in
    their place among the scans: with a gyro at 4× the scan rate and batches cut mid-step, SLAM gets exactly what
    it gets in this process."""
    from kosmap.frontend.records import Imu

    def calls():
        for name, args in _calls():
            yield name, args
            if name == "odom":  # a gyro sample beside each odometry sample, and one between
                t = args[0].stamp_ns
                for dt in (0, 25_000_000):
                    yield "imu", (Imu(t + dt, np.array([0.0, 0.0, 1e-3 * (t // 10_000_000 % 7)]), np.zeros(3)),)

    local = _gyro_feed()
    assert local.use_imu
    _run(local, calls())
    want = local.result()
    remote = RemoteFeed(_gyro_feed(), "laser")
    remote.BATCH = 37  # batches end mid-step
    real_send = remote._conn.send
    sent = []
    remote._conn.send = lambda obj: (sent.append(obj), real_send(obj))
    try:
        _run(remote, calls())
        got = remote.result()
    finally:
        remote.close()
    assert len(sent) > 5 and sum(len(b[3]) for b in sent) == 61  # the objects: 60 scans and the end, no sample
    events = [e for b in sent for e in _events(b)]
    assert sum(len(args[0]) for name, args in events if name == "gyro_samples") == 240
    assert sum(len(args[0]) for name, args in events if name == "wheel_samples") == 120
    assert np.array_equal(got.poses, want.poses) and np.array_equal(got.stamps_ns, want.stamps_ns)
    assert got.imu_stats == want.imu_stats and got.imu_stats["samples"] == 240 and got.imu_stats["factors"] > 10


def test_scans_released_by_the_odometry_timeout_get_the_in_process_result():
    """Odometry whose stamps lag the scans by 1.2 s (an unsynced clock): every scan is handed to SLAM by the 1 s
    timeout, with the samples read by then. Batches cut anywhere must replay the samples exactly in their place
    among the scans and advances, or the remote SLAM would see samples read later and differ."""
    from kosmap.frontend.records import Imu

    def calls():
        rng = np.random.default_rng(4)
        for i in range(60):
            t = int(i * 1e8)
            lag = t - 1_200_000_000
            for k in (0, 1):
                if lag >= 0:
                    yield "odom", (Odometry(lag + k * 50_000_000, 0.05 * (lag / 1e8) + 0.025 * k, 0.0, 0.0,
                                            "odom", "base_link", "/odom"),)
                    yield "imu", (Imu(lag + k * 50_000_000, np.array([0.0, 0.0, 1e-3 * (i % 5)]), np.zeros(3)),)
            yield "push", (t, _corridor_scan(0.05 * i, rng))
            yield "advance", (t + 50_000_000,)

    local = _gyro_feed()
    _run(local, calls())
    want = local.result()
    for batch in (5, 37, 256):
        remote = RemoteFeed(_gyro_feed(), "laser")
        remote.BATCH = batch
        try:
            _run(remote, calls())
            got = remote.result()
        finally:
            remote.close()
        assert np.array_equal(got.odom_poses, want.odom_poses, equal_nan=True), batch
        assert np.array_equal(got.poses, want.poses) and got.imu_stats == want.imu_stats, batch
    assert np.isfinite(want.odom_poses).all(axis=1).sum() > 30  # most scans got a (held) odometry prior


def test_samples_in_columns_give_the_per_sample_result():
    """wheel_samples / gyro_samples (an OdometrySamples' or ImuSamples' columns, what the build hands over for a
    stretch of the log) give exactly what one call per sample gives, in this process and in a SLAM process."""
    from kosmap.frontend.records import Imu

    def per_sample():
        for name, args in _calls():
            yield name, args
            if name == "odom":
                t = args[0].stamp_ns
                yield "imu", (Imu(t + 10_000_000, np.array([0.0, 0.0, 1e-3 * (t // 10_000_000 % 7)]), np.zeros(3)),)

    def in_columns():
        wheel, gyro = [], []
        for name, args in per_sample():
            if name == "odom":
                o = args[0]
                wheel.append((o.stamp_ns, o.x, o.y, o.yaw))
                continue
            if name == "imu":
                gyro.append((args[0].stamp_ns, args[0].yaw_rate))
                continue
            if wheel:  # the stretch before this scan: wheel columns, then gyro columns (as a chunk's batches come)
                t, x, y, a = (np.array(c) for c in zip(*wheel))
                yield "wheel_samples", (t.astype(np.int64), x, y, a)
                t, w = (np.array(c) for c in zip(*gyro))
                yield "gyro_samples", (t.astype(np.int64), w)
                wheel, gyro = [], []
            yield name, args

    local = _gyro_feed()
    _run(local, per_sample())
    want = local.result()
    columns = _gyro_feed()
    _run(columns, in_columns())
    got = columns.result()
    assert np.array_equal(got.poses, want.poses) and got.imu_stats == want.imu_stats
    assert got.imu_stats["samples"] == 120 and got.imu_stats["factors"] > 10
    remote = RemoteFeed(_gyro_feed(), "laser")
    remote.BATCH = 37
    try:
        _run(remote, in_columns())
        got = remote.result()
    finally:
        remote.close()
    assert np.array_equal(got.poses, want.poses) and got.imu_stats == want.imu_stats
