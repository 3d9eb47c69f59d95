"""The simulated office surveyed: the office world's `survey` path (into all 16 side rooms, both
labs and round the open office, looking all round in each: 365 m, 23 min), Kinect v2 at 5 Hz, Hokuyo at 10 Hz
(18.75 ms per scan, so scans are skewed while the robot turns), wheel odometry and the IMU: `kosmap demo --survey`'s
log, built with the blueprint. Required: the KOS map vs the blueprint F1 ≥ 0.90 at 0.10 m, the laser map ≥ 0.95, both in
the report.

The KOS map on its own SLAM needs the running estimate rebased at each calibration and the Manhattan heading priors
(backend/kosprofile.py KOS_GRAPH): a one-pass survey with a 70° forward camera closes few loops, and without them the graph's
heading drifted (F1 0.717 at KOS SLAM ATE 0.218 m before either, 0.869 with the rebase alone).

The default (demo) path never enters the side rooms: the Kinect sees 58 % of the plan's wall faces from it, so no
map made on it can reach these numbers; tests/mapping/test_pipeline_office.py checks that run.
"""

from __future__ import annotations

import pytest

from kosmap.mapping.config import Config
from kosmap.mapping.build import build


@pytest.fixture(scope="module")
def survey_run(tmp_path_factory):
    from kosmap.tools.commands.demo import demo_log

    d = tmp_path_factory.mktemp("survey")
    log, bp, _ = demo_log(cache=d, quiet=True, path="survey")  # what `kosmap demo --survey` maps
    return build(log, d / "out", Config(), blueprint=bp, workers=2)


def _t(res, key: str) -> dict:
    return res.metrics["comparisons"][key]["tolerances"]["0.10"]


def _info(m: dict, laser: dict, kos: dict, kos_lp: dict) -> str:
    return (f"laser F1 {laser['f1']:.3f} (P {laser['precision']:.3f} R {laser['recall']:.3f}, laser SLAM ATE "
            f"{m['slam']['laser']['ate']['rmse']:.3f} m); KOS F1 {kos['f1']:.3f} (P {kos['precision']:.3f} R "
            f"{kos['recall']:.3f}, KOS SLAM ATE {m['slam']['kos']['ate']['rmse']:.3f} m); KOS at the laser's poses "
            f"{kos_lp['f1']:.3f}")


@pytest.mark.slow
def test_survey_maps_match_the_blueprint(survey_run):
    """Measured 2026-11-23: KOS F1 0.922 (KOS SLAM ATE 0.044 m), laser F1 0.973 (laser SLAM 0.019 m), the KOS map at
    the laser's poses 0.923."""
    m = survey_run.metrics
    assert not survey_run.partial and m["frames"]["processed"] == m["frames"]["in_log"] > 6000
    laser, kos = _t(survey_run, "laser_vs_blueprint"), _t(survey_run, "kos_obstacle_vs_blueprint")
    kos_lp = _t(survey_run, "kos_obstacle_at_laser_poses_vs_blueprint")
    info = _info(m, laser, kos, kos_lp)
    print(info)
    assert kos["f1"] >= 0.90, info  # the KOS map on its own SLAM's poses
    assert laser["f1"] >= 0.95, info
    assert kos_lp["f1"] >= 0.90, info  # the KOS map itself, on the laser's poses
    assert m["slam"]["laser"]["ate"]["rmse"] < 0.05, info
    assert m["slam"]["kos"]["ate"]["rmse"] < 0.07, info
    hd = m["slam"]["kos"]["heading"]
    assert hd["priors"] > 0.5 * m["slam"]["kos"]["keyframes"] and abs(hd["axis_deg"]) < 1.0, hd  # the office is Manhattan
    html = (survey_run.out / "report.html").read_text()
    for t in (laser, kos):
        assert f"{t['f1']:.3f}" in html  # the report shows both F1s
