"""`kosmap localize` on a held-out world (tests/worlds/atrium.yaml: an irregular hall with walls at 30° and 60°,
pillars, glazing mullions and round objects the blueprint lacks), with a laser unlike the default (a Hokuyo
URG-04LX: 240°, 683 beams, 5.6 m) and harsh wheel odometry, no initial pose, in the building's blueprint; scored
against the log's ground truth without alignment. The goals are localize's own: found within 20 s of log, then
position RMSE ≤ 0.05 m and heading RMSE ≤ 1°."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kosmap.tools.cli import main

WORLDS = Path(__file__).resolve().parents[1] / "worlds"
HARSH = dict(odom_scale_error_left=0.02, odom_scale_error_right=0.028, odom_heading_bias_deg_per_m=0.3)
URG_04LX = dict(laser_fov_deg=240.0, laser_beams=683, laser_range_max=5.6, laser_rate=10.0)


@pytest.mark.slow
def test_irregular_hall_localized_with_a_short_range_laser(tmp_path, capsys):
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    world = load_world(str(WORLDS / "atrium.yaml"))
    log, plan = tmp_path / "atrium.mcap", tmp_path / "atrium_plan.yaml"
    simulate(world, SimConfig(seed=2, **HARSH, **URG_04LX, depth_rate=0.2, depth_width=32, depth_height=24,
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
