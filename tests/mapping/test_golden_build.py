"""`kosmap build` gives the same bytes as the golden digests in golden_build.json: every map (PGM, PNG, YAML),
every trajectory (TUM) and kosmap.mcap's messages of two short simulated logs (the room with one camera; the office
with a front and a rear camera), built serially. A rerun and a parallel build give the same bytes
(test_pipeline.py checks serial against parallel), so any difference is a change of behaviour.

When a change is meant to change them, regenerate the digests with `python -m kosmap.tools.regold` and say in the
commit why the outputs changed. What is digested and why (tools/regold.py): the files a build writes
deterministically; stats.csv, metrics.json and the report hold timings and are left out."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kosmap.tools.regold import GOLDEN, SAMPLES, build_sample, digests


@pytest.mark.slow
@pytest.mark.parametrize("sample", SAMPLES, ids=[s.name for s in SAMPLES])
def test_build_outputs_match_the_golden_digests(sample, tmp_path):
    golden = json.loads(Path(GOLDEN).read_text())[sample.name]
    got = digests(build_sample(sample, tmp_path))
    assert set(got["files"]) == set(golden["files"]), "the build writes other maps or trajectories"
    changed = sorted(f for f in golden["files"] if got["files"][f] != golden["files"][f])
    assert not changed, f"these outputs changed: {changed} (python -m kosmap.tools.regold if that is meant)"
    assert got["kosmap.mcap message count"] == golden["kosmap.mcap message count"]
    assert got["kosmap.mcap messages"] == golden["kosmap.mcap messages"], "kosmap.mcap's messages changed"
    assert len(golden["files"]) >= 20  # the seven maps × 3 files and the four trajectories
