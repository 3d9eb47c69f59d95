"""`mapping.build.build` end to end on short simulated logs of the room world: serial and parallel runs give
identical maps; a log without a laser, without depth or with neither; an interrupted run writes partial outputs;
every output exists and parses."""

from __future__ import annotations

import csv
import json
import re
import tomllib

import numpy as np
import pytest

from kosmap.backend.trajio import read_tum
from kosmap.frontend.errors import ConfigError, TopicError
from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.records import CameraModel, DepthFrame, Scan
from kosmap.mapping.config import load_config
from kosmap.mapping.mapio import read_map_server, write_map_server
from kosmap.mapping.build import Progress, build
from tests.frontend.synthetic_log import copy_log

# lean settings for seconds-long logs: the room's 11 m loop from its start, a cloud every 0.5 s in the MCAP
SETS = ["build.mcap_planes_period=0.5", "build.depth_rate=0"]  # every frame of the 30 Hz camera (the default takes 10 Hz)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    d = tmp_path_factory.mktemp("pipeline")
    world = load_world("room")
    full = d / "room.mcap"
    simulate(world, SimConfig(seed=4, duration=2.5), full)
    bp = write_map_server(world.blueprint(0.05), d / "room_bp.yaml", ".png")
    laser_only = d / "laser_only.mcap"
    copy_log(full, laser_only, lambda r: not isinstance(r, (DepthFrame, CameraModel)))
    depth_only = d / "depth_only.mcap"
    copy_log(full, depth_only, lambda r: not isinstance(r, Scan))
    neither = d / "neither.mcap"
    copy_log(full, neither, lambda r: not isinstance(r, (DepthFrame, CameraModel, Scan)))
    return {"full": full, "laser_only": laser_only, "depth_only": depth_only, "neither": neither, "blueprint": bp}


