"""FSPF+ on simulated tabletops (tests/frontend/tabletop.py: boxes 4–9 cm high on a table, Kinect-like noise):
the table is one plane, whole, and no plane bridges it and the box tops (the coherence test and region growing
of frontend/fspf.py)."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.fspf import FspfConfig, fspf_plus
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
