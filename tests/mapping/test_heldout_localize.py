"""`kosmap localize` on held-out worlds (tests/worlds/) with lasers unlike the default and harsh wheel odometry, no
initial pose, in the building's blueprint; scored against the log's ground truth without alignment. The goals are
localize's own: found within 20 s of log, then position RMSE ≤ 0.05 m and heading RMSE ≤ 1°, never lost.

- atrium: an irregular hall with walls at 30° and 60°, pillars, glazing mullions and round objects the blueprint
  lacks, seen by a Hokuyo URG-04LX (240°, 683 beams, 5.6 m: in the middle of the hall little but pillars);
- ward: a corridor of 14 identical rooms and doors 3 m apart, seen by a 360° RPLidar-like scanner (360 beams,
  12 m, 5.5 Hz, 2 cm noise) that sees the corridor's dead end behind the robot at the start."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kosmap.tools.cli import main

WORLDS = Path(__file__).resolve().parents[1] / "worlds"
HARSH = dict(odom_scale_error_left=0.02, odom_scale_error_right=0.028, odom_heading_bias_deg_per_m=0.3)
URG_04LX = dict(laser_fov_deg=240.0, laser_beams=683, laser_range_max=5.6, laser_rate=10.0)
RPLIDAR = dict(laser_fov_deg=360.0, laser_beams=360, laser_range_max=12.0, laser_rate=5.5, laser_sigma=0.02)


@pytest.mark.slow
@pytest.mark.parametrize("name, seed, sim", [("atrium", 2, URG_04LX),
                                             ("ward", 0, dict(RPLIDAR, speed_min=0.6, speed_max=0.9))])
def test_held_out_building_localized_with_another_laser(tmp_path, capsys, name, seed, sim):
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    world = load_world(str(WORLDS / f"{name}.yaml"))
    log, plan = tmp_path / f"{name}.mcap", tmp_path / f"{name}_plan.yaml"
    simulate(world, SimConfig(seed=seed, **HARSH, **sim, depth_rate=0.2, depth_width=32, depth_height=24,
                              imu=False, compression="lz4"), log)
    write_map_server(world.blueprint(0.05), plan, image_ext=".png")
    out = tmp_path / "out"
    code = main(["localize", str(log), "--map", str(plan), "--out", str(out), "--source", "laser", "--quiet"])
    assert code == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    loc, tr = m["localization"], m["truth"]["after_convergence"]
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0, loc
    assert tr["position_m"]["rmse"] <= 0.05, tr
    assert tr["heading_deg"]["rmse"] <= 1.0, tr
    assert not loc["lost"], loc