@pytest.fixture(scope="module")
def serial_run(logs, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    return build(logs["full"], out, load_config(None, SETS), blueprint=logs["blueprint"], workers=0)


@pytest.mark.slow
def test_serial_and_parallel_runs_give_identical_maps(logs, serial_run, tmp_path):
    par = build(logs["full"], tmp_path, load_config(None, SETS), blueprint=logs["blueprint"], workers=2)
    a, b = serial_run.metrics, par.metrics
    assert a["frames"]["processed"] == b["frames"]["processed"] == 75  # 2.5 s at 30 Hz (SETS: every frame)
    assert set(a["maps"]) == set(b["maps"]) == {"kos_h0_30", "kos_h0_75", "kos_h1_50", "kos_obstacle", "laser",
                                               "fused", "kos_obstacle_at_laser_poses"}
    for name in a["maps"]:
        ga = read_map_server(serial_run.out / f"map_{name}.yaml")
        gb = read_map_server(par.out / f"map_{name}.yaml")
        assert ga.origin == gb.origin and np.array_equal(ga.data, gb.data), name
        assert (serial_run.out / f"map_{name}.pgm").read_bytes() == (par.out / f"map_{name}.pgm").read_bytes()
    for src in ("kos", "laser"):
        ta, pa = read_tum(serial_run.out / f"trajectory_{src}.tum")
        tb, pb = read_tum(par.out / f"trajectory_{src}.tum")
        assert np.array_equal(ta, tb) and np.array_equal(pa, pb), src
    assert (serial_run.out / "stats.csv").read_text().splitlines()[1:] and \
        [r.split(",")[:9] for r in (serial_run.out / "stats.csv").read_text().splitlines()] == \
        [r.split(",")[:9] for r in (par.out / "stats.csv").read_text().splitlines()]  # all but the timings
    assert a["table_5_5"]["workers"] == 0 and b["table_5_5"]["workers"] == 2


@pytest.mark.slow
def test_outputs_exist_and_parse(serial_run, logs):
    out, m = serial_run.out, serial_run.metrics
    assert not serial_run.partial and m["partial"] is False
    assert not list(out.glob("*.partial")) and not list(out.glob(".kosmap-spill-*"))  # nothing half-written, spill gone
    # maps: map_server YAML + PGM and a PNG per source and level
    for name in m["maps"]:
        g = read_map_server(out / f"map_{name}.yaml")
        assert g.resolution == pytest.approx(0.05) and (g.data == 100).any() and (g.data == 0).any(), name
        assert (out / f"map_{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # trajectories (TUM) cover the log; the ground truth is written beside them
    t, p = read_tum(out / "trajectory_kos.tum")
    assert len(t) == m["frames"]["steps"] == 75 and p.shape == (75, 3)
    assert t[-1] - t[0] == pytest.approx(2.5 - 1 / 30, abs=0.01)
    assert len(read_tum(out / "ground_truth.tum")[0]) >= 250
    # stats.csv: one row per frame with the Table 5.2 columns
    with open(out / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 75
    r = rows[0]
    parts = float(r["ineligible_pct"]) + float(r["inlier_pct"]) + float(r["dropped_pct"]) + float(r["outlier_pct"])
    assert 0 < parts <= 100.0 + 1e-6 and float(r["fspf_ms"]) > 0
    # metrics.json: strict JSON, accuracy on this short loop segment, comparisons at every tolerance
    m2 = json.loads((out / "metrics.json").read_text())
    assert m2["sources"] == {"kos": True, "laser": True, "ground_truth": True, "blueprint": str(logs["blueprint"])}
    assert m2["slam"]["laser"]["ate"]["rmse"] < 0.05 and m2["slam"]["kos"]["ate"]["rmse"] < 0.10
    assert set(m2["comparisons"]) == {"kos_obstacle_vs_blueprint", "laser_vs_blueprint", "fused_vs_blueprint",
                                      "kos_obstacle_at_laser_poses_vs_blueprint", "kos_obstacle_vs_laser"}
    for c in m2["comparisons"].values():
        assert set(c["tolerances"]) == {"0.05", "0.10", "0.20"}
    # the maps on the laser's poses go through the laser map's alignment: the same frame, one transform
    al = m2["comparisons"]["laser_vs_blueprint"]["alignment"]
    for k in ("fused_vs_blueprint", "kos_obstacle_at_laser_poses_vs_blueprint"):
        assert m2["comparisons"][k]["alignment"] == {**al, "from": "laser"}
    assert "from" not in m2["comparisons"]["kos_obstacle_vs_blueprint"]["alignment"]
    lb = m2["comparisons"]["laser_vs_blueprint"]["tolerances"]["0.10"]
    assert lb["recall_observed"] > 0.85  # the laser finds the room's walls where it looks ...
    assert lb["precision"] > 0.75  # ... and sees furniture the plan lacks (table legs, shelves, a box)
    kb = m2["comparisons"]["kos_obstacle_vs_blueprint"]["tolerances"]["0.10"]
    assert kb["precision"] > 0.7 and kb["coverage"] > 0.3  # furniture, and KOS SLAM's error
    t55 = m2["table_5_5"]
    assert t55["fspf_ms"]["n"] == 75 and t55["system_hz"] > 0 and m2["timing"]["realtime_factor"] > 0
    # the effective config round-trips
    cfg = tomllib.loads((out / "config.toml").read_text())
    assert cfg["build"]["mcap_planes_period"] == 0.5 and cfg["build"]["slam_scan"] == "obstacle"
    # report.html: self-contained (every image embedded), says what it shows; report.md links the PNGs
    html = (out / "report.html").read_text()
    imgs = re.findall(r"<img [^>]*src='([^']*)'", html)
    assert len(imgs) >= len(m["maps"]) + len(m["comparisons"]) + 2  # maps, overlays, trajectories, frames
    assert all(s.startswith("data:image/png;base64,") for s in imgs)
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]*", "", html)  # base64 may spell "http" by chance
    assert "http" not in text and "Table 5.2" in html and "Table 5.5" in html and "ATE" in html
    assert "PARTIAL" not in html
    md = (out / "report.md").read_text()
    for png in re.findall(r"\]\(([^)]+\.png)\)", md):
        assert (out / png).is_file(), png
    # the MCAP for Foxglove: scans per level, laser, fused, plane points, /tf, paths and every map
    with open_log(out / "kosmap.mcap") as log:
        counts = {t.name: t.count for t in log.info().topics}
    for level in ("h0_30", "h0_75", "h1_50", "obstacle"):
        assert counts[f"/kinect_scan/{level}"] == 75
    assert counts["/tf"] == 75 and counts["/tf_static"] == 1 and counts["/scan"] == m["frames"]["laser_scans_used"]
    assert counts["/kinect_scan/fused"] >= 20 and counts["/kosmap/planes/points"] == 5
    assert counts["/kosmap/path/kos"] == counts["/kosmap/path/laser"] == counts["/kosmap/path/ground_truth"] == 1
    assert {f"/kosmap/map/{n}" for n in m["maps"]} <= set(counts)


@pytest.mark.slow
def test_a_log_without_laser_builds_the_kos_maps_alone(logs, tmp_path):
    res = build(logs["depth_only"], tmp_path, load_config(None, SETS), blueprint=logs["blueprint"], workers=0)
    m = res.metrics
    assert m["sources"]["laser"] is False and set(m["slam"]) == {"kos"}
    assert set(m["maps"]) == {"kos_h0_30", "kos_h0_75", "kos_h1_50", "kos_obstacle"}
    assert set(m["comparisons"]) == {"kos_obstacle_vs_blueprint"}
    assert not (tmp_path / "trajectory_laser.tum").exists() and (tmp_path / "report.html").is_file()


@pytest.mark.slow
def test_a_log_without_depth_builds_the_laser_map_alone(logs, tmp_path):
    res = build(logs["laser_only"], tmp_path, load_config(None, SETS), workers=2)
    m = res.metrics
    assert m["sources"]["kos"] is False and set(m["slam"]) == {"laser"} and set(m["maps"]) == {"laser"}
    assert m["comparisons"] == {} and m["frames"]["processed"] == 0
    assert m["frames"]["laser_scans_used"] == 25  # 2.5 s at the default 10 Hz of the 40 Hz laser
    assert m["maps"]["laser"]["scans"] == 13  # of which the map integrates 5 a second ([build] laser_map_rate)
    assert m["slam"]["laser"]["ate"]["rmse"] < 0.05
    assert not (tmp_path / "stats.csv").read_text().splitlines()[1:]  # the header only
    html = (tmp_path / "report.html").read_text()
    assert "Plane filtering per frame" not in html and "laser SLAM" in html


def test_a_log_with_neither_fails_with_one_line(logs, tmp_path):
    with pytest.raises(TopicError, match="neither a depth image topic nor a laser scan topic") as e:
        build(logs["neither"], tmp_path / "o", workers=0)
    assert "\n" not in str(e.value)
    assert not (tmp_path / "o").exists()  # refused before writing anything


def test_an_unknown_slam_scan_is_refused(logs, tmp_path):
    with pytest.raises(ConfigError, match="slam_scan"):
        build(logs["full"], tmp_path / "o", load_config(None, ["build.slam_scan=\"h9_99\""]), workers=0)
    with pytest.raises(ConfigError, match="kos_odometry has unknown key"):
        build(logs["full"], tmp_path / "o", load_config(None, ["build.kos_odometry={nonsense=1}"]), workers=0)
    with pytest.raises(ConfigError, match="kos_graph has unknown key"):
        build(logs["full"], tmp_path / "o", load_config(None, ["build.kos_graph={nonsense=1}"]), workers=0)


@pytest.mark.slow
@pytest.mark.parametrize("workers", [0, 2])
def test_an_interrupted_run_writes_what_is_done_marked_partial(logs, tmp_path, workers):
    seen = []

    def stop_after_30(p: Progress) -> None:
        seen.append(p.frames)
        if p.frames == 30:
            raise KeyboardInterrupt

    res = build(logs["full"], tmp_path, load_config(None, SETS), blueprint=logs["blueprint"], workers=workers,
                on_progress=stop_after_30)
    m = res.metrics
    assert res.partial and m["partial"] is True
    assert m["frames"]["processed"] == 30 and 25 <= m["frames"]["steps"] <= 30
    assert 0.8 < m["interrupted_at_s"] < 2.0
    t, _ = read_tum(tmp_path / "trajectory_kos.tum")
    assert len(t) == m["frames"]["steps"]
    assert read_map_server(tmp_path / "map_kos_obstacle.yaml").data.size > 0
    assert "PARTIAL RESULT" in (tmp_path / "report.html").read_text()
    assert "PARTIAL RESULT" in (tmp_path / "report.md").read_text()
    assert json.loads((tmp_path / "metrics.json").read_text())["partial"] is True
    assert not list(tmp_path.glob("*.partial")) and not list(tmp_path.glob(".kosmap-spill-*"))


@pytest.mark.slow
def test_the_builds_kos_slam_is_kosmap_slam_source_kos(logs, serial_run, tmp_path):
    """One KOS SLAM: the same KOS stream, SLAM feed and KOS profile (backend/kosprofile.py) under `kosmap build` and
    `kosmap slam --source kos`, so the build's KOS trajectory is, to the byte, the one the slam command gives on the
    same log and config; and both score the same against the log's ground truth (about 6 mm ATE here)."""
    from kosmap.backend.trajio import write_tum
    from kosmap.mapping.slam import evaluate, run_slam

    r = run_slam(logs["full"], load_config(None, SETS), source="kos")
    mine = write_tum(tmp_path / "slam_kos.tum", r.stamps, r.poses)
    assert mine.read_bytes() == (serial_run.out / "trajectory_kos.tum").read_bytes()
    ate = evaluate(r)["ate"]["rmse"]
    assert ate == pytest.approx(serial_run.metrics["slam"]["kos"]["ate"]["rmse"], abs=1e-12)
    assert 0 < ate < 0.02  # 2.5 s of the room: centimetre-level, not a degenerate run


@pytest.mark.slow
def test_two_cameras_give_identical_steps_serial_and_parallel(tmp_path):
    """The KOS stream of `kosmap scan` and `kosmap build`: front and rear camera merged per step, fused with the
    nearest laser scan, the same whether the frames run here or in a pool (whose results arrive late)."""
    from kosmap.mapping.config import Config
    from kosmap.mapping.kosstream import ScanRun, kos_steps
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "two.mcap"
    simulate(load_world("room"), SimConfig(seed=6, duration=1.0, rear_camera=True), log)
    serial = list(kos_steps(log, Config(), ScanRun(), workers=0))
    pooled = list(kos_steps(log, Config(), ScanRun(), workers=2))
    assert len(serial) == len(pooled) == 30 and all(len(s.frames) == 2 for s in serial)
    for a, b in zip(serial, pooled):
        assert a.stamp_ns == b.stamp_ns and set(a.scans) == set(b.scans)
        for k in a.scans:
            assert np.array_equal(a.scans[k].ranges, b.scans[k].ranges, equal_nan=True), k
        assert (a.laser is None) == (b.laser is None) and (a.laser is None or a.laser.stamp_ns == b.laser.stamp_ns)


def test_each_comparison_starts_when_its_two_maps_exist(tmp_path):
    """The comparisons are submitted as their maps arrive (so the workers compare while the MCAP is written), once
    each, and come back in the fixed order of the pairs whatever the order the maps finished in. The maps made on
    the laser SLAM's poses (fused, KOS at the laser's poses) go with the laser map's job: its alignment is theirs."""
    from kosmap.mapping.grid import OccupancyGrid
    from kosmap.mapping.build.compares import Compares
    from kosmap.mapping.build.jobs import Done

    submitted = []

    class Jobs:
        def submit(self, fn, a, b, ccfg, more=()):
            submitted.append((a.frame_id, b.frame_id, *(m.frame_id for m in more)))
            return Done([({"a": g.frame_id, "alignment": {}}, np.zeros((2, 2, 3), np.uint8), None) for g in (a, *more)])

    def grid(name):
        return OccupancyGrid(np.zeros((2, 2), np.int8), 0.05, frame_id=name)

    c = Compares(grid("blueprint"), load_config(None, []), Jobs())
    c.expect(["kos_h0_30", "kos_obstacle", "laser", "fused"])
    assert c.pairs == [("kos_obstacle", "blueprint"), ("laser", "blueprint"), ("fused", "blueprint"),
                       ("kos_obstacle", "laser")]
    c.grid_ready("laser", grid("laser"))
    assert submitted == []  # laser vs blueprint waits for the fused map, KOS vs laser for the KOS map
    c.grid_ready("kos_obstacle", grid("kos_obstacle"))
    assert submitted == [("kos_obstacle", "blueprint"), ("kos_obstacle", "laser")]
    c.grid_ready("kos_obstacle", grid("kos_obstacle"))  # polled again: not submitted twice
    c.grid_ready("fused", grid("fused"))
    assert submitted[2:] == [("laser", "blueprint", "fused")]
    files, warnings = {}, []
    comparisons, overlays = c.finish(tmp_path, files, warnings)
    assert list(comparisons) == ["kos_obstacle_vs_blueprint", "laser_vs_blueprint", "fused_vs_blueprint",
                                 "kos_obstacle_vs_laser"]
    assert comparisons["fused_vs_blueprint"]["alignment"] == {"from": "laser"}
    assert "from" not in comparisons["laser_vs_blueprint"]["alignment"]
    assert all(p.exists() for p in overlays.values()) and not warnings

    # the laser map does not align: the map on its poses says so, not "map A"
    class Failing(Jobs):
        def submit(self, fn, a, b, ccfg, more=()):
            return Done([(None, None, "map A has fewer than 3 wall cells: nothing to align")] * (1 + len(more)))

    c = Compares(grid("blueprint"), load_config(None, []), Failing())
    c.expect(["laser", "fused"])
    for name in ("laser", "fused"):
        c.grid_ready(name, grid(name))
    failed: list[str] = []
    assert c.finish(tmp_path, {}, failed) == ({}, {})
    assert failed == ["laser_vs_blueprint: map A has fewer than 3 wall cells: nothing to align",
                      "fused_vs_blueprint: the laser map, whose alignment it shares, did not align: map A has fewer "
                      "than 3 wall cells: nothing to align"]


@pytest.mark.slow
def test_chunks_longer_than_the_odometry_wait_give_reads_inputs(logs, tmp_path, monkeypatch):
    """The build reads the gyro and odometry a chunk at a time (read_batched). With chunks longer than ODOM_WAIT_S
    (1.25 s here; a 5 Hz Kinect log's 4 MB chunks hold ~1.8 s) the log's "now" must still stand where `read` has it,
    or scans near a chunk's end time out before their odometry (in the next chunk) is read: the same trajectories as
    a build reading record by record, serial and parallel."""
    from kosmap.frontend.logs.mcap import McapLog

    size = sum(c.uncompressed_size for c in McapLog(logs["full"])._summary.chunk_indexes)
    long = tmp_path / "long.mcap"
    with open_log(logs["full"]) as log, McapWriter(long, chunk_size=size // 2) as w:
        for rec in log.read(log.info().types()):
            w.write(rec, rec.topic)
    spans = [(c.message_end_time - c.message_start_time) * 1e-9 for c in McapLog(long)._summary.chunk_indexes]
    assert len(spans) == 2 and min(spans) > 1.0

    def trajectories(out):
        return {n: (out / f"trajectory_{n}.tum").read_bytes() for n in ("kos", "laser")}

    batched = trajectories(build(long, tmp_path / "b0", load_config(None, SETS), workers=0).out)
    parallel = trajectories(build(long, tmp_path / "b2", load_config(None, SETS), workers=2).out)
    monkeypatch.setattr(McapLog, "read_batched", McapLog.read)
    by_record = trajectories(build(long, tmp_path / "r0", load_config(None, SETS), workers=0).out)
    assert batched == by_record == parallel
