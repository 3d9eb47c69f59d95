"""`kosmap batch` on a local Dask cluster of 2 workers, on short simulated logs of the room world: per-log folders
identical to `kosmap build`'s, a corrupt log reported without stopping the others, re-runs that skip what is
unchanged, a change map that finds an added obstacle and a closed door where they are, and a merged map at least
as good as the better of its runs."""

from __future__ import annotations

import csv
import io
import json
import os

import numpy as np
import pytest
import yaml

from kosmap.tools.cli import main

pytest.importorskip("distributed", reason="kosmap batch needs Dask: pip install 'kosmap[cluster]'")

OBSTACLE = (3.0, 4.6)  # an added 0.5 × 0.3 m box, 1 m tall, against the north wall of the room's main part
DOOR = (5.0, 1.0)  # the room's door, closed in the variant
TIMED = {"metrics.json", "report.html", "report.md", "stats.csv", "frames.png"}  # files holding measured times


def _world(tmp, name: str, **changes) -> object:
    from kosmap.tools.simulate import load_world
    from kosmap.tools.simulate.world import world_file

    doc = yaml.safe_load(world_file("room").read_text())
    doc.update(name=name, **changes)
    p = tmp / f"{name}.yaml"
    p.write_text(yaml.safe_dump(doc))
    return load_world(p)


