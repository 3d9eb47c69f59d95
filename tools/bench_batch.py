"""Benchmark: what a fleet's logs cost to map, per hour of log: CPU seconds, wall time, and bytes (the logs, and
each kind of output), for `kosmap batch` against the same logs built one after another by `kosmap build`.

    .venv/bin/python -m kosmap.tools.bench_batch [--minutes 2] [--logs 2] [--laser]
    .venv/bin/python -m kosmap.tools.bench_batch --logs 0 --laser    # only the laser logs, beside the last fleet run

The logs are `kosmap simulate office` with the simulator's default rates (Kinect 512×424 at 30 Hz, laser 40 Hz,
zstd MCAP), each from another seed and start on the office's 140 m path, cached under .kosmap-cache/bench/batch/.
The baseline is each log through `kosmap build` in turn (its default processes); the peer is one `kosmap batch` of
all of them on its default local cluster, in the same run. CPU seconds are those of every process of a command
(its children's included, as the kernel accounts them once they end). `--laser` adds the public laser-only logs
(CARMEN / ROS 1 bags under ../shared/data/laser), built one by one: a laser-only robot's cost per hour.
Writes docs/bench/batch.json and docs/bench/batch.md (docs/scale.md reads its numbers from there).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

from kosmap.tools.benchutil import cpu_model
from kosmap.tools.data import REPO, data_dir

CACHE = REPO / ".kosmap-cache" / "bench" / "batch"
OUT = REPO / "docs" / "bench"
KINDS = {  # where a build's bytes go: file name patterns, first match wins
    "kosmap.mcap (scans, plane points, paths, maps for Foxglove)": ("kosmap.mcap",),
    "maps (map_server PGM + YAML, PNG)": ("map_*",),
    "report (HTML with embedded figures, Markdown, figures)": ("report.*", "summary.png", "frames.png",
                                                               "trajectories.png", "overlay_*"),
    "trajectories, stats.csv, metrics.json, config": ("*.tum", "stats.csv", "metrics.json", "config.toml",
                                                      ".kosmap-outputs"),
}


def office_logs(n: int, minutes: float) -> tuple[list[Path], Path]:
    """n office logs of this length (seeds 0..n-1, each starting further along the path), and the blueprint."""
    import numpy as np

    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate
    from kosmap.tools.simulate.world import PathSpec

    world = load_world("office")
    CACHE.mkdir(parents=True, exist_ok=True)
    bp = CACHE / "office_blueprint.yaml"
    if not bp.is_file():
        write_map_server(world.blueprint(0.05), bp, ".png")
    logs = []
    way = np.asarray(world.path.waypoints, float)
    for k in range(n):
        log = CACHE / f"office_{minutes:g}min_{k}.mcap"
        if not log.is_file():
            s = 2 * k % (len(way) - 1)  # each robot starts at another waypoint of the loop
            ring = np.vstack([way[s:], way[1:], way[1:s + 1]])
            yaw = float(np.arctan2(*(ring[1] - ring[0])[::-1]))
            t0 = time.perf_counter()
            simulate(world, SimConfig(seed=k, duration=60.0 * minutes), log, PathSpec(ring, yaw))
            print(f"simulated {log.name} in {time.perf_counter() - t0:.0f} s", flush=True)
        logs.append(log)
    return logs, bp


def timed(cmd: list[str]) -> dict:
    """Run a kosmap command in a child process: wall seconds and the CPU seconds of it and all it started."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "kosmap.tools.cli", *cmd], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd[:2])} failed ({p.returncode}): {p.stderr.strip()[-500:]}")
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "load_avg_1min": [load0, os.getloadavg()[0]], "exit": p.returncode}


def bytes_by_kind(folder: Path) -> dict[str, int]:
    out = {k: 0 for k in KINDS}
    out["other"] = 0
    for p in folder.iterdir():
        if not p.is_file():
            continue
        kind = next((k for k, pats in KINDS.items() if any(p.match(x) for x in pats)), "other")
        out[kind] += p.stat().st_size
    return out


def log_seconds(folder: Path) -> float:
    return float(json.loads((folder / "metrics.json").read_text())["log"]["duration_s"])


def fleet(minutes: float, n: int, work: Path) -> dict:
    """Baseline (build one by one) and peer (one batch) on the office logs."""
    logs, bp = office_logs(n, minutes)
    seq = []
    for log in logs:
        out = work / "builds" / log.stem
        seq.append(timed(["build", str(log), "--out", str(out), "--blueprint", str(bp), "--quiet"]))
        seq[-1]["log_s"] = log_seconds(out)
        seq[-1]["bytes"] = bytes_by_kind(out)
        seq[-1]["log_bytes"] = log.stat().st_size
    batch_out = work / "batch"
    bt = timed(["batch", *map(str, logs), "--out", str(batch_out), "--blueprint", str(bp), "--quiet"])
    doc = json.loads((batch_out / "batch.json").read_text())
    bt["cluster"] = doc["cluster"]["where"]
    bt["fleet_bytes"] = sum(p.stat().st_size for p in batch_out.iterdir() if p.is_file())
    rerun = timed(["batch", *map(str, logs), "--out", str(batch_out), "--blueprint", str(bp), "--quiet"])
    return {"logs": [str(p.name) for p in logs], "minutes": minutes, "builds": seq, "batch": bt, "rerun": rerun,
            "merged_f1": doc["fleet"].get("merged", {}).get("f1"),
            "single_f1": [r["f1"].get(doc["fleet"]["map"]) for r in doc["logs"]]}


