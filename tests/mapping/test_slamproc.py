"""mapping/slamproc.py: a SLAM fed in its own process gives exactly the in-process result; its failures reach the
parent as errors that say what happened."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from frontend.errors import KosmapError
from frontend.records import Odometry
from mapping.config import load_config
from mapping.pipeline import SlamFeed
from mapping.slam import Slam
from mapping.slamproc import RemoteFeed


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


def _feed_calls(feed, n: int = 60) -> None:
    """A robot driving 5 cm a step along the corridor, odometry at twice the scan rate."""
    rng = np.random.default_rng(3)
    for i in range(n):
        t = int(i * 1e8)
        for k in (0, 1):
            feed.odom(Odometry(t + k * 50_000_000, 0.05 * i + 0.025 * k, 0.0, 0.0, "odom", "base_link", "/odom"))
        feed.push(t, _corridor_scan(0.05 * i, rng))
        feed.advance(t + 50_000_000)
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
