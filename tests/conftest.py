"""Shared fixtures: the public datasets (skip when absent, fail when KOSMAP_REQUIRE_DATA=1)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from kosmap.tools.data import data_dir as _data_dir


def require_data(relpath: str = "") -> Path:
    """Path under the shared data folder; skips the test if missing (fails instead when CI requires the data)."""
    p = _data_dir() / relpath
    if not p.exists():
        msg = f"shared data {p} not found (set KOSMAP_DATA to the folder holding laser/ and depth/)"
        if os.environ.get("KOSMAP_REQUIRE_DATA") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return p


@pytest.fixture
def data_dir() -> Path:
    return require_data()
