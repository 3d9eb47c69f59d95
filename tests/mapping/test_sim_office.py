"""The map metric on the simulator's office (tools/simulate, 48 × 24 m, 15 cm walls): a laser grid built
from the log's ground-truth poses scores F1 ≥ 0.95 at 0.10 m against the office blueprint (which validates the
metric), and the same scans with one corridor sheared sideways by 0.5 m score clearly lower.

The log is simulated here (a few seconds): the laser at 2 Hz, a token depth camera, and a path that enters
every room, so that every wall of the blueprint was in view (the bundled path skips the 16 side rooms).
"""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.records import Odometry, Scan, Transforms
from kosmap.mapping.compare import CompareConfig, compare
from kosmap.mapping.grid import GridConfig, build_grid

EVERY_ROOM = [  # south rooms from the south corridor, east rooms, north rooms, west rooms, open office, both labs
    (6, 6), (6.5, 6), (6.5, 2.5), (6.5, 6), (12, 6), (12, 4), (12, 6), (20, 6), (20, 2.5), (20, 6), (28, 6), (28, 2.5),
    (28, 6), (36, 6), (36, 2.5), (36, 6), (41.5, 6), (41.5, 2.5), (41.5, 6), (42, 6),
    (42, 8.5), (45.5, 8.5), (42, 8.5), (42, 15.5), (45.5, 15.5), (42, 15.5), (42, 18),
    (41.5, 18), (41.5, 21.5), (41.5, 18), (36, 18), (36, 21.5), (36, 18), (28, 18), (28, 21.5), (28, 18), (20, 18),
    (20, 21.5), (20, 18), (12, 18), (12, 21.5), (12, 18), (6.5, 18), (6.5, 21.5), (6.5, 18), (6, 18),
    (6, 15.5), (2.5, 15.5), (6, 15.5), (6, 12), (20, 12), (6, 12), (6, 8.5), (2.5, 8.5), (6, 8.5), (6, 6),
    (24, 6), (24, 9.5), (38, 9.5), (33, 9.5), (33, 15.5), (37, 15.5), (33, 15.5), (33, 14.5), (24, 14.5), (24, 18)]


def read_laser_and_truth(path, scan_topic="/scan", gt_topic="/ground_truth/odom"):
    """Scans, the true base_link pose at each scan's stamp (interpolated), and the laser's mount (x, y, yaw)."""
    scans, gt, mount = [], [], (0.0, 0.0, 0.0)
    with open_log(path) as log:
        for rec in log.read([scan_topic, gt_topic, "/tf_static"]):
            if isinstance(rec, Scan):
                scans.append(rec)
            elif isinstance(rec, Odometry):
                gt.append((rec.stamp, rec.x, rec.y, rec.yaw))
            elif isinstance(rec, Transforms):
                mount = next(((t.translation[0], t.translation[1], t.rpy()[2]) for t in rec.transforms
                              if t.child == "laser"), mount)
    g = np.array(gt)
    t = np.array([s.stamp for s in scans])
    yaw = np.unwrap(g[:, 3])
    poses = np.column_stack([np.interp(t, g[:, 0], v) for v in (g[:, 1], g[:, 2], yaw)])
    return scans, poses, mount


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    sim = pytest.importorskip("kosmap.tools.simulate")
    from kosmap.tools.simulate.world import PathSpec

    world = sim.World.load("office")
    cfg = sim.SimConfig(seed=1, laser_rate=2.0, laser_beams=541, depth_rate=0.01, depth_width=16, depth_height=12,
                        speed_min=0.8, speed_max=1.0, accel=1.0, turn_rate_deg=90.0, turn_accel_deg=180.0)
    log = tmp_path_factory.mktemp("sim") / "office.mcap"
    sim.simulate(world, cfg, log, path=PathSpec(np.array(EVERY_ROOM, float)))
    scans, poses, mount = read_laser_and_truth(log)
    return world.blueprint(0.05), scans, poses, mount


@pytest.mark.slow
def test_laser_grid_with_true_poses_scores_f1_095_against_blueprint(office):
    blueprint, scans, poses, mount = office
    assert len(scans) > 900 and mount[0] == pytest.approx(0.15)
    grid = build_grid(poses, scans, mount, GridConfig(resolution=0.05))
    m = compare(grid, blueprint).metrics
    t = m["tolerances"]["0.10"]
    assert t["f1"] >= 0.95, t
    assert t["recall"] >= 0.95 and t["coverage"] >= 0.98
    assert t["precision"] >= 0.93  # furniture the laser sees (desk legs, bins, people) is not in the plan
    al = m["alignment"]
    assert abs(al["yaw_deg"]) < 0.1 and np.hypot(al["x"], al["y"]) < 0.05  # the frames already agree
    same = compare(grid, blueprint, CompareConfig(align=False)).metrics["tolerances"]["0.10"]
    assert same["f1"] >= 0.95


@pytest.mark.slow
def test_map_with_a_sheared_corridor_scores_clearly_lower(office):
    blueprint, scans, poses, mount = office
    good = compare(build_grid(poses, scans, mount), blueprint).metrics["tolerances"]
    sheared = poses.copy()
    north = (sheared[:, 1] > 17.0) & (sheared[:, 1] < 19.0)  # the scans taken in the north corridor
    sheared[north, 1] += 0.5
    bad = compare(build_grid(sheared, scans, mount), blueprint).metrics["tolerances"]
    assert bad["0.10"]["f1"] < good["0.10"]["f1"] - 0.07, (good["0.10"], bad["0.10"])  # measured 0.972 → 0.879
    assert bad["0.10"]["f1"] < 0.9
    assert bad["0.20"]["f1"] < good["0.20"]["f1"] - 0.05  # 0.5 m is beyond every tolerance (0.977 → 0.897)
