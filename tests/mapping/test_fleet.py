"""The parts of `kosmap batch` that need no cluster: merging runs' evidence, finding what changed between runs
of a synthetic room mapped in different frames, naming and finding logs, sizing a local cluster, and the
content-hash check that lets a re-run skip a log."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kosmap.mapping.batch import (BatchError, BuildState, find_logs, output_hashes, task_names, up_to_date)
from kosmap.mapping.cluster import machine_sizing
from kosmap.mapping.compare import CompareConfig, apply, se2
from kosmap.mapping.fleet import fleet, merge_logodds
from kosmap.mapping.grid import GridBuilder, GridConfig
from kosmap.mapping.runtime.outdir import MANIFEST
from tests.mapping.worlds import path_poses, room, scan_at

BOX = np.array([[6.0, 5.0, 6.6, 5.0], [6.6, 5.0, 6.6, 5.6], [6.6, 5.6, 6.0, 5.6], [6.0, 5.6, 6.0, 5.0]])  # 0.6 m


def _logit(p):
    return np.log(p / (1 - p))


def test_merge_sums_the_runs_log_odds_and_keeps_unseen_cells_unknown():
    stack = np.array([[[97, 97, -1, 70]], [[12, -1, -1, 12]], [[12, -1, -1, -1]]], np.int8)  # 3 runs × 1 × 4 cells
    m = merge_logodds(stack, 0.12, 0.97)
    want = 100 / (1 + np.exp(-(_logit(0.97) + 2 * _logit(0.12))))
    assert m[0, 0] == round(want) and m[0, 0] < 50  # one run's wall against two runs' free space: free
    assert m[0, 1] == 97 and m[0, 2] == -1  # one run's evidence alone is kept; a cell no run saw stays unknown
    assert m[0, 3] == round(100 / (1 + np.exp(-(_logit(0.70) + _logit(0.12)))))


def _run(segs, waypoints, frame=(0.0, 0.0, 0.0), seed=0):
    """A log-odds map of `segs` from a laser driven along `waypoints`, kept in a map frame moved by `frame`."""
    rng = np.random.default_rng(seed)
    T = np.linalg.inv(se2(*frame))  # world → this run's map frame
    b = GridBuilder()
    for x, y, th in path_poses(waypoints, 0.25):
        p = apply(T, np.array([[x, y]]))[0]
        b.add((p[0], p[1], th - frame[2]), scan_at((x, y, th), segs, noise=0.01, rng=rng))
    return b.to_occupancy()


def test_runs_in_other_frames_are_aligned_merged_and_their_change_found():
    """Run 1 of the room; run 2 along another path with a box added, its map in a frame turned 30° and moved."""
    walls = room()
    path1 = [(1.0, 1.0), (2.0, 6.0), (6.5, 6.3), (8.0, 2.0)]
    path2 = [(8.0, 2.0), (6.0, 6.4), (1.5, 6.0), (1.2, 1.0)]
    frame = (1.5, -0.7, np.radians(30))
    a = _run(walls, path1)
    b = _run(np.vstack((walls, BOX)), path2, frame, seed=1)
    f = fleet(["one", "two"], [a, b], None, CompareConfig(), GridConfig())
    al = f.frames[1].alignment
    assert np.degrees(al.yaw) == pytest.approx(30, abs=0.5) and np.hypot(al.x - 1.5, al.y + 0.7) < 0.05
    assert f.tolerance_m == pytest.approx(0.10)  # two cells: the alignment is within a cell here
    assert len(f.regions) == 1, f.regions
    g = f.regions[0]
    assert np.hypot(g.x - 6.3, g.y - 5.3) < 0.2  # the box's faces seen from the path, around its centre
    assert g.occupied_in == ["two"] and g.free_in == ["one"]
    assert 0.05 < g.area_m2 < 0.6 ** 2 + 0.1
    # the merged map holds both runs' walls, in run one's frame
    cells = f.merged.center_of(*np.nonzero(f.merged.data.T >= 65))
    for corner in ((0.0, 0.0), (10.0, 0.0), (7.0, 7.0)):
        assert np.hypot(*(cells - corner).T).min() < 0.15


def test_log_names_come_from_the_files_and_collisions_are_told_apart(tmp_path):
    for sub in ("robot1", "robot2"):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "run.mcap").write_bytes(b"x")
    (tmp_path / "robot1" / "other.bag").write_bytes(b"x")
    (tmp_path / "robot1" / "notes.txt").write_text("not a log")
    (tmp_path / "robot1" / "built").mkdir()  # a build's folder: its kosmap.mcap is an output, not a log
    (tmp_path / "robot1" / "built" / "kosmap.mcap").write_bytes(b"x")
    (tmp_path / "robot1" / "built" / MANIFEST).write_text("{}")
    logs = find_logs([tmp_path])
    assert [p.relative_to(tmp_path).as_posix() for p in logs] == ["robot1/other.bag", "robot1/run.mcap",
                                                                  "robot2/run.mcap"]
    assert task_names(logs) == ["other", "robot1-run", "robot2-run"]
    lst = tmp_path / "logs.txt"
    lst.write_text("# the week's runs\nrobot2/run.mcap\n\nrobot1/other.bag  # late\n")
    assert find_logs([], lst) == [tmp_path / "robot2/run.mcap", tmp_path / "robot1/other.bag"]
    assert find_logs([tmp_path], exclude=tmp_path / "robot1") == [tmp_path / "robot2/run.mcap"]
    lst.write_text("robot3/run.mcap\n")
    with pytest.raises(BatchError, match="line 1: robot3/run.mcap is not a file"):
        find_logs([], lst)
    (tmp_path / "a" / "robot1").mkdir(parents=True)
    (tmp_path / "a" / "robot1" / "run.mcap").write_bytes(b"x")
    with pytest.raises(BatchError, match="would share the output folder 'robot1-run'"):
        task_names(find_logs([tmp_path]))


@pytest.mark.parametrize("cores, mem_gb, asked, want", [
    (2, 8.0, None, (1, 2)),  # a build keeps about two cores busy
    (16, 64.0, None, (8, 2)),
    (16, 6.0, None, (4, 4)),  # memory for 4 builds only: the cores shared among them
    (2, 8.0, 2, (2, 1)),
    (3, None, None, (1, 3)),
])
def test_a_local_cluster_is_sized_to_the_machine(cores, mem_gb, asked, want):
    s = machine_sizing(cores, mem_gb, asked)
    assert (s.workers, s.build_workers) == want


def test_a_build_is_up_to_date_only_with_the_same_inputs_and_untouched_outputs(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "map_laser.pgm").write_bytes(b"P5 map")
    (out / MANIFEST).write_text(json.dumps({"kosmap": "build", "files": ["map_laser.pgm"]}))
    inputs = {"log": "1" * 64, "config": "2" * 64}
    state = BuildState(inputs, output_hashes(out))
    assert up_to_date(state, inputs, out)
    assert not up_to_date(state, {**inputs, "config": "3" * 64}, out)  # another config
    assert not up_to_date(None, inputs, out)  # never built by a batch
    (out / "map_laser.pgm").write_bytes(b"P5 mop")  # same size, another content
    assert not up_to_date(state, inputs, out)
    (out / MANIFEST).write_text(json.dumps({"kosmap": "build", "in_progress": True}))
    assert output_hashes(out) is None  # a build that never finished is no build


def test_a_build_in_a_daemonic_worker_runs_serially_and_says_why(monkeypatch, tmp_path):
    """A daemonic process may not start children: the build runs in it alone (same maps), with a note."""
    from types import SimpleNamespace

    from kosmap.mapping import batch
    from kosmap.mapping.config import Config

    task = batch.BatchTask("x", tmp_path / "x.mcap", tmp_path / "x", tmp_path / "x.json", Config(), workers=None)
    assert batch._frame_workers(task) == (None, None)
    monkeypatch.setattr(batch.mp, "current_process", lambda: SimpleNamespace(daemon=True))
    workers, note = batch._frame_workers(task)
    assert workers == 0 and "DASK_DISTRIBUTED__WORKER__DAEMON=False" in note
