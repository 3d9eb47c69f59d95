"""Benchmark: KOS ms per frame for 1 and 3 levels beside a depthimage_to_laserscan-style baseline.

    .venv/bin/python -m tools.bench_kos [--frames 20]

Frames: simulated Kinect v2 frames of the office world (noisy), FSPF+ plane points as KOS input (the thesis),
and all valid depth points (the `depth` source). Times are CPU time of this process (the machine is shared),
median and p90 over frames. Baselines in the same run: depthimage_to_laserscan (min range per column over a
band of rows around the centre row, vectorised numpy) and a numpy KOS (`np.minimum.at`). Writes
docs/bench/kos.json and kos.md.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from frontend.camera import DepthConfig, backproject, depth_constraints  # noqa: E402
from frontend.fspf import FspfConfig, filter_planes, warmup  # noqa: E402
from frontend.kos import KosAccumulator, KosConfig, bearings_for, camera_view  # noqa: E402
from tools.benchutil import pin_one_core  # noqa: E402
from tools.data import REPO  # noqa: E402

TARGET_3_LEVELS_MS, TARGET_PER_LEVEL_MS = 1.0, 0.1  # issue 5


def frames(n: int):
    """(depth, camera, mount) of n noisy simulated office frames along the bundled path."""
    from tools.simulate import load_world, render_depth
    from tools.simulate.log import trajectory
    from tools.simulate.config import SimConfig
    from tools.simulate.render import camera_mount, kinect_v2_model

    world = load_world("office")
    traj = trajectory(world, SimConfig())
    cam, mount = kinect_v2_model(), camera_mount()
    out = []
    for i, t in enumerate(np.linspace(5.0, traj.duration - 5.0, n)):
        pose = tuple(float(v) for v in traj.pose(t)[0])
        d, _ = render_depth(world, pose, mount, cam, rng=np.random.default_rng(i))
        out.append((d, cam, mount))
    return out


def depthimage_to_laserscan(depth: np.ndarray, cam, scan_height: int = 10, rmin: float = 0.5, rmax: float = 4.5):
    """The ROS depthimage_to_laserscan idea: per column, the nearest range over a band of rows at the centre."""
    c = int(round(cam.cy))
    band = depth[c - scan_height // 2: c + scan_height // 2 + 1]
    x = (np.arange(depth.shape[1]) - cam.cx) / cam.fx
    r = band * np.sqrt(1.0 + x * x)[None, :]
    r = np.where((band > 0) & (r >= rmin) & (r <= rmax), r, np.inf)
    return r.min(axis=0)


def kos_numpy(points: np.ndarray, mount, cfg: KosConfig, b, rmin=0.5, rmax=4.5) -> np.ndarray:
    """KOS with numpy only: transform, bands, atan2 bins and `np.minimum.at` (STACK.md's baseline)."""
    m = mount.matrix()
    p = points.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    r = np.hypot(p[:, 0], p[:, 1])
    k = np.floor((np.arctan2(p[:, 1], p[:, 0]) - b.angle_min) / b.angle_increment + 0.5).astype(np.int64)
    ok = (r >= rmin) & (r <= rmax) & (k >= 0) & (k < b.n)
    out = np.full((len(cfg.bands()), b.n), np.inf)
    for i, (_, lo, hi) in enumerate(cfg.bands()):
        sel = ok & (p[:, 2] >= lo) & (p[:, 2] <= hi)
        np.minimum.at(out[i], k[sel], r[sel])
    return out


def cpu_ms(fn, repeat: int = 5) -> float:
    best = math.inf
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, (time.process_time() - t) * 1e3)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    args = ap.parse_args()
    pin = pin_one_core()
    warmup()
    data = frames(args.frames)
    dcfg = DepthConfig()
    rows = {k: [] for k in ("kos1_planes", "kos3_planes", "kos3_depth", "kos3_numpy_planes", "d2l", "n_planes", "n_depth")}
    for i, (d, cam, mount) in enumerate(data):
        planes = filter_planes(d, cam, FspfConfig(analysed_fraction=0.99), dcfg, mount, seed=i)
        ok = depth_constraints(d, dcfg.min_depth, dcfg.max_depth)
        rr, cc = np.nonzero(ok)
        allpts = backproject(d, cam, rr, cc)
        b = bearings_for([(cam, mount)])
        lo, hi = camera_view(cam, mount)
        for key, pts, levels in (("kos1_planes", planes.points, [0.3]), ("kos3_planes", planes.points, [0.3, 0.75, 1.5]),
                                 ("kos3_depth", allpts, [0.3, 0.75, 1.5])):
            acc = KosAccumulator(KosConfig(levels=levels), b, dcfg.min_depth, dcfg.max_depth)
            acc.add(pts, mount, (hi - lo) / 2)  # compile/warm
            rows[key].append(cpu_ms(lambda: (acc.reset(), acc.add(pts, mount, (hi - lo) / 2))))
        rows["kos3_numpy_planes"].append(cpu_ms(lambda: kos_numpy(planes.points, mount, KosConfig(), b), repeat=2))
        rows["d2l"].append(cpu_ms(lambda: depthimage_to_laserscan(d, cam)))
        rows["n_planes"].append(len(planes.points))
        rows["n_depth"].append(len(allpts))

    def stat(k):
        v = np.array(rows[k], float)
        return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90))}

    res = {k: stat(k) for k in rows}
    res["per_added_level_ms"] = (res["kos3_planes"]["median"] - res["kos1_planes"]["median"]) / 2
    res["machine"] = {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                      "frames": len(data), "pinning": pin, "load_average": os.getloadavg()}
    base = res["d2l"]["median"]
    lines = ["# KOS benchmark", "",
             f"{len(data)} simulated Kinect v2 frames (office world, 512×424, noisy), {pin}, load average "
             f"{os.getloadavg()[0]:.1f} (a shared machine); CPU ms per frame, best of 5 runs "
             f"per frame, median and p90 over frames. Targets (issue 5): 3 levels ≤ {TARGET_3_LEVELS_MS} ms, "
             f"each added level ≤ {TARGET_PER_LEVEL_MS} ms.", "",
             "| method | input points (median) | median ms | p90 ms | × depthimage_to_laserscan |", "|---|---:|---:|---:|---:|"]
    names = {"kos1_planes": ("KOS numba, 1 level, FSPF+ points", "n_planes"),
             "kos3_planes": ("KOS numba, 3 levels + obstacle, FSPF+ points", "n_planes"),
             "kos3_depth": ("KOS numba, 3 levels + obstacle, all valid depth points", "n_depth"),
             "kos3_numpy_planes": ("KOS numpy (`np.minimum.at`), 3 levels + obstacle, FSPF+ points", "n_planes"),
             "d2l": ("depthimage_to_laserscan (numpy, 11 centre rows)", None)}
    for k, (label, n) in names.items():
        pts = f"{int(np.median(rows[n]))}" if n else "11 rows"
        lines.append(f"| {label} | {pts} | {res[k]['median']:.3f} | {res[k]['p90']:.3f} | {res[k]['median'] / base:.1f} |")
    lines += ["", f"Each added level: {res['per_added_level_ms']:.3f} ms (3 levels − 1 level, halved)."]
    out = REPO / "docs" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    (out / "kos.json").write_text(json.dumps(res, indent=2))
    (out / "kos.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
