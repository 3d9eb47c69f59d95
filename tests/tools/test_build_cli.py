"""`kosmap build` and `kosmap demo` from the command line: what they print and write, and one-line errors."""

from __future__ import annotations

import json

import pytest

from kosmap.tools.cli import main


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    d = tmp_path_factory.mktemp("buildcli")
    w = load_world("room")
    simulate(w, SimConfig(seed=2, duration=1.5), d / "room.mcap")
    return d / "room.mcap", write_map_server(w.blueprint(0.05), d / "bp.yaml", ".png")


@pytest.mark.slow
def test_build_prints_the_headline_and_writes_the_report(room, tmp_path, capsys):
    log, bp = room
    out = tmp_path / "out"
    code = main(["build", str(log), "--out", str(out), "--blueprint", str(bp), "--workers", "2",
                 "--set", "build.mcap_planes_period=0", "--set", "grid.resolution=0.1"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "F1 at 0.10 m  KOS obstacle (SLAM scan) vs blueprint " in cap.out
    assert "F1 at 0.10 m  laser vs blueprint " in cap.out and "ATE RMSE      laser SLAM " in cap.out
    assert "× real time" in cap.out and f"report: {out / 'report.html'}" in cap.out
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"]["processed"] == 15 and m["maps"]["laser"]["resolution"] == pytest.approx(0.1)
    assert "resolution = 0.1" in (out / "config.toml").read_text()
    assert (out / "report.html").is_file() and (out / "map_kos_obstacle.pgm").is_file()
    # beside each F1 against the blueprint, the F1 of the walls the robot saw (never below the plain F1)
    laser_bp = next(c for c in m["comparisons"].values() if c["a"] == "laser" and c["b"] == "blueprint")["tolerances"]["0.10"]
    assert laser_bp["f1_observed"] >= laser_bp["f1"] - 1e-9
    line = next(ln for ln in cap.out.splitlines() if "laser vs blueprint" in ln)
    assert line.endswith(f"{laser_bp['f1']:.3f}   (walls seen: {laser_bp['f1_observed']:.3f})")


def test_build_refuses_a_log_with_neither_depth_nor_laser(tmp_path, capsys):
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import Odometry

    p = tmp_path / "odom_only.mcap"
    with McapWriter(p) as w:
        for i in range(3):
            w.write(Odometry(i * 10_000_000, 0.01 * i, 0.0, 0.0), "/odom")
    code = main(["build", str(p), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("kosmap: error: ") and err.count("\n") == 1
    assert "neither a depth image topic nor a laser scan topic" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, words", [
    (["missing.mcap"], "does not exist"),
    (["LOG", "--set", "build.slam_scan=\"h9_99\""], "slam_scan"),
    (["LOG", "--set", "build.depth_rate=-1"], "depth_rate"),
    (["LOG", "--workers", "-1"], "--workers"),
    (["LOG", "--blueprint", "nowhere.yaml"], "nowhere.yaml"),
])
def test_build_bad_input_is_one_line(room, tmp_path, capsys, args, words):
    log, _ = room
    argv = ["build"] + [str(log) if a == "LOG" else (str(tmp_path / a) if a.endswith((".mcap", ".yaml")) else a)
                        for a in args] + ["--out", str(tmp_path / "o")]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("kosmap: error: ") and err.count("\n") == 1, err
    assert words in err


def test_build_refuses_an_out_that_is_a_file(room, tmp_path, capsys):
    log, _ = room
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["build", str(log), "--out", str(f)]) == 2
    assert "is a file" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_simulates_once_then_reuses_the_log(tmp_path, capsys, monkeypatch):
    from kosmap.tools.commands import demo

    monkeypatch.setattr(demo, "DEMO_WORLD", "room")
    monkeypatch.setattr(demo, "DEMO_SIM", {**demo.DEMO_SIM, "duration": 1.5})
    monkeypatch.setattr(demo, "CACHE", tmp_path / "cache")
    monkeypatch.setattr(demo, "warm_up", lambda: type("P", (), {"wait": lambda self: 0})())
    out = tmp_path / "demo_out"
    assert main(["demo", "--out", str(out), "--workers", "0"]) == 0
    cap = capsys.readouterr()
    assert "simulated in" in cap.err and "kosmap demo: the room" in cap.out
    assert "F1 at 0.10 m  laser vs blueprint" in cap.out and "report:" in cap.out
    assert len(list((tmp_path / "cache").glob("room-*.mcap"))) == 1
    assert main(["demo", "--out", str(out), "--workers", "0"]) == 0
    assert "(cached)" in capsys.readouterr().err
