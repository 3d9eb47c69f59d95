"""Issue 8 acceptance on the simulated office (`kosmap demo`'s log: the bundled 140 m path, Kinect at 5 Hz, laser
at 10 Hz): KOS map vs blueprint F1 ≥ 0.90 at 0.10 m, laser map vs blueprint F1 ≥ 0.95, both shown in the report.

The F1 thresholds are not met today; the two tests below are marked xfail with the numbers measured, and a third
asserts what holds now. Why, as measured: the bundled path never enters the 16 side rooms, so recall against the
whole blueprint is bounded by what the sensors saw (the laser sees 93 % of the blueprint's walls through the doors,
the 4.5 m Kinect 58 %: even a perfect map of what the camera saw scores F1 ≤ 2·0.58/1.58 = 0.73 here, whatever
the SLAM; grid settings moved the KOS F1 by ±0.04 at most); the laser map's precision is 0.95 (furniture the plan lacks); the KOS map's walls are
faint (a wall seen at grazing angles by a narrow scan gets about as many misses as hits) and KOS SLAM's trajectory
bends the walls by more than the 0.10 m tolerance (ATE 0.67 m with mapping.slam.kos_odometry_config's front end,
0.19-0.22 m with [odometry] + [build] kos_odometry alone; wheel odometry 0.62 m).
"""

from __future__ import annotations

import pytest

from mapping.config import Config
from mapping.pipeline import build


@pytest.fixture(scope="module")
def office_run(tmp_path_factory):
    from tools.commands.demo import demo_log

    cache = tmp_path_factory.mktemp("office")
    log, bp, _ = demo_log(cache=cache, quiet=True)
    res = build(log, cache / "out", Config(), blueprint=bp, workers=2)
    return res


def _t(res, key: str) -> dict:
    return res.metrics["comparisons"][key]["tolerances"]["0.10"]


def _desc(t: dict) -> str:
    return (f"F1 {t['f1']:.3f} (precision {t['precision']:.3f}, recall {t['recall']:.3f}, coverage {t['coverage']:.3f}, "
            f"recall of observed walls {t['recall_observed']:.3f})")


@pytest.mark.slow
def test_office_builds_and_reports_both_maps_against_the_blueprint(office_run):
    m = office_run.metrics
    assert not office_run.partial and m["frames"]["processed"] == 1764 and m["frames"]["laser_scans_used"] == 3527
    assert m["slam"]["laser"]["ate"]["rmse"] < 0.05  # laser SLAM: centimetres over 140 m with loop closures
    assert m["slam"]["laser"]["loops"] > 10
    laser = _t(office_run, "laser_vs_blueprint")
    assert laser["precision"] > 0.9 and laser["coverage"] > 0.9 and laser["recall_observed"] > 0.85
    kos = _t(office_run, "kos_obstacle_at_laser_poses_vs_blueprint")  # KOS without KOS SLAM's error
    assert kos["precision"] > 0.8 and kos["coverage"] > 0.4
    html = (office_run.out / "report.html").read_text()
    for key in ("kos_obstacle_vs_blueprint", "laser_vs_blueprint"):
        assert f"{_t(office_run, key)['f1']:.3f}" in html  # the report shows both F1s


@pytest.mark.slow
@pytest.mark.xfail(reason="issue 8 acceptance not met: KOS map vs blueprint F1 at 0.10 m measured 0.36-0.42 "
                          "(precision 0.52-0.64, recall 0.28-0.32, coverage 0.58-0.60); the KOS map at "
                          "the laser's poses 0.55 (precision 0.85); the camera sees 58 % of the plan's walls on "
                          "this path, so F1 <= 0.73 even for a perfect map", strict=False)
def test_office_kos_map_f1_vs_blueprint_at_least_090(office_run):
    t = _t(office_run, "kos_obstacle_vs_blueprint")
    assert t["f1"] >= 0.90, _desc(t)


@pytest.mark.slow
@pytest.mark.xfail(reason="issue 8 acceptance not met: laser map vs blueprint F1 at 0.10 m measured 0.87-0.89 "
                          "(precision 0.95, recall 0.81-0.84, coverage 0.93, recall of observed walls 0.87-0.91): the path "
                          "never enters the side rooms, and furniture is not in the plan",
                   strict=False)
def test_office_laser_map_f1_vs_blueprint_at_least_095(office_run):
    t = _t(office_run, "laser_vs_blueprint")
    assert t["f1"] >= 0.95, _desc(t)
