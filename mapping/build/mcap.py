"""kosmap.mcap, the build in one file for Foxglove: the KOS scans of every level, the laser and fused scans used,
plane points (a cloud a second), map → base_link on /tf (from the KOS SLAM, else the laser's), the paths, and
every map."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from kosmap.backend.slam import SlamResult
from kosmap.frontend.kos import FUSED
from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.records import Transform, Transforms, yaw_to_quat
from kosmap.mapping.build.spill import Spill, scan_of
from kosmap.mapping.grid import OccupancyGrid
from kosmap.mapping.kosstream import KOS_PREFIX

PLANES_TOPIC = "/kosmap/planes/points"


def write_mcap(path: Path, spill: Spill, statics: list[Transforms], gt: np.ndarray, results: dict[str, SlamResult],
               grids_when_done: Callable[[], dict[str, OccupancyGrid]], poll: Callable[[], None] = lambda: None) -> Path:
    """Write the MCAP (module doc); `poll` is called between batches of messages, `grids_when_done` gives the maps
    (name → grid) once the scans are written."""
    primary = "kos" if "kos" in results else "laser"
    pres = results[primary]
    # (stamp, kind, index) of every message, written in time order: three int64 arrays (24 bytes a message), not
    # a list of tuples (~100 bytes each)
    parts = [np.asarray(spill.kos.stamps, np.int64), np.array(spill.laser.stamps, np.int64),
             np.array(spill.fused.stamps, np.int64),
             np.array([c[0] for c in spill.cloud_index], np.int64).reshape(-1), np.asarray(pres.stamps_ns, np.int64)]
    ev_t = np.concatenate(parts)
    ev_k = np.concatenate([np.full(len(a), k, np.int64) for k, a in enumerate(parts)])
    ev_i = np.concatenate([np.arange(len(a), dtype=np.int64) for a in parts])
    order = np.lexsort((ev_i, ev_k, ev_t))
    kos_rows, laser_rows, fused_rows, plane_rows = (spill.kos.reader(), spill.laser.reader(), spill.fused.reader(),
                                                    spill.planes.reader())
    t_end = int(ev_t.max()) if len(ev_t) else 0
    with McapWriter(path) as w:
        for rec in statics:
            w.write(rec, "/tf_static")
        for c in range(0, len(order), 1024):
            poll()
            sel = order[c:c + 1024]
            for stamp, kind, i in zip(ev_t[sel].tolist(), ev_k[sel].tolist(), ev_i[sel].tolist()):
                if kind == 0:
                    r = kos_rows.get(i).reshape(len(spill.bands), -1)
                    for k, b in enumerate(spill.bands):
                        w.write(scan_of(spill.kos.meta, stamp, r[k]), KOS_PREFIX + b)
                elif kind == 1:
                    w.write(scan_of(spill.laser.meta, stamp, laser_rows.get(i)), spill.laser.meta.get("topic") or "/scan")
                elif kind == 2:
                    w.write(scan_of(spill.fused.meta, stamp, fused_rows.get(i)), KOS_PREFIX + FUSED)
                elif kind == 3:
                    _, first, n = spill.cloud_index[i]
                    rows = plane_rows.block(first, n)
                    w.write_pointcloud(PLANES_TOPIC, stamp, "base_link", rows[:, :3], {"class": rows[:, 3]})
                else:
                    x, y, yaw = pres.poses[i]
                    tf = Transform("map", "base_link", np.array([x, y, 0.0]), yaw_to_quat(float(yaw)), stamp)
                    w.write(Transforms(stamp, (tf,), False, "/tf"), "/tf")
        for name, res in results.items():
            step = max(1, len(res.poses) // 2000)
            w.write_path(f"/kosmap/path/{name}", t_end, "map", res.poses[::step], res.stamps_ns[::step])
        if len(gt):
            step = max(1, len(gt) // 2000)
            w.write_path("/kosmap/path/ground_truth", t_end, "map", gt[::step, 1:4], (gt[::step, 0] * 1e9).astype(np.int64))
        for name, gr in grids_when_done().items():
            w.write_grid(f"/kosmap/map/{name}", t_end, "map", gr.data, gr.resolution, gr.origin)
    for r in (kos_rows, laser_rows, fused_rows, plane_rows):
        r.close()
    return path

