"""The per-frame stage of the pipeline: FSPF+ on one depth frame, then KOS on its plane points.

A pure function of the frame and the configs (the frame's seed comes from its index), so frames can run
in any order, in other processes, and give the same result as a serial run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from kosmap.frontend.camera import DepthConfig, depth_constraints
from kosmap.frontend.depthstream import DepthItem
from kosmap.frontend.fspf import FspfConfig, filter_planes, frame_seed
from kosmap.frontend.kos import Bearings, KosAccumulator, KosConfig
from kosmap.frontend.planes import FrameStats, Planes


@dataclass
class KosFrame:
    """What one depth frame contributes: its Table 5.2 stats, timings and its ranges per KOS level."""

    index: int
    stamp_ns: int
    topic: str
    ranges: np.ndarray  # (levels + obstacle) × bins float32, +inf empty, on the shared bearing grid
    stats: FrameStats
    fspf_ms: float
    kos_ms: float
    n_points: int
    planes: Planes | None = None  # kept only when asked
    cloud: tuple[np.ndarray, np.ndarray] | None = None  # a subsample of the plane points, when asked (plane_cloud)


def plane_cloud(planes: Planes, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """At most `n` of the frame's plane points (N×3 float32, camera frame) and their classes (N int8): a sorted
    subsample seeded by `seed` (the frame's index). Taken where the frame is processed, so that a worker sends
    back 4000 points, not the ~100k of the whole Planes (~2.4 MB pickled each way)."""
    pts, cls = planes.points, planes.point_classes()
    if len(pts) > n:
        pick = np.sort(np.random.default_rng(seed).choice(len(pts), n, replace=False))
        return pts[pick], cls[pick]
    return pts.copy(), cls  # (the points may be FSPF+'s scratch buffers)


def surface_window(kos_cfg: KosConfig, fspf_cfg: FspfConfig) -> float:
    """The KOS surface rule's window (frontend/kos.py KosAccumulator): the points of one plane lie within its
    noise tail, ±tail_eps·ε of it (FSPF+; FSPF's error ε), so a bin's nearest surface spans 2·tail_eps·ε from its
    nearest point. 0 (the nearest point) when [kos] nearest = "point"."""
    if kos_cfg.nearest == "point":
        return 0.0
    eps = fspf_cfg.epsilon_m if fspf_cfg.method == "fspf+" else fspf_cfg.fspf_error_m
    return 2.0 * fspf_cfg.tail_eps * eps


def kos_frame(item: DepthItem, fspf_cfg: FspfConfig, depth_cfg: DepthConfig, kos_cfg: KosConfig, bearings: Bearings,
              keep_planes: bool = False, cloud_points: int = 0) -> KosFrame:
    """FSPF+ (or FSPF) → KOS for one frame (thesis Alg. 3–7); `kos_cfg.source = "depth"` skips plane filtering.
    `keep_planes` keeps the frame's Planes; `cloud_points` > 0 keeps that many of its points (plane_cloud)."""
    t0 = time.perf_counter()
    if kos_cfg.source == "planes":
        planes = filter_planes(item.depth, item.camera, fspf_cfg, depth_cfg, item.mount, frame_seed(fspf_cfg, item.index),
                               copy=keep_planes)  # else its arrays are scratch, used only below
        pixels, n_points, stats = planes.pixels, len(planes.points), planes.stats
    else:  # every valid depth point, as depthimage_to_laserscan does
        ok = depth_constraints(item.depth, depth_cfg.min_depth, depth_cfg.max_depth)
        pixels, n_points, planes = None, int(ok.sum()), None
        stats = FrameStats(pixels=item.depth.size, ineligible=int(item.depth.size - n_points), inliers=n_points)
    t1 = time.perf_counter()
    acc = KosAccumulator(kos_cfg, bearings, depth_cfg.min_depth, depth_cfg.max_depth,
                         surface_window(kos_cfg, fspf_cfg))
    acc.add_depth(item.depth, item.camera, item.mount, pixels)  # per-pixel tables: no back-projection needed
    t2 = time.perf_counter()
    cloud = plane_cloud(planes, cloud_points, item.index) if cloud_points > 0 and planes is not None else None
    return KosFrame(item.index, item.stamp_ns, item.topic, acc.ranges, stats, (t1 - t0) * 1e3, (t2 - t1) * 1e3,
                    n_points, planes if keep_planes else None, cloud)


def merge_cameras(frames: list[KosFrame]) -> np.ndarray:
    """One time step's ranges from several cameras: the nearest per bin."""
    out = frames[0].ranges.copy()
    for f in frames[1:]:
        np.minimum(out, f.ranges, out=out)
    return out
