"""FSPF+ on simulated tabletops (tests/frontend/tabletop.py: boxes 4–9 cm high on a table, Kinect-like noise):
the table is one plane, whole, and no plane bridges it and the box tops (the coherence test and region growing
of frontend/fspf.py)."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.fspf import FspfConfig, fspf_plus
from kosmap.frontend.records import CameraModel
from tests.frontend.tabletop import TABLE, tabletop_frame

TOPS = np.arange(10, 10 + 5 * 6, 5)  # the boxes' top faces (tabletop.py numbers each box's top first)

pytestmark = pytest.mark.slow


def _bridges(p, sid):
    """Planes holding ≥ 300 pixels of the table and ≥ 300 of box tops (4–9 cm above it: beyond ε = 2 cm)."""
    out = []
    for k in range(len(p)):
        sel = p.plane == k
        ids = sid[p.pixels[sel, 0], p.pixels[sel, 1]]
        if (ids == TABLE).sum() >= 300 and np.isin(ids, TOPS).sum() >= 300:
            out.append(k)
    return out


SCENES = (0, 1, 4)


@pytest.fixture(scope="module")
def frames():
    return {scene: tabletop_frame(scene, scene) for scene in SCENES}


@pytest.mark.parametrize("scene", SCENES)
def test_tabletop_table_whole_and_unbridged(frames, scene):
    depth, sid, cam, n_true = frames[scene]
    table = (sid == TABLE) & (depth > 0.5)
    recalls = []
    for seed in range(3):
        p = fspf_plus(depth, cam, FspfConfig(drop_classes=[]), seed=seed)
        lab = p.label_image()
        overlap = np.bincount(lab[table], minlength=len(p) + 1)[1:]
        k = int(overlap.argmax())
        recalls.append(overlap[k] / table.sum())
        assert overlap[k] / p.counts[k] >= 0.96, (scene, seed)  # box sides' bottom ε are within ε of the table
        assert np.degrees(np.arccos(min(1.0, abs(p.normals[k] @ n_true)))) <= 0.5
        assert _bridges(p, sid) == [], (scene, seed)
    assert min(recalls) >= 0.95 and max(recalls) - min(recalls) <= 0.05, (scene, recalls)


def test_tabletop_bridges_without_the_coherence_test(frames):
    """The scene does make RANSAC bridge: without the coherence test some plane holds table and box tops."""
    found = 0
    for depth, sid, cam, _ in frames.values():
        for seed in range(3):
            p = fspf_plus(depth, cam, FspfConfig(drop_classes=[], coherence=False), seed=seed)
            found += len(_bridges(p, sid))
    assert found >= 2


def _random_views(n: int, first: int = 100):
    """n tabletops (layout seed first…first+n−1), each seen from a camera 1.40–1.70 m high pitched 35–55° down
    (the table 1.0–1.8 m away: the noise gate's hard range included), drawn from the same seed."""
    for scene in range(first, first + n):
        rng = np.random.default_rng(scene)
        pitch, height = rng.uniform(35.0, 55.0), rng.uniform(1.40, 1.70)
        yield scene, tabletop_frame(scene, scene, pitch_deg=pitch, height=height)


def test_tabletop_bridges_are_rare_over_random_views():
    """30 random tabletops and views, one FSPF+ seed each: at most 1 frame keeps a plane holding ≥ 300 px of
    both the table and box tops (measured: 0 of these 30, 1 of 180 frames over 60 other layouts × 3 seeds from
    the fixed view; without the coherence test 16 of these 30), and the table stays whole: recall ≥ 0.95 (measured
    ≥ 0.98), precision ≥ 0.95 (≥ 0.96: the box sides' bottom ε), normal within 0.5° (≤ 0.05°)."""
    bridged, worst = [], []
    for scene, (depth, sid, cam, n_true) in _random_views(30):
        p = fspf_plus(depth, cam, FspfConfig(drop_classes=[]), seed=scene)
        if _bridges(p, sid):
            bridged.append(scene)
        table = (sid == TABLE) & (depth > 0.5)
        overlap = np.bincount(p.label_image()[table], minlength=len(p) + 1)[1:]
        k = int(overlap.argmax())
        worst.append((overlap[k] / table.sum(), overlap[k] / p.counts[k],
                      np.degrees(np.arccos(min(1.0, abs(p.normals[k] @ n_true))))))
    worst = np.array(worst)
    assert len(bridged) <= 1, bridged
    assert worst[:, 0].min() >= 0.95 and worst[:, 1].min() >= 0.95 and worst[:, 2].max() <= 0.5, worst


@pytest.mark.parametrize("quantize", [False, True])
def test_one_noisy_plane_is_not_split_away(quantize):
    """The coherence test on a single wall seen at 2.1–4.5 m with a Kinect's noise (σ = 1.4 mm·z², millimetre
    steps or not): it may shrink a plane to a layer now and then, but the wall stays one plane as large as
    without the test (measured 0.885–0.924 of the pixels either way; beyond, the noise tail past ε) and true."""
    cam = CameraModel(640, 480, np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]]), np.zeros(5), "plumb_bob",
                      "camera_optical_frame")
    n = np.array([np.sin(np.radians(30.0)), 0.0, -np.cos(np.radians(30.0))])
    x = (np.arange(640) - 319.5) / 525.0
    z = np.broadcast_to(2.5 / -(n[0] * x + n[2]), (480, 640))
    z = z + np.random.default_rng(0).normal(size=z.shape) * 1.4e-3 * z * z
    depth = (np.round(z * 1000.0) / 1000.0 if quantize else z).astype(np.float32)
    share = {}
    for coherence in (True, False):
        s = []
        for seed in range(3):
            p = fspf_plus(depth, cam, FspfConfig(drop_classes=[], coherence=coherence), seed=seed)
            k = int(p.counts.argmax())
            s.append(p.counts[k] / depth.size)
            assert np.degrees(np.arccos(min(1.0, abs(p.normals[k] @ n)))) <= 0.1
        share[coherence] = np.mean(s)
    assert share[True] >= 0.87 and share[True] >= share[False] - 0.02, share
