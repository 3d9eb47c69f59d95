"""metrics.json of a build: the log and its sources, the frames (thesis Table 5.2: what FSPF+ kept; Table 5.5:
its speed), each SLAM's summary and accuracy against the ground truth, the maps, the comparisons, the timings."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.backend import metrics as M
from kosmap.backend.slam import SlamResult
from kosmap.frontend.errors import KosmapError
from kosmap.mapping.build.grids import MapOut
from kosmap.mapping.build.readpass import TABLE_5_2, LogSources, ReadResult
from kosmap.mapping.config import Config, config_dict
from kosmap.mapping.slam import evaluate, summary


@dataclass
class Timing:
    """Wall time of the build's stages, s."""

    read_and_frames_s: float
    slam_finish_s: float
    maps_s: float
    compare_s: float


def _stats(v) -> dict:
    a = np.asarray(v, np.float64)
    if not a.size:
        return {"n": 0, "mean": None, "std": None, "median": None, "p90": None}
    return {"n": int(a.size), "mean": float(a.mean()), "std": float(a.std()), "median": float(np.median(a)),
            "p90": float(np.percentile(a, 90))}


def slam_metrics(results: dict[str, SlamResult], gt: np.ndarray, warnings: list[str]) -> dict:
    """Each SLAM's summary (backend/slam.py) and, with a ground truth, its ATE/RPE and the wheel odometry's ATE."""
    slam = {}
    for name, res in results.items():
        s = summary(res)
        s.pop("warnings", None)
        acc = {}
        if len(gt) >= 2:
            try:
                acc = evaluate(res, ground_truth=(gt[:, 0], gt[:, 1:4]))
                ok = np.isfinite(res.odom_poses).all(axis=1)
                if ok.sum() >= 2:
                    acc["ate_odometry"] = M.ate(res.stamps[ok], res.odom_poses[ok], gt[:, 0], gt[:, 1:4])
            except KosmapError as e:
                warnings.append(f"{name} trajectory not scored against the ground truth: {e}")
        slam[name] = {**s, **acc, "scans_in": int(len(res.stamps_ns))}
    return slam


def build_metrics(log: Path, src: LogSources, read: ReadResult, results: dict[str, SlamResult],
                  maps: dict[str, MapOut], comparisons: dict, overlays: dict[str, Path], cfg: Config, blueprint,
                  workers: int, warnings: list[str], timing: Timing) -> dict:
    """The metrics document (module doc), before the memory and the totals the caller adds."""
    det, counts = src.det, src.counts
    st = read.stats
    frames = read.frames
    slam = slam_metrics(results, read.gt, warnings)
    pass1 = timing.read_and_frames_s
    fspf, kos = st["fspf_ms"], st["kos_ms"]
    t52 = {k: _stats(st[k]) for k in TABLE_5_2}
    t55 = {"fspf_ms": _stats(fspf), "kos_ms": _stats(kos),
           "per_core_hz": 1000.0 / float(np.mean(fspf + kos)) if frames else None,
           "system_hz": frames / pass1 if pass1 > 0 and frames else None,
           "map_creation_s": timing.maps_s + timing.slam_finish_s,
           "workers": workers}
    depth_in_log = sum(counts.get(t, 0) for t in det.depth)
    return {
        "kosmap": "build", "partial": read.partial,
        "log": {"path": str(log), "duration_s": src.duration, "read_s": read.log_s, "topics": det.as_dict()},
        "interrupted_at_s": read.log_s if read.partial else None,
        "sources": {"kos": bool(det.depth), "laser": bool(det.scan), "ground_truth": bool(len(read.gt)),
                    "blueprint": None if blueprint is None else str(blueprint)},
        "frames": {"processed": frames, "in_log": depth_in_log, "cameras": len(det.depth),
                   "steps": len(read.spill.kos), "depth_rate_hz": cfg.build.depth_rate,
                   "laser_scans_in_log": counts.get(det.scan, 0) if det.scan else 0,
                   "laser_scans_read": read.laser_seen, "laser_scans_used": read.laser_kept,
                   "laser_rate_hz": cfg.build.laser_rate},
        "table_5_2": t52, "table_5_5": t55,
        "timing": {"read_and_frames_s": timing.read_and_frames_s, "slam_finish_s": timing.slam_finish_s,
                   "maps_s": timing.maps_s, "compare_s": timing.compare_s, "read_and_frames_cpu_s": read.cpu_s,
                   "log_s": read.log_s},
        "slam": slam, "slam_scan": cfg.build.slam_scan,
        "maps": {k: m.as_metrics() for k, m in maps.items()},
        "comparisons": comparisons, "overlays": {k: str(v) for k, v in overlays.items()},
        "config": config_dict(cfg), "warnings": list(dict.fromkeys(warnings)),
    }
