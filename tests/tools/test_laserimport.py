"""Research-format laser logs imported as CARMEN ROBOTLASER1 logs (tools/laserimport.py) and mapped: the readers'
geometry (beam angles, ranges, saturation, odometry) on small files, then two real logs through SLAM."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.records import Odometry, Scan
from kosmap.tools.laserimport import import_log, main


def _records(path):
    with open_log(path) as log:
        return list(log.read())


def test_dpslam_text_becomes_scans_with_odometry_and_its_saturation_is_no_return(tmp_path):
    lines = []
    for k in range(40):
        r = [2.0 + 0.01 * i for i in range(181)]
        r[90] = 8.183  # the SICK's 8 m mode: no return
        lines += [f"Odometry {0.1 * k:.3f} 0.0 0.05", "Laser 181 " + " ".join(f"{v:.3f}" for v in r)]
    src = tmp_path / "loop.log"
    src.write_text("\n".join(lines) + "\n")
    assert main([str(src), str(tmp_path / "loop.clf"), "--rate", "4"]) == 0
    recs = _records(tmp_path / "loop.clf")
    scans = [r for r in recs if isinstance(r, Scan)]
    odo = [r for r in recs if isinstance(r, Odometry)]
    assert len(scans) == len(odo) == 40
    s = scans[3]
    assert abs(s.angle_min + math.pi / 2) < 1e-6 and abs(s.angle_increment - math.pi / 180) < 1e-7
    assert abs((scans[1].stamp_ns - scans[0].stamp_ns) * 1e-9 - 0.25) < 1e-6  # no times: 4 Hz as asked
    assert s.ranges[90] >= s.range_max and abs(s.ranges[10] - 2.1) < 1e-3  # saturation lies beyond range_max
    assert abs(odo[3].x - 0.3) < 1e-6 and abs(odo[3].yaw - 0.05) < 1e-6


def test_breezyslam_ticks_become_a_differential_drive(tmp_path):
    # 2000 ticks a turn of a 77 mm wheel: 1000 ticks on both wheels = 0.2419 m straight; then the right wheel only
    rows = []
    for k, (left, right) in enumerate([(0, 0), (1000, 1000), (1000, 1500)]):
        rows.append(" ".join([str(1_000_000 + 100_000 * k), "0", str(left), str(right)] + ["0"] * 20
                             + ["1500"] * 682 + ["0"]))
    src = tmp_path / "exp.dat"
    src.write_text("\n".join(rows) + "\n")
    log = import_log(src, tmp_path / "exp.clf")
    assert log.ranges.shape == (3, 682) and abs(math.degrees(log.angle_increment * 681) - 240.0) < 1e-9
    step = 1000 * 2 * math.pi / 2000 * 0.077
    assert abs(log.odometry[1, 0] - step) < 1e-9 and log.odometry[1, 2] == 0.0
    assert abs(log.odometry[2, 2] - (step / 2) / (2 * 0.165)) < 1e-9  # right wheel 0.121 m more: a left turn
    assert abs(log.stamps[1] - log.stamps[0] - 0.1) < 1e-9


def test_an_unknown_file_is_one_line(tmp_path, capsys):
    src = tmp_path / "x.txt"
    src.write_text("hello world\n")
    assert main([str(src), str(tmp_path / "x.clf")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--format" in err and not (tmp_path / "x.clf").exists()


@pytest.mark.slow
@pytest.mark.data
@pytest.mark.parametrize("name, odometry_m", [("dpslam_duke_loop5/loop5.log", 56.0),
                                              ("breezyslam_mines_exp1/exp1.dat", 44.5)])
def test_real_research_logs_map(data_dir, tmp_path, name, odometry_m):
    from kosmap.mapping.config import Config
    from kosmap.mapping.slam import run_slam

    out = tmp_path / "log.clf"
    log = import_log(data_dir / "laser" / "unscored" / name, out)
    r = run_slam(out, Config())
    assert len(r.stamps_ns) == len(log.stamps) and len(r.keyframes) > 100
    # the path SLAM finds is the wheels' within 10 % (SOURCES.md: about 56 m and 44.5 m; measured 57.8 and 46.6 m)
    length = float(np.hypot(*np.diff(r.poses[:, :2], axis=0).T).sum())
    assert abs(length - odometry_m) < 0.1 * odometry_m, length
