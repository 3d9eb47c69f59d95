"""The wheel odometry's noise measured against the scans while the SLAM ran (backend/odomnoise.py) is printed by
`kosmap build` and written in its report (report.md and report.html), from metrics.json's own numbers."""

from __future__ import annotations

import json

import pytest

from kosmap.mapping.report import odometry_noise_text
from kosmap.tools.cli import main
from tests.frontend.synthetic_log import write_mcap
from tests.mapping.synthetic_laser import make_log, records


def test_the_text_says_what_was_measured_or_that_nothing_was():
    n = {"scale_error": 0.0241, "trans_sigma": 0.0176, "heading_drift": 0.0213, "rot_scale_error": 0.0,
         "yaw_sigma": 0.0094, "turn_sigma": 0.0, "samples": 238, "measured": True}
    assert odometry_noise_text(n) == "distance +2.41 %, heading drift +1.220°/m, random 1.76 cm/√m and 0.54°/√m (238 intervals)"
    assert odometry_noise_text({**n, "measured": False}) == "–" and odometry_noise_text(None) == "–"


@pytest.mark.slow
def test_a_build_prints_and_reports_the_measured_odometry_noise(tmp_path, capsys):
    # the synthetic ring's wheels read 2 % long with a 0.5°/m heading random walk
    log = make_log(seed=1, laps=1, odom_scale=0.02)
    path = write_mcap(records(log), tmp_path / "ring.mcap")
    out = tmp_path / "out"
    assert main(["build", str(path), "--out", str(out), "--workers", "2"]) == 0
    n = json.loads((out / "metrics.json").read_text())["slam"]["laser"]["odometry_noise"]
    # measured: distance +1.48 % against the 2 % the ring's wheels were given (one lap of a small ring)
    assert n["measured"] and abs(n["scale_error"] - 0.02) <= 0.01, n
    text = odometry_noise_text(n)
    assert text.startswith(f"distance +{100 * n['scale_error']:.2f} %")
    printed = [ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("odometry")]
    assert len(printed) == 1 and "laser SLAM" in printed[0] and printed[0].endswith(text), printed
    md = (out / "report.md").read_text()
    html = (out / "report.html").read_text()
    assert text in md and "wheel odometry measured against the scans" in md
    assert f"distance +{100 * n['scale_error']:.2f} %" in html
