"""Benchmark: the log simulator on one core: rendering methods, noise, laser, and a minute of the office log.

    .venv/bin/python -m kosmap.tools.bench_simulate [--frames 40] [--naive-frames 8] [--seconds 60]

Rendering: 512×424 Kinect v2 frames at poses spread along the office's bundled path, cast three ways —
the column method (one 2D ray per image column; valid for a camera without roll and pitch), the 3D cast
through angular bins (any orientation; what a pitched camera uses), and the baseline: every pixel in 3D
against every object within reach. The three must agree. End to end: `simulate()` of the office with the
default config (30 Hz depth, 40 Hz laser, 50 Hz odometry, 100 Hz ground truth, zstd chunks), timed by wall
clock and CPU. Writes docs/bench/simulate.json and simulate.md; ratios are against the naive cast measured
in the same run.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from kosmap.tools.data import REPO  # noqa: E402
from kosmap.tools.benchutil import pin_one_core  # noqa: E402
from kosmap.tools.simulate import SimConfig, load_world, simulate  # noqa: E402
from kosmap.tools.simulate.log import trajectory  # noqa: E402
from kosmap.tools.simulate.render import (LaserModel, camera_mount, kinect_v2_model, laser_mount,  # noqa: E402
                                   render_depth_geometry, render_laser_geometry)
from kosmap.tools.simulate.sensors import DepthNoise, LaserNoise, apply_laser_noise, depth_noise_mm  # noqa: E402



def _timed(fn):
    """(result, CPU ms of this thread, wall ms)."""
    c0, w0 = time.thread_time(), time.perf_counter()
    out = fn()
    return out, (time.thread_time() - c0) * 1e3, (time.perf_counter() - w0) * 1e3


def _stats(cpu: list[float], wall: list[float]) -> dict:
    a, w = np.asarray(cpu), np.asarray(wall)
    return {"median_ms": float(np.median(a)), "p90_ms": float(np.percentile(a, 90)),
            "wall_median_ms": float(np.median(w)), "n": len(a)}


def bench_render(world, poses, mount, model, methods, n_naive: int) -> dict:
    out, ref = {}, {}
    for method in methods:
        render_depth_geometry(world, poses[0], mount, model, method=method)  # compile / warm caches
        cpu, wall, worst, mism = [], [], 0.0, 0
        use = poses if method != "naive" else poses[:n_naive]
        for i, p in enumerate(use):
            (z, sid, _), c, w = _timed(lambda p=p: render_depth_geometry(world, p, mount, model, method=method))
            cpu.append(c)
            wall.append(w)
            if i in ref:
                worst = max(worst, float(np.max(np.abs(np.asarray(z) - ref[i][0]))))
                mism += int(np.count_nonzero(np.asarray(sid) != ref[i][1]))
            else:
                ref[i] = (np.asarray(z).copy(), np.asarray(sid).copy())
        out[method] = _stats(cpu, wall) | {"max_abs_diff_m": worst, "id_mismatches": mism}
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--naive-frames", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "bench")
    args = ap.parse_args(argv)
    pin = pin_one_core()
    world = load_world("office")
    cfg = SimConfig()
    traj = trajectory(world, cfg)
    times = np.linspace(0.0, traj.duration, args.frames, endpoint=False)
    poses = [traj.pose(t)[0] for t in times]
    model = kinect_v2_model()
    level, pitched = camera_mount(), camera_mount(rpy=(0.0, math.radians(15), 0.0))
    res: dict = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                             "cores": os.cpu_count(), "affinity": pin},
                 "world": {"name": world.name, "solids": len(world.solids), "surfaces": len(world.surfaces),
                           "path_s": traj.duration, "path_m": traj.distance}}
    print(f"office: {len(world.solids)} solids, {len(world.surfaces)} surfaces; {pin}")
    res["render_level"] = bench_render(world, poses, level, model, ("column", "pixels", "naive"), args.naive_frames)
    res["render_pitched_15deg"] = bench_render(world, poses, pitched, model, ("pixels", "naive"), args.naive_frames)
    for k in ("render_level", "render_pitched_15deg"):
        for m, v in res[k].items():
            print(f"{k:22} {m:7} {v['median_ms']:8.2f} ms/frame (p90 {v['p90_ms']:.2f})  max|Δ| {v['max_abs_diff_m']:.1e} m"
                  f"  id mismatches {v['id_mismatches']}")
    # noise and laser
    noise, rng = DepthNoise(), np.random.default_rng(0)
    geo = [render_depth_geometry(world, p, level, model) for p in poses[:10]]
    depth_noise_mm(*geo[0], noise, rng)  # warm
    cpu, wall = [], []
    for z, sid, cs in geo:
        _, c, w = _timed(lambda z=z, sid=sid, cs=cs: depth_noise_mm(z, sid, cs, noise, rng))
        cpu.append(c)
        wall.append(w)
    res["depth_noise"] = _stats(cpu, wall)
    lm, L, ln = laser_mount(), LaserModel(), LaserNoise()
    beam_dt = L.scan_time * L.angle_increment / (2 * math.pi)
    cpu, wall = [], []
    for t in times:
        def scan(t=t):
            r, _, cs = render_laser_geometry(world, traj.pose(t + np.arange(L.beams) * beam_dt), lm, L)
            return apply_laser_noise(r, cs, ln, L.range_min, L.range_max, rng)
        scan()
        _, c, w = _timed(scan)
        cpu.append(c)
        wall.append(w)
    res["laser_scan"] = _stats(cpu, wall)
    print(f"depth noise {res['depth_noise']['median_ms']:.2f} ms/frame, laser {res['laser_scan']['median_ms']:.2f} ms/scan")
    # end to end
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        simulate(world, SimConfig(duration=1.0), Path(tmp) / "warm.mcap")
        for name, c in (("default (zstd)", SimConfig(duration=args.seconds)),
                        ("lz4 chunks", SimConfig(duration=args.seconds, compression="lz4")),
                        ("front + rear camera, surface ids", SimConfig(duration=args.seconds / 3, rear_camera=True,
                                                                       surface_ids=True))):
            s = simulate(world, c, Path(tmp) / "log.mcap")
            cpu_s = s["cpu_s"]
            runs[name] = {"simulated_s": s["duration_s"], "wall_s": s["wall_s"], "cpu_s": cpu_s,
                          "real_time_factor": s["real_time_factor"], "cpu_real_time_factor": s["duration_s"] / cpu_s,
                          "mb": s["bytes"] / 1e6, "depth_frames": s["depth_frames"], "scans": s["scans"],
                          "timing_cpu_s": s["timing_cpu_s"], "distance_m": s["distance_m"], "odom_drift_m": s["odom_drift_m"]}
            print(f"{name:34} {s['duration_s']:.0f} s simulated in {s['wall_s']:.1f} s wall / {cpu_s:.1f} s CPU "
                  f"({s['real_time_factor']:.2f}× real time), {s['bytes'] / 1e6:.0f} MB")
    res["end_to_end"] = runs
    # what the naive cast would cost end to end (its render time in place of the column method's)
    lv = res["render_level"]
    d = runs["default (zstd)"]
    naive_extra = d["depth_frames"] * (lv["naive"]["median_ms"] - lv["column"]["median_ms"]) / 1e3
    res["naive_end_to_end_estimate_s"] = d["cpu_s"] + naive_extra
    res["ratios"] = {"naive_over_column": lv["naive"]["median_ms"] / lv["column"]["median_ms"],
                     "naive_over_binned_3d": lv["naive"]["median_ms"] / lv["pixels"]["median_ms"],
                     "binned_3d_over_column": lv["pixels"]["median_ms"] / lv["column"]["median_ms"],
                     "pitched_naive_over_binned": res["render_pitched_15deg"]["naive"]["median_ms"]
                     / res["render_pitched_15deg"]["pixels"]["median_ms"]}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "simulate.json").write_text(json.dumps(res, indent=2))
    (args.out / "simulate.md").write_text(markdown(res, args))
    print(f"wrote {args.out / 'simulate.json'} and simulate.md")
    return res


def markdown(r: dict, args) -> str:
    m = r["machine"]
    lines = ["# Simulator benchmark (tools/bench_simulate.py)", "",
             f"Python {m['python']}, {m['cores']} cores, {m['affinity']}; office world: {r['world']['solids']} solids, "
             f"{r['world']['surfaces']} surfaces; frames at {args.frames} poses spread over its "
             f"{r['world']['path_m']:.0f} m path (naive: the first {args.naive_frames}). CPU ms of this thread "
             "(wall clock in brackets; the machine is shared, so wall time is noisier).", "",
             "## Depth rendering, 512×424, exact geometry", "",
             "| camera | method | ms/frame (median) | p90 | wall | max abs diff vs first method | id mismatches |",
             "|---|---|---|---|---|---|---|"]
    names = {"column": "column (2D ray per column)", "pixels": "3D through angular bins", "naive": "naive 3D (baseline)"}
    for k, cam in (("render_level", "level, 1.0 m"), ("render_pitched_15deg", "pitched 15° down")):
        for meth, v in r[k].items():
            lines.append(f"| {cam} | {names[meth]} | {v['median_ms']:.2f} | {v['p90_ms']:.2f} | ({v['wall_median_ms']:.2f}) "
                         f"| {v['max_abs_diff_m']:.1e} m | {v['id_mismatches']} |")
    ra = r["ratios"]
    lines += ["", f"Naive / column: **{ra['naive_over_column']:.0f}×**; naive / binned 3D: {ra['naive_over_binned_3d']:.0f}× "
              f"(pitched: {ra['pitched_naive_over_binned']:.0f}×); binned 3D / column: {ra['binned_3d_over_column']:.1f}×.",
              "", "## Per frame / scan", "",
              f"- Kinect v2 noise (flying pixels, σ(z, θ), dropouts, mm): {r['depth_noise']['median_ms']:.2f} ms/frame",
              f"- Hokuyo scan (1081 beams, a pose per beam, noise): {r['laser_scan']['median_ms']:.2f} ms/scan", "",
              "## End to end: `simulate()` on the office", "",
              "| run | simulated | wall | CPU | real-time factor (wall) | (CPU) | size | CPU s: render / noise / laser / write |",
              "|---|---|---|---|---|---|---|---|"]
    for name, v in r["end_to_end"].items():
        t = v["timing_cpu_s"]
        lines.append(f"| {name} | {v['simulated_s']:.0f} s | {v['wall_s']:.1f} s | {v['cpu_s']:.1f} s | "
                     f"{v['real_time_factor']:.2f}× | {v['cpu_real_time_factor']:.2f}× | {v['mb']:.0f} MB | "
                     f"{t['render_depth']:.1f} / {t['depth_noise']:.1f} / {t['render_laser']:.1f} / {t['write']:.1f} |")
    lines += ["", f"With the naive cast in place of the column method the default minute would take about "
              f"{r['naive_end_to_end_estimate_s']:.0f} s of CPU.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
