"""The self-consistency check (backend/consistency.py) on a narrow scan's few revisits: a verdict needs evidence. A
revisit is compared only where the earlier scans saw the same stretch of surface (a point past their end is not
compared against their last point), and the revisits' count must be able to refute a consistent map (a sign test);
fewer are "too few revisits to tell". KOS SLAM (one Kinect, 70.6°) in the irregular hall (tests/worlds/atrium.yaml:
30°/60° walls, pillars, round objects) with harsh wheel odometry maps well and is not called bent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kosmap.backend.consistency import BENT_P90_CELLS, consistency, revisit_verdict
from kosmap.frontend import se2

WORLDS = Path(__file__).resolve().parents[1] / "worlds"
HARSH = dict(odom_scale_error_left=0.02, odom_scale_error_right=0.028, odom_heading_bias_deg_per_m=0.3)


def test_a_verdict_needs_enough_revisits():
    """Seven revisits all beyond their tolerance refute a consistent map (2⁻⁷ < 1 %); five do not (too few to tell),
    nor do seven of which two fit; three off by more than BENT_P90_CELLS tolerances each do (0.1³: a gross bend shows
    on fewer); none: nothing."""
    assert revisit_verdict(np.full(7, 1.5)) == (True, True)
    assert revisit_verdict(np.full(5, 1.5)) == (False, False)
    assert revisit_verdict(np.array([1.5] * 5 + [0.5] * 2)) == (False, True)
    assert revisit_verdict(np.full(3, BENT_P90_CELLS + 0.5)) == (True, False)
    assert revisit_verdict(np.full(2, BENT_P90_CELLS + 0.5)) == (False, False)
    assert revisit_verdict(np.zeros(0)) == (False, False)


def _wall_run(x0_new: float, shift: float):
    """Ten keyframes see the wall y = 2 over x ∈ [0, 3] (the same world points, 5 cm apart); 45 s later ten more see it
    over [x0_new, x0_new + 3], placed `shift` m off across the wall; poses are exact otherwise."""
    def scan(pose, lo):
        x = np.arange(lo, lo + 3.0, 0.05)
        return se2.transform_points(se2.inverse(pose), np.column_stack((x, np.full_like(x, 2.0))))

    old = [np.array([0.1 * k, 0.0, 0.0]) for k in range(10)]
    new = [np.array([x0_new + 0.1 * k, 0.0, 0.0]) for k in range(10)]
    pts = [scan(p, 0.0) for p in old] + [scan(p, x0_new) for p in new]
    solved = np.array(old + new)
    solved[10:, 1] += shift
    return np.concatenate([np.arange(10.0), 45.0 + np.arange(10.0)]), solved, pts


def test_a_revisit_is_compared_only_where_the_views_overlap():
    """The later keyframes see the wall 1.5 m further along, at exact poses: their points past x = 3 have no earlier
    scan there; measured against the earlier scans' last point (along the wall) they made a consistent map 'off'. Only
    the overlap is compared: the misfit is ~0; the same run placed 8 cm across the wall is off by 8 cm and bent."""
    t, poses, pts = _wall_run(1.5, 0.0)
    c = consistency(t, poses, pts)
    assert c.revisit_keyframes == 10 and c.median_m < 0.005 and not c.bent, c
    t, poses, pts = _wall_run(1.5, 0.08)
    c = consistency(t, poses, pts)
    assert c.revisit_keyframes == 10 and 0.07 < c.median_m < 0.09 and c.bent, c


@pytest.mark.slow
def test_kos_slam_in_the_irregular_hall_with_harsh_wheels_is_not_called_bent(tmp_path):
    """KOS SLAM alone (no laser), the harsh wheels, seed 1 (the camera 1 m up, level): a good map (ATE ≤ 0.05 m) whose
    few revisits see the hall's pillars and round objects from other sides; not called bent."""
    from kosmap.mapping.config import Config
    from kosmap.mapping.slam import evaluate, run_slam
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    log = tmp_path / "atrium.mcap"
    simulate(load_world(str(WORLDS / "atrium.yaml")),
             SimConfig(seed=1, **HARSH, depth_rate=10.0, depth_width=256, depth_height=212, laser=False,
                       compression="lz4"), log)
    r = run_slam(log, Config(), source="kos")
    m = evaluate(r)
    c = r.consistency
    assert m["ate"]["rmse"] <= 0.05, m["ate"]
    assert m["ate_odometry"]["rmse"] > 0.3, m["ate_odometry"]  # the wheels alone are far off
    assert not c["bent"], c
    assert not any("likely bent" in w for w in r.warnings), r.warnings


def test_the_console_says_too_few_revisits_to_tell():
    """Five revisits a cell and a half off: no verdict, and the console/report line says so; seven: likely bent."""
    from kosmap.mapping.report import consistency_text

    t5, p5, pts5 = _wall_run(1.5, 0.08)
    keep = list(range(10)) + list(range(10, 15))  # five revisits
    c = consistency(t5[keep], p5[keep], [pts5[k] for k in keep])
    assert c.revisit_keyframes == 5 and not c.bent and c.too_few, c
    assert consistency_text(c.as_dict()).endswith("5 keyframes): too few revisits to tell")
    keep = list(range(10)) + list(range(10, 17))
    c = consistency(t5[keep], p5[keep], [pts5[k] for k in keep])
    assert c.bent and not c.too_few and consistency_text(c.as_dict()).endswith(": likely bent"), c
