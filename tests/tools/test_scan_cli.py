"""`kosmap scan` end to end on a short simulated log: the MCAP, CSV, figures, config and the one-line errors."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.records import Scan
from kosmap.tools.cli import main
from kosmap.tools.simulate import SimConfig, load_world, simulate


@pytest.fixture(scope="module")
def room_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("scan") / "room.mcap"
    simulate(load_world("room"), SimConfig(seed=3, duration=0.7, rear_camera=True), out)
    return out


@pytest.mark.slow
def test_scan_writes_levels_fused_csv_and_figures(room_log, tmp_path, capsys):
    out = tmp_path / "kos"
    code = main(["scan", str(room_log), "--out", str(out), "--levels", "0.3,0.75,1.5", "--figures", "1",
                 "--set", "fspf.analysed_fraction=0.99"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "fused with the laser" in printed
    for name in ("kos.mcap", "scan_points.csv", "kos_top_0.png", "config.toml", "summary.json"):
        assert (out / name).is_file(), name
    assert not list(out.glob("*.partial"))
    with open_log(out / "kos.mcap") as log:
        counts = {t.name: t.count for t in log.info().topics}
        scans = [r for r in log.read(["/kinect_scan/h0_75", "/kinect_scan/fused", "/scan"]) if isinstance(r, Scan)]
    steps = counts["/kinect_scan/obstacle"]
    assert steps == 21  # 0.7 s of 30 Hz frames, front and rear merged per step
    for level in ("h0_30", "h0_75", "h1_50", "obstacle", "fused"):
        assert counts[f"/kinect_scan/{level}"] == steps
    level = next(s for s in scans if s.topic == "/kinect_scan/h0_75")
    assert level.frame_id == "base_link"
    assert level.angle_min == pytest.approx(-np.pi, abs=1e-6)  # two cameras: a full circle
    fused = next(s for s in scans if s.topic == "/kinect_scan/fused")
    assert len(fused.ranges) == 1081 and fused.frame_id == "laser"
    with open(out / "scan_points.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["scan"] for r in rows} >= {"h0_30", "h0_75", "h1_50", "obstacle", "fused"}
    r = rows[0]
    assert float(r["x_m"]) == pytest.approx(float(r["range_m"]) * np.cos(float(r["bearing_rad"])), abs=2e-3)
    s = json.loads((out / "summary.json").read_text())
    assert s["filled_fraction"]["obstacle"] > 0.25  # two 70° cameras see ~39 % of the circle


def test_scan_refuses_a_log_without_depth(tmp_path, capsys):
    from kosmap.frontend.logs.writer import McapWriter
    from tests.frontend.synthetic_log import records

    p = tmp_path / "laser_only.mcap"
    with McapWriter(p) as w:
        for r in records(n=2):
            if r.topic == "/scan":
                w.write(r)
    code = main(["scan", str(p), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("kosmap: error: ") and "no depth image topic" in err
    assert not (tmp_path / "o" / "kos.mcap").exists()


def test_scan_refuses_bad_levels(tmp_path, capsys):
    code = main(["scan", str(tmp_path / "x.mcap"), "--levels", "low,high"])
    assert code == 2 and "--levels" in capsys.readouterr().err


@pytest.mark.slow
def test_a_rerun_replaces_the_last_scans_files_and_a_stop_leaves_them_as_they_were(room_log, tmp_path, capsys, monkeypatch):
    out = tmp_path / "kos"
    assert main(["scan", str(room_log), "--out", str(out), "--figures", "3", "--limit", "9"]) == 0
    assert len(list(out.glob("kos_top_*.png"))) == 3
    assert main(["scan", str(room_log), "--out", str(out), "--figures", "1", "--limit", "9"]) == 0
    assert [p.name for p in out.glob("kos_top_*.png")] == ["kos_top_0.png"]  # not the first run's three
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    import kosmap.mapping.kosscan as kosscan

    def stop(*a, **k):  # Ctrl-C while the frames are read
        raise KeyboardInterrupt
        yield

    monkeypatch.setattr(kosscan, "kos_steps", stop)
    assert main(["scan", str(room_log), "--out", str(out), "--limit", "9"]) == 130
    assert "kosmap: interrupted" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the earlier scan's, byte for byte
