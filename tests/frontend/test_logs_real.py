"""The real public logs read completely and consistently (../shared/data/laser, SOURCES.md)."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.records import Odometry, Scan, Transforms
from tests.conftest import require_data

pytestmark = pytest.mark.data

# (file, scans, odometry messages, duration s) from SOURCES.md
REAL_LOGS = [
    ("laser/intel/intel.orig.bag", 13631, 26915, 2691.3),
    ("laser/fr079/fr079.orig.bag", 4934, 8951, 1061.7),
    ("laser/mit-csail/mit-csail.clf", 1988, 1988, 424.0),
]


@pytest.mark.parametrize("rel,n_scans,n_odom,duration", REAL_LOGS)
def test_real_log_reads_completely(rel, n_scans, n_odom, duration):
    with open_log(require_data(rel)) as log:
        info = log.info()
        assert info.count("/scan") == n_scans
        assert info.duration == pytest.approx(duration, abs=0.5)
        det = detect_topics(info.types())
        assert det.scan == "/scan" and det.odom == "/odom" and det.depth == []
        scans = odoms = 0
        last = -1
        beams = set()
        for rec in log.read(det.wanted()):
            assert rec.stamp_ns >= last, "records must come in time order"
            last = rec.stamp_ns
            if isinstance(rec, Scan):
                scans += 1
                beams.add(len(rec.ranges))
                assert rec.ranges.dtype == np.float32
                assert rec.angle_min == pytest.approx(-np.pi / 2, abs=1e-6)
                assert rec.angle_max == pytest.approx(np.pi / 2, abs=1e-4)
            elif isinstance(rec, Odometry):
                odoms += 1
        assert scans == n_scans and odoms == n_odom
        assert len(beams) == 1
        assert log.warnings == []


def test_intel_static_mount_and_relations_stamps_match_scans():
    """Relation timestamps (ipc) are scan header stamps to < 1e-5 s (SOURCES.md): the reader keeps them exact."""
    rel = require_data("laser/intel/intel.relations")
    t_rel = np.unique(np.loadtxt(rel, usecols=(0, 1)).ravel())
    with open_log(require_data("laser/intel/intel.orig.bag")) as log:
        stamps, statics = [], []
        for rec in log.read(["/scan", "/tf_static"]):
            if isinstance(rec, Scan):
                stamps.append(rec.stamp)
            elif isinstance(rec, Transforms):
                statics.append(rec)
    stamps = np.array(stamps)
    idx = np.clip(np.searchsorted(stamps, t_rel), 1, len(stamps) - 1)
    err = np.minimum(np.abs(stamps[idx] - t_rel), np.abs(stamps[idx - 1] - t_rel))
    assert err.max() < 1e-5
    assert len(statics) == 1 and statics[0].static
    assert statics[0].transforms[0].parent == "base_link"


def test_csail_clf_no_returns_are_outside_range_and_odometry_is_per_scan():
    with open_log(require_data("laser/mit-csail/mit-csail.clf")) as log:
        recs = list(log.read())
    scans = [r for r in recs if isinstance(r, Scan)]
    odoms = [r for r in recs if isinstance(r, Odometry)]
    assert len(scans[0].ranges) == 361
    # The first FLASER line holds 81.91 "no return" values: they must not count as valid beams.
    assert (scans[0].ranges >= 80).sum() > 0
    assert not scans[0].valid()[scans[0].ranges >= 80].any()
    assert [s.stamp_ns for s in scans] == [o.stamp_ns for o in odoms]
    # Odometry moves a plausible distance: the CSAIL run is a few hundred metres.
    xy = np.array([(o.x, o.y) for o in odoms])
    travelled = np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()
    assert 100 < travelled < 1000


def test_scan_tools_demo_bag_with_nonstandard_index_reads_all_scans():
    """rosbags asserts on this real bag's index; the linear fallback recovers all 360 scans (SOURCES.md)."""
    with open_log(require_data("depth/scan_tools_demo_bag/demo.bag")) as log:
        info = log.info()
        scans = [r for r in log.read(["/scan"])]
    assert info.count("/scan") == 360
    assert len(scans) == 360
    assert all(len(s.ranges) == 681 for s in scans)
    assert scans[0].angle_increment == pytest.approx(0.0061359, abs=1e-6)
    assert scans[-1].stamp - scans[0].stamp == pytest.approx(35.8, abs=0.2)
