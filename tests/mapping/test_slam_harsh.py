"""Laser SLAM with harsh but ordinary wheel odometry (2 % and 2.8 % wheel radius errors, 0.3°/m heading bias) on
the simulated office and on the long-corridor world (a ring of 42 m bare corridors round a closed block, a 180°
SICK-like laser of 181 beams), scored against the log's ground truth. The robot drives at 0.8–1 m/s so that each
log is two minutes; no IMU (the CARMEN-era robots had none). KOS SLAM on the corridor world with the same wheels (one
Kinect and a gyro, the simulator's default speeds)."""

from __future__ import annotations

from pathlib import Path

import pytest

from kosmap.mapping.config import Config
from kosmap.mapping.slam import evaluate, run_slam, summary

WORLDS = Path(__file__).resolve().parents[2] / "tools" / "simulate" / "worlds"
HARSH = dict(odom_scale_error_left=0.02, odom_scale_error_right=0.028, odom_heading_bias_deg_per_m=0.3)
QUICK = dict(laser_rate=10.0, depth_rate=0.2, depth_width=32, depth_height=24, compression="lz4", imu=False,
             speed_min=0.8, speed_max=1.0)


def _run(tmp_path, world: str, seed: int, **laser):
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "harsh.mcap"
    simulate(load_world(world), SimConfig(seed=seed, **HARSH, **QUICK, **laser), log)
    r = run_slam(log, Config())
    return r, evaluate(r)


@pytest.mark.slow
@pytest.mark.parametrize("seed, wheels", [
    (9, HARSH),  # a seed the rule was not designed on (seeds 0-2 were)
    (3, dict(odom_scale_error_left=-0.015, odom_scale_error_right=-0.03, odom_heading_bias_deg_per_m=-0.3)),
])
def test_long_corridors_with_a_sick_and_harsh_odometry(tmp_path, seed, wheels):
    """Along a bare corridor the front end holds its along-track position to the wheels' prediction, so the corridor's
    length is the wheels' times the scale the graph estimates. That scale is seen only where the scans fix the motion
    (corners, doors, rooms): the odometry's noise measured there (backend/odomnoise.py) is the scale variable's prior,
    and the degenerate matches tell the graph nothing along the corridor (else they carry the prediction's scale error
    a second time, unscaled). Wheels that read long (2 %, 2.8 %) and wheels that read short (-1.5 %, -3 %, the heading
    bias the other way)."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate
    from kosmap.tools.simulate.log import simulation_truth

    log = tmp_path / "harsh.mcap"
    simulate(load_world(str(WORLDS / "corridors.yaml")),
             SimConfig(seed=seed, **wheels, **QUICK, laser_fov_deg=180.0, laser_beams=181), log)
    r = run_slam(log, Config())
    m = evaluate(r)
    true_scale = simulation_truth(log)["truth"]["odometry"]["distance_scale"]
    # measured: seed 9 ATE 0.081 m (max 0.148), scale 1.0181 against 1.024 (0.098 m, scale 1.0137 with the degenerate
    # matches' geometric share and the prior at 1); short wheels, seed 3: 0.038 m (max 0.074), scale 0.9784 against
    # 0.9775 (0.109 m, 0.9826 with the prior at 1). The wheels alone 10.9 m and 20.0 m
    assert m["ate"]["rmse"] <= 0.10, m["ate"]
    assert m["ate"]["max"] <= 0.3, m["ate"]
    assert m["ate_odometry"]["rmse"] > 2.0, m["ate_odometry"]
    assert abs(r.graph.odom_scale / true_scale - 1.0) <= 0.008, (r.graph.odom_scale, true_scale)
    assert len(r.loops) >= 5


@pytest.mark.slow
def test_office_with_harsh_odometry(tmp_path):
    r, m = _run(tmp_path, "office", 2)
    # measured 0.023 m RMSE, 0.086 m max, 27 loops
    assert m["ate"]["rmse"] <= 0.05, m["ate"]
    assert m["ate_odometry"]["rmse"] > 1.0, m["ate_odometry"]


@pytest.mark.slow
def test_kos_slam_on_the_long_corridors_with_harsh_odometry(tmp_path):
    """KOS SLAM (one front Kinect at 10 Hz, half resolution, and the gyro) on the corridor ring with the same harsh
    wheels: along a bare corridor the narrow scan fixes nothing along-track, so the wheels' 2.4 % scale must be
    measured where the scan does (corners, doors, the room) and carried through the corridors. That takes the front
    end held along-track only where the scan leaves that direction open (backend/kosprofile.py) and the KOS bins'
    surface means ([kos] nearest = surface: the nearest point is short). Held always, its matches repeat the wheels'
    scale: 0.23 m on this log with the same scans (docs/benchmarks.md)."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate
    from kosmap.tools.simulate.log import simulation_truth

    log = tmp_path / "harsh-kos.mcap"
    simulate(load_world(str(WORLDS / "corridors.yaml")),
             SimConfig(seed=1, **HARSH, depth_rate=10.0, depth_width=256, depth_height=212, laser=False,
                       compression="lz4"), log)
    cfg = Config()
    cfg.build.depth_rate = 10.0  # the defaults: surface means, the front end free where the scan fixes it
    r = run_slam(log, cfg, source="kos", workers=2)
    m = evaluate(r)
    scale = summary(r)["odometry_scale"]
    true_scale = simulation_truth(log)["truth"]["odometry"]["distance_scale"]
    # measured ATE 0.047 m (max 0.103 m), scale 1.0224 against the true 1.0240, the wheels alone 9.98 m (keyframes at
    # 7.5°, [odometry] keyframe_spacing = "fixed": 0.056 m, max 0.124 m, scale 1.0217); at 0.8-1 m/s
    # instead of 0.3-0.6 m/s the same run gave 0.121 m (docs/benchmarks.md, KOS SLAM with harsh wheel odometry)
    assert m["ate"]["rmse"] <= 0.10, (m["ate"], scale, true_scale)
    assert m["ate_odometry"]["rmse"] > 1.0, m["ate_odometry"]
    assert abs(scale / true_scale - 1.0) <= 0.005, (scale, true_scale)
