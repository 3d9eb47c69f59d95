"""`kosmap slam`: outputs on a small synthetic log, and one-line errors for what it cannot do."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kosmap.backend.trajio import read_g2o, read_tum
from kosmap.mapping.report import odometry_noise_text
from tests.frontend.synthetic_log import write_mcap
from tests.mapping.synthetic_laser import make_log, records
from kosmap.tools.cli import main


@pytest.fixture(scope="module")
def ring_log(tmp_path_factory):
    log = make_log(seed=1, laps=1)
    return write_mcap(records(log), tmp_path_factory.mktemp("slam") / "ring.mcap"), log


def test_slam_writes_every_output(ring_log, tmp_path, capsys):
    path, log = ring_log
    out = tmp_path / "out"
    code = main(["slam", str(path), "--out", str(out), "--set", "graph.submap_nodes=20"])
    stdout, err = capsys.readouterr()
    assert code == 0, err
    for name in ("trajectory.tum", "keyframes.tum", "graph.g2o", "metrics.json", "map.png", "map.pgm", "map.yaml",
                 "config.toml"):
        assert (out / name).is_file(), name
    t, p = read_tum(out / "trajectory.tum")
    assert len(t) == len(log.scans) and np.all(np.diff(t) > 0)
    v, e = read_g2o(out / "graph.g2o")
    assert len(v) > 10 and len(e) >= len(v) - 1
    m = json.loads((out / "metrics.json").read_text())
    assert m["ate"]["rmse"] < 0.05  # scored against the log's /ground_truth/odom
    assert "submap_nodes = 20" in (out / "config.toml").read_text()
    assert "ATE" in stdout
    assert f"estimated: wheel odometry distance scale {m['run']['odometry_scale']:.4f}" in stdout  # the graph's own
    assert "gyro" not in stdout  # no IMU in this log
    on = m["run"]["odometry_noise"]  # measured against the scan matcher while running
    assert on["measured"] and on["samples"] > 100, on
    assert f"wheel odometry measured against the scans: {odometry_noise_text(on)}" in stdout
    assert f"distance {100 * on['scale_error']:+.2f} %" in stdout and f"({on['samples']} intervals)" in stdout


def test_slam_kos_source_without_depth_is_a_clear_error(ring_log, tmp_path, capsys):
    path, _ = ring_log
    code = main(["slam", str(path), "--source", "kos", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("kosmap: error: ") and "no depth image topic" in err
    assert len(err.strip().splitlines()) == 1


def test_slam_relations_of_another_log_is_a_clear_error(ring_log, tmp_path, capsys):
    path, _ = ring_log
    rel = tmp_path / "other.relations"
    rel.write_text("976052905.167303 976052911.885496 -0.05 -0.12 0 0 0 -1.68\n")
    code = main(["slam", str(path), "--relations", str(rel), "--no-map", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "relations" in err and "Traceback" not in err
    assert main(["slam", str(path), "--relations", str(tmp_path / "missing.relations"), "--out", str(tmp_path / "o")]) == 2
