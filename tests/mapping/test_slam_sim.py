"""SLAM on the simulator's office log (tools/simulate): Hokuyo laser + drifting wheel odometry, scored against
the log's /ground_truth/odom."""

from __future__ import annotations

import pytest

from kosmap.mapping.config import Config
from kosmap.mapping.slam import evaluate, run_slam


@pytest.mark.slow
def test_simulated_office_laser_log(tmp_path):
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "office.mcap"
    # the depth camera is not used here: a tiny, rare depth image keeps the log small and quick to write
    cfg = SimConfig(seed=3, laser_rate=10.0, depth_rate=0.2, depth_width=32, depth_height=24, compression="lz4")
    simulate(load_world("office"), cfg, log)
    r = run_slam(log, Config())
    m = evaluate(r)
    odom = evaluate(type(r)(**{**r.__dict__, "poses": r.odom_poses}))["ate"]["rmse"]
    # measured (seed 3): 0.022 m RMSE, 0.126 m max, 27 of 27 loops correct; with per-wheel odometry
    # errors (total heading drift 0.215°/m; wheel odometry's ATE 0.94 → 1.74 m): 0.021 m, 0.123 m, precision 1.0
    assert m["ate"]["rmse"] <= 0.05, m["ate"]
    assert m["ate"]["max"] <= 0.25, m["ate"]
    assert odom > 0.2
    assert m["loop_precision_gt"]["precision"] >= 0.95, m["loop_precision_gt"]
