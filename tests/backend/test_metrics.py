"""Trajectory metrics: the Kümmerle relations metric against a hand-computed case, ATE/RPE, references, files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kosmap.backend import metrics as M
from kosmap.backend.trajio import read_g2o, read_tum, write_g2o, write_tum
from kosmap.frontend import se2


def test_relations_metric_hand_computed(tmp_path):
    # Estimated poses at three scan times.
    stamps = [10.0, 11.0, 12.0]
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, math.pi / 2], [1.0, 1.0, math.pi / 2]])
    # Relations (t1 t2 x y z roll pitch yaw): pose at t2 in the frame of the pose at t1.
    # Estimated δ(10→11) = (1, 0, 90°); δ(11→12) = (1, 0, 0) [1 m along the robot's x, which points +y];
    # δ(10→12) = (1, 1, 90°).
    text = ("10.000000 11.000000 1.1 0.0 0 0 0 1.5707963267948966\n"  # 0.1 m off along x, yaw exact
            "11.000000 12.000000 1.0 0.2 0 0 0 0.0174532925199433\n"  # 0.2 m off along y, 1° off
            "10.000000 12.000000 0.7 1.4 0 0 0 1.5707963267948966\n")  # (−0.3, +0.4): 0.5 m off, yaw exact
    p = tmp_path / "hand.relations"
    p.write_text(text)
    m = M.relations_metric(stamps, poses, p)
    # hand computation: translational errors 0.1, 0.2, 0.5 m; rotational 0, 1, 0 degrees
    et = np.array([0.1, 0.2, 0.5])
    er = np.array([0.0, 1.0, 0.0])
    assert m["n"] == 3 and m["missing"] == 0
    assert m["abs_trans"]["mean"] == pytest.approx(0.8 / 3, abs=1e-12)
    assert m["abs_trans"]["std"] == pytest.approx(np.std(et), abs=1e-12)
    assert m["sq_trans"]["mean"] == pytest.approx((0.01 + 0.04 + 0.25) / 3, abs=1e-12)
    assert m["sq_trans"]["std"] == pytest.approx(np.std(et ** 2), abs=1e-12)
    assert m["abs_rot_deg"]["mean"] == pytest.approx(1.0 / 3, abs=1e-9)
    assert m["abs_rot_deg"]["std"] == pytest.approx(np.std(er), abs=1e-9)
    assert m["sq_rot_deg2"]["mean"] == pytest.approx(1.0 / 3, abs=1e-9)
    assert m["max_trans"] == pytest.approx(0.5, abs=1e-12)


def test_relations_metric_is_frame_free_and_refuses_foreign_relations():
    rng = np.random.default_rng(1)
    poses = np.cumsum(rng.normal(0, 0.3, (50, 3)), axis=0)
    stamps = np.arange(50) * 0.2 + 100.0
    i, j = rng.integers(0, 50, 40), rng.integers(0, 50, 40)
    rel = np.column_stack((stamps[i], stamps[j], se2.between(poses[i], poses[j])))
    moved = se2.compose(np.repeat([[5.0, -2.0, 1.0]], 50, 0), poses)  # same trajectory, another map frame
    m = M.relations_metric(stamps, moved, rel)
    assert m["abs_trans"]["mean"] < 1e-12 and m["abs_rot_deg"]["mean"] < 1e-9
    with pytest.raises(M.MetricsError, match="relations"):
        M.relations_metric(stamps + 1000.0, poses, rel)


def test_ate_aligns_and_rpe_measures_increments():
    t = np.arange(100) * 0.1
    ref = np.column_stack((np.cos(t), np.sin(t), t + np.pi / 2))
    est = se2.compose(np.repeat([[2.0, 3.0, 0.7]], 100, 0), ref)
    assert M.ate(t, est, t, ref)["rmse"] < 1e-9
    assert M.ate(t, est, t, ref, align=False)["rmse"] > 1.0
    noisy = ref.copy()
    noisy[50:, 0] += 0.1  # one step of 0.1 m
    r = M.rpe(t, noisy, t, ref)
    assert r["trans_max"] == pytest.approx(0.1, abs=1e-9)
    with pytest.raises(M.MetricsError):
        M.ate(t + 500, est, t, ref)


def test_reference_from_relations_recovers_the_trajectory():
    rng = np.random.default_rng(2)
    truth = np.cumsum(rng.normal(0, 0.2, (30, 3)), axis=0)
    truth[:, 2] = se2.wrap(truth[:, 2])
    stamps = 1000.0 + np.arange(30)
    pairs = [(k, k + 1) for k in range(29)] + [(0, 29), (5, 20)]
    rel = np.array([(stamps[a], stamps[b], *se2.between(truth[a], truth[b])) for a, b in pairs])
    ref = M.reference_from_relations(rel)
    assert ref.comp.max() == 0
    # up to the gauge (first pose at the origin) the reference is the truth
    back = se2.compose(np.repeat(truth[:1], 30, 0), ref.poses)
    assert np.abs(back[:, :2] - truth[:, :2]).max() < 1e-6
    # loop precision: one correct loop, one 0.5 m off
    good = se2.between(truth[3], truth[25])
    bad = se2.compose(good, [0.5, 0.0, 0.0])
    pa, ca = ref.at(stamps[[3, 3]])
    pb, cb = ref.at(stamps[[25, 25]])
    lp = M.loop_precision(np.array([good, bad]), pa, pb, ca, cb)
    assert (lp["checked"], lp["correct"]) == (2, 1)


def test_tum_and_g2o_round_trip(tmp_path):
    t = 1_700_000_000.0 + np.arange(5) * 0.1
    poses = np.array([[0, 0, 0], [1, 0, 0.5], [1, 1, 3.1], [0, 1, -3.1], [0.5, 0.5, -1.0]], dtype=float)
    write_tum(tmp_path / "a.tum", t, poses)
    t2, p2 = read_tum(tmp_path / "a.tum")
    assert np.allclose(t2, t, atol=1e-6) and np.allclose(p2, poses, atol=1e-6)
    edges = [(0, 1, se2.between(poses[0], poses[1]), np.array([0.1, 0.1, 0.01]), "match"),
             (0, 4, se2.between(poses[0], poses[4]), np.array([0.05, 0.05, 0.02]), "loop")]
    write_g2o(tmp_path / "g.g2o", poses, edges)
    v, e = read_g2o(tmp_path / "g.g2o")
    assert np.allclose(v, poses, atol=1e-6)
    assert len(e) == 2 and e[1][3][0, 0] == pytest.approx(400.0) and e[1][3][2, 2] == pytest.approx(2500.0)
    with pytest.raises(M.KosmapError):
        read_tum(tmp_path / "missing.tum")


def test_ate_and_rpe_agree_with_evo(tmp_path):
    pytest.importorskip("evo")
    from evo.core import metrics as em
    from evo.core import sync
    from evo.tools import file_interface

    rng = np.random.default_rng(5)
    t = 100.0 + np.arange(200) * 0.1
    ref = np.cumsum(rng.normal(0, 0.1, (200, 3)), axis=0)
    est = se2.compose(np.repeat([[1.0, -2.0, 0.4]], 200, 0), se2.compose(ref, rng.normal(0, 0.02, (200, 3))))
    write_tum(tmp_path / "ref.tum", t, ref)
    write_tum(tmp_path / "est.tum", t + 0.001, est)
    r = file_interface.read_tum_trajectory_file(str(tmp_path / "ref.tum"))
    e = file_interface.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    r, e = sync.associate_trajectories(r, e, max_diff=0.01)
    e.align(r, correct_scale=False)
    ape = em.APE(em.PoseRelation.translation_part)
    ape.process_data((r, e))
    ours = M.ate(t + 0.001, est, t, ref)
    assert ours["rmse"] == pytest.approx(ape.get_statistic(em.StatisticsType.rmse), rel=1e-6)
    rpe = em.RPE(em.PoseRelation.translation_part, delta=1, delta_unit=em.Unit.frames, all_pairs=False)
    rpe.process_data((r, e))
    assert M.rpe(t + 0.001, est, t, ref)["trans_rmse"] == pytest.approx(rpe.get_statistic(em.StatisticsType.rmse), rel=1e-6)
