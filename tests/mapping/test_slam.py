"""SLAM end to end on a synthetic laser world with exact ground truth (tests/mapping/synthetic_laser.py):
with and without wheel odometry, with time gaps and empty scans, and from a log file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kosmap.backend.graph import GraphConfig
from kosmap.backend.metrics import ate
from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.odometry import OdometryConfig, scan_points_base
from kosmap.frontend.records import Scan
from kosmap.mapping.config import Config
from kosmap.backend.slam import Slam
from kosmap.mapping.slam import evaluate, run_slam, save_run
from tests.mapping.synthetic_laser import make_log, records


@pytest.fixture(scope="module")
def log():
    return make_log(seed=0)


def _run(log, use_odom=True, drop=(), empty=(), **odo):
    slam = Slam(OdometryConfig(**odo), GraphConfig())
    keep = []
    for i, (scan, o) in enumerate(zip(log.scans, log.odom)):
        if i in drop:
            continue
        pts = scan_points_base(scan.ranges, scan.angles, scan.valid(), log.mount, 0.1, 30.0)
        if i in empty:
            pts = pts[:0]
        slam.add_scan(scan.stamp_ns, pts, o if use_odom else None)
        keep.append(i)
    r = slam.finish()
    return r, ate(r.stamps, r.poses, r.stamps, log.truth[keep])


def test_synthetic_laser_with_odometry(log):
    r, err = _run(log)
    odom = ate(r.stamps, log.odom, r.stamps, log.truth)
    assert err["rmse"] <= 0.05, err  # measured 0.035 m (odometry alone 0.62 m)
    assert odom["rmse"] > 5 * err["rmse"]  # the odometry drifts: the scans did the work
    assert len(r.loops) > 20  # the second lap closes on the first
    assert len(r.poses) == len(log.scans) and r.matched[1:].all()


def test_synthetic_laser_without_odometry(log):
    r, err = _run(log, use_odom=False)
    assert err["rmse"] <= 0.08, err  # measured 0.037 m


def test_time_gaps_and_empty_scans_still_run(log):
    drop = set(range(100, 115)) | set(range(700, 712))  # 3 s and 2.4 s without scans
    empty = {300, 301, 302, 900, 1000}  # scans without a single return
    r, err = _run(log, drop=drop, empty=empty)
    assert err["rmse"] <= 0.08, err  # measured 0.026 m
    assert len(r.poses) == len(log.scans) - len(drop)
    assert not r.matched[[np.searchsorted(r.stamps_ns, log.stamps_ns[i]) for i in sorted(empty)]].any()


def test_log_file_end_to_end(log, tmp_path):
    path = tmp_path / "ring.mcap"
    recs = records(log)
    # two empty scans in the file, too
    for k in (50, 51):
        i = next(j for j, rec in enumerate(recs) if isinstance(rec, Scan) and rec.stamp_ns == log.stamps_ns[k])
        s = recs[i]
        recs[i] = Scan(s.stamp_ns, np.full_like(s.ranges, np.inf), s.angle_min, s.angle_increment, s.range_min,
                       s.range_max, s.frame_id, s.topic)
    with McapWriter(path) as w:
        for rec in recs:
            w.write(rec)
    cfg = Config()
    r = run_slam(path, cfg, keep_scans=True)
    assert np.allclose(r.mount, log.mount, atol=1e-9)  # the laser mount came from /tf_static
    assert r.ground_truth is not None and len(r.ground_truth[0]) == len(log.scans)
    m = evaluate(r)  # scored against the log's own /ground_truth/odom
    assert m["ate"]["rmse"] <= 0.05, m["ate"]
    assert m["loop_precision_gt"]["precision"] >= 0.9
    assert any("fewer than" in w for w in r.warnings)
    from kosmap.mapping.slam import build_map

    paths = save_run(r, tmp_path / "out", cfg, m, build_map(r, cfg.grid))
    doc = json.loads(paths["metrics"].read_text())
    assert doc["run"]["scans"] == len(log.scans) and doc["ate"]["rmse"] <= 0.05
    assert paths["map_png"].stat().st_size > 1000 and paths["graph"].read_text().startswith("VERTEX_SE2 0")


def test_kos_source_needs_depth_frames(log, tmp_path):
    from kosmap.frontend.errors import TopicError
    from tests.frontend.synthetic_log import write_mcap

    path = write_mcap(records(log), tmp_path / "laser_only.mcap")
    with pytest.raises(TopicError, match="no depth image topic; --source kos needs one"):
        run_slam(path, source="kos")
