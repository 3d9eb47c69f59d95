"""KOS SLAM with the simulator's /imu on the office: a 90 s slice, and the whole office (361 s,
140 m, the corridor ring with two loops) on two seeds. One front Kinect at 10 Hz, at half resolution to keep CI
short (same 70.6° view and range), the default wheel-odometry errors (per-wheel scale 1.0/1.1 %, heading bias) and
the default MEMS gyro. Full-resolution numbers (3 seeds, 10 and 5 Hz, front + rear, laser):
tools/bench_kos_slam.py → docs/bench/kos_slam.md."""

from __future__ import annotations

import pytest

from kosmap.mapping.config import Config
from kosmap.mapping.slam import evaluate, run_slam, summary


def _office(tmp_path_factory, seed: int, duration: float | None = None):
    """The office simulated (the first `duration` s, or all of it): 10 Hz depth at half resolution, no laser; the
    default IMU (200 Hz, 0.005 °/s/√Hz, turn-on bias, bias walk) and per-wheel odometry scale errors."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate
    from kosmap.tools.simulate.log import simulation_truth

    log = tmp_path_factory.mktemp(f"office{seed}") / "office.mcap"
    cfg = SimConfig(seed=seed, depth_rate=10.0, depth_width=256, depth_height=212, laser=False, compression="lz4",
                    **({} if duration is None else {"duration": duration}))
    simulate(load_world("office"), cfg, log)
    return log, simulation_truth(log)["truth"]


@pytest.fixture(scope="module")
def office_slice(tmp_path_factory):
    return _office(tmp_path_factory, seed=3, duration=90.0)


def _run(log, imu: bool, workers: int = 0):
    """KOS SLAM at 10 Hz with or without the log's gyro: (result, evaluate(), summary())."""
    cfg = Config()
    cfg.build.depth_rate = 10.0
    if not imu:
        cfg.topics.imu = "none"
    r = run_slam(log, cfg, source="kos", workers=workers)
    return r, evaluate(r), summary(r)


@pytest.mark.slow
def test_office_slice_with_the_gyro(office_slice):
    log, truth = office_slice
    r1, e1, s1 = _run(log, True)
    r0, e0, s0 = _run(log, False)
    a1, a0 = e1["ate"]["rmse"], e0["ate"]["rmse"]
    assert s1["imu"]["samples"] > 100 * 90 and s1["factors"]["gyro"] >= s1["keyframes"] - 2
    assert s0["factors"]["gyro"] == 0 and s0["gyro_bias_deg_s"] is None
    # measured: 0.034 m with the gyro, 0.020 m without (the front end free along-track where the scan fixes it:
    # on this 90 s slice the gyro-aided graph's scale comes out +0.38 %, docs/benchmarks.md)
    assert a1 <= 0.10 and a1 <= a0 + 0.02, (a1, a0)
    true_bias = truth["imu"]["gyro_bias_initial_dps"][2]
    assert abs(s1["gyro_bias_deg_s"] - true_bias) <= 0.02, (s1["gyro_bias_deg_s"], true_bias)
    assert abs(s1["odometry_scale"] - truth["odometry"]["distance_scale"]) <= 0.01  # 90 s: loosely observed
    assert not any("gyro" in w for w in r1.warnings), r1.warnings


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_whole_office_kos_slam_with_the_gyro(tmp_path_factory, seed):
    log, truth = _office(tmp_path_factory, seed)
    _, e1, s1 = _run(log, imu=True, workers=2)
    ate, odo = e1["ate"]["rmse"], e1["ate_odometry"]["rmse"]
    scale_err = s1["odometry_scale"] / truth["odometry"]["distance_scale"] - 1.0
    # measured: seed 0 ATE 0.052 m, scale error +0.33 %; seed 1 0.032 m, +0.31 %. The scale comes out long by the
    # scan matcher's drag at mapped wall ends (docs/benchmarks.md, "KOS SLAM with harsh wheel odometry"); held to the
    # wheels along-track the front end gives +0.24 % / −0.01 % here but 0.17-0.20 m on the harsh corridors
    assert ate <= 0.10, (ate, odo)
    assert abs(scale_err) <= 0.004, (s1["odometry_scale"], truth["odometry"]["distance_scale"])
    assert abs(s1["gyro_bias_deg_s"] - truth["imu"]["gyro_bias_mean_dps"][2]) <= 0.01
    assert e1["ate"]["max"] <= 0.25  # no stretch bent off: the corridors stay straight
    if seed == 0:  # the same log without the gyro: must still beat the wheels by far
        _, e0, s0 = _run(log, imu=False, workers=2)
        print(f"office seed 0 without the gyro: ATE {e0['ate']['rmse']:.3f} m (with {ate:.3f} m, odometry {odo:.3f} m)")
        assert s0["factors"]["gyro"] == 0 and e0["ate"]["rmse"] < 0.5 * odo  # measured 0.107 m vs 0.81 m
