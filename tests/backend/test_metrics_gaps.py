"""The relations metric of a trajectory from a damaged log: relations whose scans fell in a gap (a skipped chunk)
are counted as lost and the rest scored; relations naming scans the trajectory does not have anywhere near still
mean another log's file."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.backend.metrics import MetricsError, relations_metric


def _track(n=200, rate=5.0):
    t = 1000.0 + np.arange(n) / rate
    poses = np.column_stack([0.3 * np.arange(n) / rate, np.zeros(n), np.zeros(n)])
    return t, poses


def _relations(t, poses, pairs):
    return np.array([[t[a], t[b], poses[b, 0] - poses[a, 0] + 0.01, 0.0, 0.0] for a, b in pairs])


def test_relations_in_a_gap_of_the_trajectory_are_lost_not_another_log():
    t, poses = _track()
    rel = _relations(t, poses, [(i, i + 5) for i in range(0, 190, 2)])
    keep = (t < 1010.0) | (t > 1016.0)  # 6 s of scans lost with a damaged chunk
    m = relations_metric(t[keep], poses[keep], rel)
    lost = sum(not (keep[a] and keep[b]) for a, b in [(i, i + 5) for i in range(0, 190, 2)])
    assert m["missing"] == m["in_gaps"] == lost > 0.01 * len(rel)
    assert m["n"] == len(rel) - lost and m["abs_trans"]["mean"] == pytest.approx(0.01)


def test_relations_between_the_scans_are_another_logs():
    t, poses = _track()
    rel = _relations(t, poses, [(i, i + 5) for i in range(0, 190, 2)])
    rel[::3, :2] += 0.1  # half a scan period off: stamps no scan has, inside the trajectory's span
    with pytest.raises(MetricsError, match="is the relations file for this log"):
        relations_metric(t, poses, rel)
    with pytest.raises(MetricsError):
        relations_metric(t - 5000.0, poses, _relations(t, poses, [(0, 5), (10, 15)]))  # no stamp in common
