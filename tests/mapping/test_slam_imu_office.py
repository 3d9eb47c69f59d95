"""KOS SLAM with the simulator's /imu on a slice of the office (issue #9). The whole-office acceptance (3 seeds,
10 and 5 Hz depth, ATE and scale against the simulator's truths) is tools/bench_kos_slam.py → docs/bench/kos_slam.md;
a full office log takes minutes to simulate and to run through FSPF+/KOS, this slice under a minute."""

from __future__ import annotations

import pytest

from mapping.config import Config
from mapping.slam import evaluate, run_slam, summary


@pytest.fixture(scope="module")
def office_slice(tmp_path_factory):
    from tools.simulate import SimConfig, load_world, simulate
    from tools.simulate.log import simulation_truth

    log = tmp_path_factory.mktemp("imu") / "office.mcap"
    # the first 90 s of the office, 10 Hz depth at half resolution (same 70.6° view), no laser; the default
    # IMU (200 Hz, 0.005 °/s/√Hz, turn-on bias, bias walk) and per-wheel odometry scale errors
    cfg = SimConfig(seed=3, duration=90.0, depth_rate=10.0, depth_width=256, depth_height=212, laser=False, compression="lz4")
    simulate(load_world("office"), cfg, log)
    return log, simulation_truth(log)["truth"]


def _run(log, imu: bool):
    cfg = Config()
    cfg.build.depth_rate = 10.0
    if not imu:
        cfg.topics.imu = "none"
    r = run_slam(log, cfg, source="kos")
    return r, evaluate(r)["ate"]["rmse"], summary(r)


@pytest.mark.slow
def test_office_slice_with_the_gyro(office_slice):
    log, truth = office_slice
    r1, a1, s1 = _run(log, True)
    r0, a0, s0 = _run(log, False)
    assert s1["imu"]["samples"] > 100 * 90 and s1["factors"]["gyro"] >= s1["keyframes"] - 2
    assert s0["factors"]["gyro"] == 0 and s0["gyro_bias_deg_s"] is None
    assert a1 <= 0.10 and a1 <= a0 + 0.01, (a1, a0)
    true_bias = truth["imu"]["gyro_bias_initial_dps"][2]
    assert abs(s1["gyro_bias_deg_s"] - true_bias) <= 0.02, (s1["gyro_bias_deg_s"], true_bias)
    assert abs(s1["odometry_scale"] - truth["odometry"]["distance_scale"]) <= 0.01  # 90 s: loosely observed
    assert not any("gyro" in w for w in r1.warnings), r1.warnings
