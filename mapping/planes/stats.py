"""The planes run's statistics: per frame the thesis's Table 5.2 shares of the pixels (plus those never examined,
so that the five add up to 100 %), their means over the run (stats.csv), and the run's summary (summary.json)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from kosmap.frontend.planes import Planes
from kosmap.mapping.planes.frames import GRAVITY_WORDS, Item

STATS_COLUMNS = ("frame", "source", "stamp", "ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct",
                 "unexamined_pct", "remaining", "planes", "elapsed_ms", "gravity", "floor_m")
NUMERIC = STATS_COLUMNS[3:-2]  # averaged in the summary row; gravity (the frame's source) and floor_m are not


class StatsTable:
    """The rows of stats.csv, one per frame, and the summary row of their means."""

    def __init__(self) -> None:
        self.rows: list[dict] = []

    def add(self, name: str, item: Item, planes: Planes, floor_m: float = float("nan")) -> None:
        """A frame's row: its shares, its gravity source and the camera's height above the floor its classes used
        (empty when none: no ground plane in that frame)."""
        self.rows.append({"frame": name, "source": item.source, "stamp": f"{item.stamp_ns * 1e-9:.6f}",
                          **planes.stats.row(), "unexamined_pct": planes.stats.unexamined_pct,
                          "gravity": item.gravity, "floor_m": f"{floor_m:.4f}" if np.isfinite(floor_m) else ""})

    def floor_frames(self, gravity: str) -> int:
        """The frames of that gravity source whose classes had the camera's height above the floor (the others
        have no ground plane)."""
        return sum(1 for r in self.rows if r["gravity"] == gravity and r["floor_m"] != "")

    def __len__(self) -> int:
        return len(self.rows)

    def summary_row(self) -> dict:
        out: dict = {"frame": "summary", "source": f"{len(self.rows)} frames", "stamp": ""}
        for c in NUMERIC:
            vals = np.array([r[c] for r in self.rows], float)
            out[c] = float(vals.mean()) if len(vals) else 0.0
        return out

    def write_csv(self, path: Path) -> None:
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=STATS_COLUMNS)
            w.writeheader()
            for r in self.rows + [self.summary_row()]:
                w.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()})

    def summary(self, path: Path, cfg, gravity_used: dict[str, int], mount_estimate: dict | None,
                warnings: list[str]) -> dict:
        """summary.json: the input, the method, the filter's median and 90th percentile time per frame, the mean
        shares, where gravity came from (frames per source), the mount seen from the floor, the warnings."""
        ms = np.array([r["elapsed_ms"] for r in self.rows])
        means = self.summary_row()
        return {"input": str(path), "method": cfg.fspf.method, "frames": len(self.rows),
                "median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
                **{k: means[k] for k in NUMERIC},
                "gravity": {k: {"frames": v, "from": GRAVITY_WORDS[k], "floor_frames": self.floor_frames(k)}
                            for k, v in gravity_used.items()},
                "mount_estimate": mount_estimate, "warnings": list(warnings)}