@pytest.fixture(scope="module")
def fleet_logs(tmp_path_factory):
    """a: the room's own path; a2: another path, through the door into the side room; b: the room with the door
    closed and a box added, on a's path; bad: not a log. Depth at 5 Hz, the laser at 10 Hz."""
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, simulate
    from kosmap.tools.simulate.world import world_file

    d = tmp_path_factory.mktemp("batch")
    base = yaml.safe_load(world_file("room").read_text())
    worlds = {"a": _world(d, "room_a"),
              "a2": _world(d, "room_a2", path={"waypoints": [[1.2, 1.4], [4.0, 1.1], [6.2, 1.1], [6.2, 2.3]]}),
              "b": _world(d, "room_b", doors=[], obstacles=base["obstacles"] + [
                  {"center": list(OBSTACLE), "size": [0.5, 0.3], "height": 1.0}])}
    logs = d / "logs"
    logs.mkdir()
    for k, (name, w) in enumerate(worlds.items()):
        simulate(w, SimConfig(seed=11 + k, duration={"a": 10.0, "a2": 12.0, "b": 8.0}[name], depth_rate=5,
                              laser_rate=10), logs / f"{name}.mcap")
    (logs / "bad.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 40)  # the magic, then no valid record
    bp = write_map_server(worlds["a"].blueprint(0.05), d / "bp.yaml", ".png")
    return {"dir": d, "logs": logs, "bp": bp}


def _batch(fleet_logs, out, *extra) -> tuple[int, str]:
    import contextlib

    args = ["batch", str(fleet_logs["logs"]), "--out", str(out), "--blueprint", str(fleet_logs["bp"]),
            "--workers", "2", *extra]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(args)
    return code, err.getvalue()


@pytest.fixture(scope="module")
def first(fleet_logs):
    out = fleet_logs["dir"] / "out"
    code, err = _batch(fleet_logs, out)
    return out, code, err, json.loads((out / "batch.json").read_text())


def _records(doc) -> dict:
    return {r["name"]: r for r in doc["logs"]}


def _untimed(p):
    """A timed file's content without its measured times (and its own folder's name, which it records)."""
    if p.name == "metrics.json":
        def strip(v):
            if isinstance(v, dict):
                return {k: strip(x) for k, x in v.items()
                        if k not in ("timing", "memory", "table_5_5", "seconds", "realtime_factor", "ms")
                        and not k.endswith("_ms")}
            return [strip(x) for x in v] if isinstance(v, list) else v
        return strip(json.loads(p.read_text().replace(str(p.parent), "OUT")))
    if p.name == "stats.csv":
        rows = list(csv.DictReader(io.StringIO(p.read_text())))
        return [{k: v for k, v in r.items() if not k.endswith("_ms")} for r in rows]
    return None  # the report and the frame-time figure: times throughout


@pytest.mark.slow
def test_batch_builds_each_log_as_build_does_and_reports_the_corrupt_one(first, fleet_logs, tmp_path):
    out, code, err, doc = first
    assert code == 1, err  # a log failed
    recs = _records(doc)
    assert {n: r["status"] for n, r in recs.items()} == {"a": "built", "a2": "built", "b": "built", "bad": "failed"}
    assert "bad.mcap" in recs["bad"]["error"] and "\n" not in recs["bad"]["error"]
    assert f"FAILED  bad: {recs['bad']['error']}" in err and "built   a " in err
    assert not (out / "bad").exists()
    for name in ("a", "b"):  # the same folder as a single `kosmap build` of the log (its default processes)
        single = tmp_path / name
        assert main(["build", str(fleet_logs["logs"] / f"{name}.mcap"), "--out", str(single), "--blueprint",
                     str(fleet_logs["bp"]), "--quiet"]) == 0
        got = sorted(p.name for p in (out / name).iterdir())
        assert got == sorted(p.name for p in single.iterdir()), name
        for fn in got:
            if fn in TIMED:
                assert _untimed(out / name / fn) == _untimed(single / fn), (name, fn)
            else:
                assert (out / name / fn).read_bytes() == (single / fn).read_bytes(), (name, fn)
        m = json.loads((out / name / "metrics.json").read_text())
        # built inside a Dask worker, the build still started its own processes: its frame worker and its SLAMs
        assert m["table_5_5"]["workers"] == 1 and recs[name]["worker_note"] is None
        assert set(m["memory"]["peak_rss_mb_slam"]) == {"kos", "laser"}
        assert recs[name]["f1"]["laser"] == m["comparisons"]["laser_vs_blueprint"]["tolerances"]["0.10"]["f1"]
        assert recs[name]["ate"]["laser"] < 0.05 and recs[name]["realtime_factor"] > 0
    table = (out / "batch.md").read_text()
    assert "| a | built |" in table and "| bad | failed |" in table and recs["bad"]["error"] in table
    assert (out / "batch.html").read_text().count("data:image/png;base64,") == 2


@pytest.mark.slow
def test_a_rerun_skips_what_is_unchanged_and_redoes_what_is_not(first, fleet_logs):
    out, _, _, _ = first
    before = {n: {p: p.stat().st_mtime_ns for p in (out / n).iterdir()} for n in ("a", "a2", "b")}
    # one output of a changed behind the batch's back (same size, same date: a content hash finds it)
    pgm = out / "a" / "map_laser.pgm"
    data = bytearray(pgm.read_bytes())
    data[-1] ^= 0xFF
    pgm.write_bytes(bytes(data))
    os.utime(pgm, ns=(before["a"][pgm], before["a"][pgm]))
    code, err = _batch(fleet_logs, out)
    recs = _records(json.loads((out / "batch.json").read_text()))
    assert code == 1 and {n: r["status"] for n, r in recs.items()} == {
        "a": "built", "a2": "skipped", "b": "skipped", "bad": "failed"}, err
    for n in ("a2", "b"):  # no work for the unchanged: not a file of theirs touched, their numbers still listed
        assert {p: p.stat().st_mtime_ns for p in (out / n).iterdir()} == before[n]
        assert recs[n]["f1"]["laser"] > 0.5 and recs[n]["ate"]["laser"] < 0.05
    assert "skipped a2 (unchanged" in err and pgm.read_bytes() != bytes(data)


@pytest.mark.slow
def test_the_change_map_finds_the_added_box_and_the_closed_door(first):
    from kosmap.mapping.mapio import read_map_server

    out, _, _, doc = first
    fl = doc["fleet"]
    assert fl["map"] == "laser" and fl["reference"] == "blueprint"
    assert all(r["aligned"] for r in fl["runs"])
    regions = fl["changes"]["regions"]
    for where in (OBSTACLE, DOOR):
        d = [np.hypot(g["x"] - where[0], g["y"] - where[1]) for g in regions]
        k = int(np.argmin(d))
        assert d[k] < 0.2, (where, regions)
        assert regions[k]["occupied_in"] == ["b"] and "a" in regions[k]["free_in"]
    # nothing else changed between the runs: no other region
    assert len(regions) == 2, regions
    ch = read_map_server(out / "changes.yaml")  # the map_server files mark the changed cells occupied
    cells = ch.center_of(*np.nonzero(ch.data.T == 100))
    for where in (OBSTACLE, DOOR):
        assert np.hypot(*(cells - where).T).min() < 0.2
    assert (out / "changes.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_the_merged_map_of_two_runs_scores_at_least_the_better_run(first, fleet_logs):
    from kosmap.mapping.compare import CompareConfig, compare
    from kosmap.mapping.fleet import fleet
    from kosmap.mapping.grid import GridConfig
    from kosmap.mapping.gridlog import read_build_grid
    from kosmap.mapping.mapio import read_blueprint

    out, _, _, doc = first
    recs = _records(doc)
    bp = read_blueprint(fleet_logs["bp"])
    grids = [read_build_grid(out / n / "kosmap.mcap", "laser") for n in ("a", "a2")]
    f = fleet(["a", "a2"], grids, bp, CompareConfig(), GridConfig())
    merged = compare(f.merged, bp).metrics["tolerances"]["0.10"]["f1"]
    singles = [recs[n]["f1"]["laser"] for n in ("a", "a2")]
    assert merged >= max(singles), (merged, singles)
    assert not f.regions  # two runs of one unchanged building: no change
    assert doc["fleet"]["merged"]["runs"] == 3 and doc["fleet"]["merged"]["f1"] > 0.7


@pytest.mark.slow
def test_an_existing_cluster_by_address_builds_the_same_maps(first, fleet_logs, tmp_path):
    """`--scheduler`: a cluster started elsewhere; its workers are daemonic (Dask's default), so the build runs
    without processes of its own, says so, and makes the same maps."""
    from distributed import LocalCluster

    out, _, _, _ = first
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        code = main(["batch", str(fleet_logs["logs"] / "b.mcap"), "--out", str(tmp_path / "o"), "--scheduler",
                     cluster.scheduler_address, "--quiet"])
    assert code == 0
    doc = json.loads((tmp_path / "o" / "batch.json").read_text())
    (r,) = doc["logs"]
    assert r["status"] == "built" and "daemonic" in r["worker_note"] and doc["cluster"]["scheduler"] != "local"
    for fn in ("map_laser.pgm", "map_kos_obstacle.pgm", "trajectory_laser.tum", "trajectory_kos.tum"):
        assert (tmp_path / "o" / "b" / fn).read_bytes() == (out / "b" / fn).read_bytes(), fn
    assert doc["fleet"]["merged"]["runs"] == 1 and doc["fleet"]["changes"]["regions"] == []  # nothing to compare


def test_without_dask_batch_says_how_to_get_it(monkeypatch, tmp_path, capsys):
    import sys

    log = tmp_path / "x.mcap"
    log.write_bytes(b"\x89MCAP0\r\n")
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed → ImportError
    code = main(["batch", str(log), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "pip install 'kosmap[cluster]'" in err
    assert not (tmp_path / "o").exists()
