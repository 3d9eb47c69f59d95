"""`kosmap localize` never claims a look-alike place: the held-out ward (tests/worlds/ward.yaml), a corridor of 14
identical rooms whose doors repeat 3 m apart and a T junction at one end, seen by a laser narrower than a full turn
(a 240° Hokuyo URG-04LX, a 180° SICK-like scanner), or by the depth camera, with harsh wheels, no initial pose, in
the blueprint. Along the corridor the scan fits a place two or three door pitches over as well as the truth; a
particle set collapsed on either is tight, so the claim waits until one place alone fits (mapping/localize_claim.py:
the junction in view); and a track once claimed is handed to a far mode of the particles only where the data are
sure of it. Scored against the log's ground truth without alignment: no claimed pose more than 0.5 m off, RMSE
≤ 0.05 m and heading ≤ 1° from the claim on, never lost."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kosmap.tools.cli import main

WORLDS = Path(__file__).resolve().parents[1] / "worlds"
HARSH = dict(odom_scale_error_left=0.02, odom_scale_error_right=0.028, odom_heading_bias_deg_per_m=0.3)
URG_04LX = dict(laser_fov_deg=240.0, laser_beams=683, laser_range_max=5.6)
SICK_180 = dict(laser_fov_deg=180.0, laser_beams=361, laser_range_max=80.0)


def _ward(tmp_path, capsys, source: str, **sim) -> dict:
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    world = load_world(str(WORLDS / "ward.yaml"))
    log, plan = tmp_path / "ward.mcap", tmp_path / "ward_plan.yaml"
    simulate(world, SimConfig(**HARSH, **sim, speed_min=0.6, speed_max=0.9, compression="lz4"), log)
    write_map_server(world.blueprint(0.05), plan, image_ext=".png")
    out = tmp_path / "out"
    code = main(["localize", str(log), "--map", str(plan), "--out", str(out), "--source", source, "--quiet"])
    assert code == 0, capsys.readouterr().err
    return json.loads((out / "metrics.json").read_text())


def _never_off_then_within_goals(loc: dict, tr: dict) -> None:
    """No tracked pose on a look-alike (0.5 m: a sixth of the rooms' 3 m pitch), the goals after the claim
    (RMSE ≤ 0.05 m, heading ≤ 1°), never lost."""
    assert tr["while_tracking"]["position_m"]["max"] <= 0.5, tr
    assert tr["after_convergence"]["position_m"]["rmse"] <= 0.05, tr
    assert tr["after_convergence"]["heading_deg"]["rmse"] <= 1.0, tr
    assert not loc["lost"], loc


@pytest.mark.slow
@pytest.mark.parametrize("seed, laser", [(4, URG_04LX), (1, SICK_180)])
def test_ward_look_alike_rooms_are_not_claimed_by_a_narrower_laser(tmp_path, capsys, seed, laser):
    m = _ward(tmp_path, capsys, "laser", seed=seed, **laser, depth_rate=0.2, depth_width=32, depth_height=24, imu=False)
    loc, tr = m["localization"], m["truth"]
    # measured: claimed at 27.4 s (240°, seed 4) and 20.8 s (180°, seed 1), once the T junction is in view, then
    # 0.015 / 0.014 m RMSE, at most 0.036 / 0.032 m off; a claim from the tight set alone came at 5.8 / 4.3 s on a
    # look-alike place 6-12 m off
    assert loc["converged_s"] is not None, loc
    # metrics.json lists the uniqueness tests: the tight set's earlier claims turned down, the last one made
    checks = loc["search"]["searches"]
    assert any(not c["claim"] and c["t_s"] < loc["converged_s"] for c in checks) and checks[-1]["claim"], checks
    _never_off_then_within_goals(loc, tr)


@pytest.mark.slow
def test_ward_depth_camera_track_is_not_handed_to_the_floors_half_turn_image(tmp_path, capsys):
    """The depth camera (10 Hz, half resolution): claimed by the window's search once the T junction is in view, then
    driven in and out of the rooms. Leaving a room, a scan taken in the doorway reads 13 % of its rays through the
    jamb at the right pose, while the particles have spread over the rooms' look-alikes; the track goes to the
    particles' mode only where the window is sure of it over the track."""
    m = _ward(tmp_path, capsys, "kos", seed=1, depth_rate=10.0, depth_width=256, depth_height=212)
    loc, tr = m["localization"], m["truth"]
    # measured: claimed at 26.3 s, then 0.030 m RMSE, at most 0.19 m off, never lost; handed to the mode on the
    # doorway's scan, the track went to the half-turn image at 107 s (4.7 m off) and ended 21 m off, still tracking
    assert loc["converged_s"] is not None, loc
    _never_off_then_within_goals(loc, tr)
