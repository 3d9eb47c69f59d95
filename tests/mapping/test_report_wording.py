"""The report and the console say what ran: a laser-only log has no depth camera map and no depth frames for its
workers; a KOS level that saw no obstacle is called out rather than shown as open floor; the SLAM's log time and
real-time factor are filled in a build."""

from __future__ import annotations

import json
import math

import pytest

from kosmap.mapping.report import map_warnings, summary_caption
from tests.frontend.synthetic_log import write_mcap
from tests.mapping.synthetic_laser import make_log, records
from kosmap.tools.cli import main


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    """A laser-only log (the synthetic ring: laser, wheel odometry, ground truth; no depth camera)."""
    log = make_log(seed=1, laps=1)
    path = write_mcap(records(log), tmp_path_factory.mktemp("ring") / "ring.mcap")
    return path, (log.stamps_ns[-1] - log.stamps_ns[0]) * 1e-9


@pytest.fixture(scope="module")
def laser_build(ring, tmp_path_factory):
    path, span = ring
    out = tmp_path_factory.mktemp("laser_build")
    assert main(["build", str(path), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    return out, json.loads((out / "metrics.json").read_text()), span


def test_a_laser_only_report_names_the_laser_map_and_what_the_workers_did(laser_build):
    out, _, _ = laser_build
    md = (out / "report.md").read_text()
    assert "*the laser's map, from its SLAM*" in md
    assert "depth camera" not in md and "KOS scans" not in md
    assert "× real time (laser only: 2 worker processes for the maps and comparisons)." in md
    assert "worker process(es)" not in md
    assert "- kosmap.mcap: laser scans, /tf, paths and maps for Foxglove" in md
    assert "stats.csv" not in md  # written with its header only: no depth frames
    html = (out / "report.html").read_text()
    assert "the laser&#x27;s map, from its SLAM" in html and "depth camera" not in html


def test_a_build_fills_in_the_slam_log_time_and_real_time_factor(laser_build):
    _, m, span = laser_build
    s = m["slam"]["laser"]
    assert s["duration_s"] == pytest.approx(span, abs=1e-6) and span > 100
    busy = sum(s["seconds"].values())  # SLAM beside the reading: the time of its own stages
    assert s["realtime_factor"] == pytest.approx(span / busy) and math.isfinite(s["realtime_factor"])


def test_the_summary_caption_names_only_the_maps_shown():
    both = {"slam_scan": "obstacle", "maps": {"kos_obstacle": {}, "laser": {}}}
    assert summary_caption(both) == "the depth camera's (KOS) map and the laser's, each from its own SLAM"
    assert summary_caption({"slam_scan": "obstacle", "maps": {"kos_obstacle": {}, "kos_h0_30": {}}}) == \
        "the depth camera's (KOS) map, from its SLAM"
    assert summary_caption({"slam_scan": "obstacle", "maps": {"laser": {}}}) == "the laser's map, from its SLAM"


def test_map_warnings_name_a_kos_level_without_obstacles_only():
    m = {"config": {"depth": {"max_depth": 4.5}},
         "maps": {"kos_h5_00": {"source": "kos", "level": "h5_00", "scans": 40, "occupied_cells": 0, "known_cells": 10737},
                  "kos_h0_30": {"source": "kos", "level": "h0_30", "scans": 40, "occupied_cells": 250, "known_cells": 9000},
                  "kos_h1_50": {"source": "kos", "level": "h1_50", "scans": 0, "occupied_cells": 0, "known_cells": 0}}}
    assert map_warnings(m) == [
        "map_kos_h5_00: the KOS level h5_00 saw no obstacle in its 40 scans, so its 10737 known cells are all drawn "
        "free; check that the camera sees that height (its mount's height and pitch, its vertical field of view, "
        "[depth] max_depth = 4.5 m) or choose other [kos] levels"]


@pytest.mark.slow
def test_a_level_the_camera_never_sees_is_warned_in_the_console_and_the_report(tmp_path, capsys):
    """The room's camera at 1 m looking level sees at most ~3.6 m up (4.5 m × tan 30°); 5 m passes the config only
    with a higher obstacle scan, and its map must not pass for open floor."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "room.mcap"
    simulate(load_world("room"), SimConfig(seed=2, duration=1.5), log)
    out = tmp_path / "out"
    code = main(["build", str(log), "--out", str(out), "--workers", "0", "--set", "kos.levels=[0.5,5.0]",
                 "--set", "kos.obstacle_max=6", "--set", "build.mcap_planes_period=0"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    m = json.loads((out / "metrics.json").read_text())
    assert m["maps"]["kos_h5_00"]["occupied_cells"] == 0 and m["maps"]["kos_h0_50"]["occupied_cells"] > 0
    line = "map_kos_h5_00: the KOS level h5_00 saw no obstacle in its"
    assert f"warning: {line}" in cap.err and "map_kos_h0_50" not in cap.err
    md = (out / "report.md").read_text()
    assert f"- {line}" in md and "saw no obstacle: every known cell drawn free (see Warnings)" in md
    assert m["slam"]["kos"]["duration_s"] > 1.0 and m["slam"]["kos"]["realtime_factor"] > 0
