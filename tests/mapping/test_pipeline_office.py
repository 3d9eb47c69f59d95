"""`kosmap demo`'s run of the simulated office (the bundled 140 m path, Kinect at 5 Hz, laser at 10 Hz, IMU at 200 Hz):
both SLAMs, both maps and the report, with the numbers this path allows.

This path never enters the 16 side rooms: the laser sees 85 % of the blueprint's wall faces, the 4.5 m Kinect 58 % (a
face counts as seen when the map holds free space in front of it), so a whole-blueprint F1 of 0.90 / 0.95
is out of reach by construction (KOS about 0.55, laser about 0.89). Those figures are checked where they
can be met, on the office surveyed room by room: tests/mapping/test_office_survey.py. Here: precision, the share of
walls seen, and the F1 over the walls seen. Furniture (desks, benches, a box) is in every range-sensor map and not in
the plan: precision 0.95 (laser), 0.84 (KOS obstacle scan, which sees table tops and legs by design).
"""

from __future__ import annotations

import pytest

from kosmap.mapping.config import Config
from kosmap.mapping.build import build


@pytest.fixture(scope="module")
def office_run(tmp_path_factory):
    from kosmap.tools.commands.demo import demo_log

    cache = tmp_path_factory.mktemp("office")
    log, bp, _ = demo_log(cache=cache, quiet=True)
    res = build(log, cache / "out", Config(), blueprint=bp, workers=2)
    return res


def _t(res, key: str) -> dict:
    return res.metrics["comparisons"][key]["tolerances"]["0.10"]


@pytest.mark.slow
def test_office_builds_and_reports_both_maps_against_the_blueprint(office_run):
    m = office_run.metrics
    assert not office_run.partial and m["frames"]["processed"] == 1764 and m["frames"]["laser_scans_used"] == 3527
    assert m["slam"]["laser"]["ate"]["rmse"] < 0.05  # laser SLAM: centimetres over 140 m with loop closures
    assert m["slam"]["laser"]["loops"] > 10
    laser = _t(office_run, "laser_vs_blueprint")
    assert m["slam"]["kos"]["ate"]["rmse"] < 0.10  # KOS SLAM with the gyro: measured 0.043 m
    assert laser["precision"] > 0.9 and laser["coverage"] > 0.8 and laser["recall_observed"] > 0.85  # 0.95, 0.85, 0.91
    assert laser["f1_observed"] > 0.9  # 0.927 over the wall faces it saw
    kos = _t(office_run, "kos_obstacle_vs_blueprint")
    kos_lp = _t(office_run, "kos_obstacle_at_laser_poses_vs_blueprint")  # KOS without KOS SLAM's error
    assert kos["precision"] > 0.8 and kos["coverage"] > 0.5  # 0.84, 0.57
    assert kos["f1"] > kos_lp["f1"] - 0.03  # KOS SLAM's poses map as well as the laser's (0.535 vs 0.544)
    html = (office_run.out / "report.html").read_text()
    for key in ("kos_obstacle_vs_blueprint", "laser_vs_blueprint"):
        assert f"{_t(office_run, key)['f1']:.3f}" in html  # the report shows both F1s

