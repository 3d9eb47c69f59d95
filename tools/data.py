"""Where the shared public datasets are: $KOSMAP_DATA, else ../shared/data beside the repository."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    env = os.environ.get("KOSMAP_DATA")
    return Path(env) if env else (REPO.parent / "shared" / "data").resolve()
