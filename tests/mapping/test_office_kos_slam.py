"""Issues 6 and 9 acceptance on the whole simulated office (361 s, 140 m, the corridor ring with two loops): one front
Kinect (10 Hz, at half resolution to keep CI short: same 70.6° view and range), the default wheel-odometry errors
(per-wheel scale 1.0/1.1 %, heading bias) and the default MEMS gyro. KOS SLAM with the gyro must reach ATE ≤ 0.10 m
and estimate the odometry's distance scale within 0.2 % of the simulator's truth, on several seeds; without the
gyro the result is measured and must still beat the wheel odometry. Full-resolution numbers (3 seeds, 10 and 5 Hz,
front + rear, laser) are in docs/bench/kos_slam.md (tools/bench_kos_slam.py)."""

from __future__ import annotations

import pytest

from mapping.config import Config
from mapping.slam import evaluate, run_slam, summary


def _office(tmp_path_factory, seed: int):
    from tools.simulate import SimConfig, load_world, simulate
    from tools.simulate.log import simulation_truth

    log = tmp_path_factory.mktemp(f"office{seed}") / "office.mcap"
    simulate(load_world("office"), SimConfig(seed=seed, depth_rate=10.0, depth_width=256, depth_height=212, laser=False,
                                             compression="lz4"), log)
    return log, simulation_truth(log)["truth"]


def _run(log, imu: bool):
    cfg = Config()
    cfg.build.depth_rate = 10.0
    if not imu:
        cfg.topics.imu = "none"
    r = run_slam(log, cfg, source="kos", workers=2)
    return evaluate(r), summary(r)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_whole_office_kos_slam_with_the_gyro(tmp_path_factory, seed):
    log, truth = _office(tmp_path_factory, seed)
    e1, s1 = _run(log, imu=True)
    ate, odo = e1["ate"]["rmse"], e1["ate_odometry"]["rmse"]
    scale_err = s1["odometry_scale"] / truth["odometry"]["distance_scale"] - 1.0
    # measured 2026-11-22: seed 0 ATE 0.029-0.034 m (odometry 0.81 m), scale error +0.12 %
    assert ate <= 0.10, (ate, odo)
    assert abs(scale_err) <= 0.002, (s1["odometry_scale"], truth["odometry"]["distance_scale"])
    assert abs(s1["gyro_bias_deg_s"] - truth["imu"]["gyro_bias_mean_dps"][2]) <= 0.01
    assert e1["ate"]["max"] <= 0.25  # no stretch bent off: the corridors stay straight
    if seed == 0:  # the same log without the gyro: reported in the issue, must still beat the wheels by far
        e0, s0 = _run(log, imu=False)
        print(f"office seed 0 without the gyro: ATE {e0['ate']['rmse']:.3f} m (with {ate:.3f} m, odometry {odo:.3f} m)")
        assert s0["factors"]["gyro"] == 0 and e0["ate"]["rmse"] < 0.5 * odo  # measured 0.107 m vs 0.81 m