def laser_logs(work: Path) -> list[dict]:
    """The public laser-only logs, each built once."""
    rows = []
    for log in sorted(p for p in (data_dir() / "laser").glob("*/*") if p.suffix in (".clf", ".bag")):
        out = work / "laser" / log.stem
        r = timed(["build", str(log), "--out", str(out), "--quiet"])
        r.update(name=log.name, log_s=log_seconds(out), bytes=bytes_by_kind(out), log_bytes=log.stat().st_size)
        rows.append(r)
    return rows


def per_hour(rows: list[dict]) -> dict:
    h = sum(r["log_s"] for r in rows) / 3600.0
    kinds: dict[str, float] = {}
    for r in rows:
        for k, v in r["bytes"].items():
            kinds[k] = kinds.get(k, 0.0) + v / h
    return {"log_hours": h, "cpu_s_per_hour": sum(r["cpu_s"] for r in rows) / h,
            "wall_s_per_hour": sum(r["wall_s"] for r in rows) / h,
            "log_bytes_per_hour": sum(r["log_bytes"] for r in rows) / h, "output_bytes_per_hour": kinds}


def markdown(res: dict) -> str:
    f = res["fleet"]
    b, seq = f["batch"], per_hour(f["builds"])
    h = seq["log_hours"]
    L = ["# What a fleet's logs cost: `kosmap batch` per hour of log", "",
         f"`python -m kosmap.tools.bench_batch --minutes {f['minutes']:g} --logs {len(f['logs'])}`: "
         f"{len(f['logs'])} simulated office logs of {f['minutes']:g} min (Kinect 512×424 at 30 Hz, laser at 40 Hz, "
         f"wheel odometry, IMU; zstd MCAP), each built by `kosmap build` in turn, then all by one `kosmap batch` "
         f"({b['cluster']}), with the blueprint. Machine: {res['machine']['cores']} cores ({res['machine']['cpu']}); "
         f"load average before/after each command in batch.json (the machine is shared).", "",
         "| per hour of log | `kosmap build` one by one | `kosmap batch` | ratio batch / builds |", "|---|---|---|---|",
         f"| CPU s | {seq['cpu_s_per_hour']:.0f} | {b['cpu_s'] / h:.0f} | {b['cpu_s'] / h / seq['cpu_s_per_hour']:.2f} |",
         f"| wall s | {seq['wall_s_per_hour']:.0f} | {b['wall_s'] / h:.0f} | {b['wall_s'] / h / seq['wall_s_per_hour']:.2f} |",
         "", f"A re-run with nothing changed: {res['fleet']['rerun']['wall_s']:.1f} s wall, "
             f"{res['fleet']['rerun']['cpu_s']:.1f} CPU s (hashing the logs and outputs, starting the cluster). "
             f"Merged map F1 {f['merged_f1'] or 0:.3f} against the blueprint; single runs "
             + ", ".join(f"{x:.3f}" for x in f["single_f1"] if x is not None) + ".", "",
         "Bytes per hour of log:", "", "| what | MB per hour of log |", "|---|---|",
         f"| the log (input) | {seq['log_bytes_per_hour'] / 1e6:.0f} |"]
    L += [f"| {k} | {v / 1e6:.1f} |" for k, v in seq["output_bytes_per_hour"].items() if v]
    L += [f"| the batch's own files (merged and change maps, batch.*), once per batch | {b['fleet_bytes'] / 1e6:.1f} MB |"]
    if res.get("laser"):
        lp = per_hour(res["laser"])
        L += ["", "Laser-only robots (the public CARMEN / ROS 1 logs, `kosmap build` each):", "",
              "| log | log min | CPU s | CPU s per hour of log | log MB per hour | output MB per hour |", "|---|---|---|---|---|---|"]
        for r in res["laser"]:
            hh = r["log_s"] / 3600
            L.append(f"| {r['name']} | {r['log_s'] / 60:.1f} | {r['cpu_s']:.1f} | {r['cpu_s'] / hh:.0f} | "
                     f"{r['log_bytes'] / hh / 1e6:.1f} | {sum(r['bytes'].values()) / hh / 1e6:.1f} |")
        L.append(f"| all | {lp['log_hours'] * 60:.1f} | | {lp['cpu_s_per_hour']:.0f} | "
                 f"{lp['log_bytes_per_hour'] / 1e6:.1f} | {sum(lp['output_bytes_per_hour'].values()) / 1e6:.1f} |")
    return "\n".join(L) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=2.0)
    ap.add_argument("--logs", type=int, default=2, help="office logs (0: keep the last run's fleet results)")
    ap.add_argument("--laser", action="store_true")
    a = ap.parse_args()
    import tempfile

    prev = json.loads((OUT / "batch.json").read_text()) if (OUT / "batch.json").is_file() else {}
    with tempfile.TemporaryDirectory(prefix="kosmap-bench-batch-") as tmp:
        work = Path(tmp)
        res = {"machine": {"cores": len(os.sched_getaffinity(0)), "cpu": cpu_model(),
                           "python": platform.python_version()}}
        res["fleet"] = fleet(a.minutes, a.logs, work) if a.logs > 0 else prev["fleet"]  # --logs 0: keep the last
        if a.laser:
            res["laser"] = laser_logs(work)
    res["fleet"]["per_hour_builds"] = per_hour(res["fleet"]["builds"])
    if res.get("laser"):
        res["laser_per_hour"] = per_hour(res["laser"])
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "batch.json").write_text(json.dumps(res, indent=1) + "\n")
    md = markdown(res)
    (OUT / "batch.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
