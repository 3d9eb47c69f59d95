"""Benchmark: KOS SLAM on simulated office logs with and without the gyro, several seeds and depth rates.

    .venv/bin/python -m kosmap.tools.bench_kos_slam LOG.mcap [LOG.mcap …] [--rates 10 5] [--laser] [--cache DIR] [--out docs]
    .venv/bin/python -m kosmap.tools.bench_kos_slam --harsh [--laser]      # the harsh-odometry office and corridors

Per log, the depth frames go through FSPF+ and KOS once (at the highest rate asked) and the SLAM inputs are
recorded: every call the run makes to mapping.slamfeed.SlamFeed (odometry, KOS scans, IMU samples, and when log
time advanced), pickled in --cache keyed by the log's path, size and mtime. Each SLAM configuration then replays
them into a fresh Slam in seconds, feeding exactly what `kosmap slam --source kos` feeds. A lower depth rate keeps
every scan at least 1/rate after the previous kept one (KosStream's min_period does the same on frames).
Configurations: the defaults with the log's IMU; the same with the odometry scale and gyro bias estimated only in the
final solve (not fed back to the front end while running); without the IMU; with the IMU but the odometry scale
fixed; with the IMU but the gyro bias left in the noise. Truths (odometry distance scale, gyro turn-on bias) come from the simulator's
MCAP metadata (tools.simulate.log.simulation_truth). `--laser` also runs laser SLAM on logs that have a laser.
`--harsh` adds (simulated once into --cache) the office and the long-corridor world (tools/simulate/worlds/corridors.yaml)
with harsh but ordinary wheel odometry: 2 % and 2.8 % wheel radius errors and a 0.3°/m heading bias (HARSH), for
each of --seeds. The default KOS front end is held to the wheels along-track only where the scan's own surfaces
leave that direction open (backend/kosprofile.py); `--configs ... "imu, held along-track always"` also replays it held
always (it repeats the wheels' scale along the corridors, see docs/benchmarks.md), "imu, along-track free, prior 100"
free with a weaker pull towards the odometry. `--kos-nearest surface point` records the KOS scans a second time with
each bin's nearest point (the thesis's rule) instead of the mean of its nearest surface's points (the default;
frontend/kos.py) and replays them too.
Writes docs/bench/kos_slam.md and docs/bench/kos_slam.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import pickle
import platform
import time
from pathlib import Path

import numpy as np

from kosmap.tools.data import REPO

CONFIGS = {
    "imu": {},
    "imu, calibrated at the end only": {"calibrate_every": 0},
    "no imu": {"imu": False},
    "imu, scale fixed": {"odom_scale": "fixed"},
    "imu, bias fixed": {"gyro_bias": "fixed"},
    # not the default, measured beside it: the KOS front end held along-track to the odometry always (no scan-geometry
    # rule, a pull of 1000) instead of only where the scan's own surfaces leave that direction open (backend/kosprofile.py
    # KOS_FRONTEND: degeneracy_prior of frontend/odometry.py, a pull of 300), or free with a pull of 100; the key
    # "odometry" holds [odometry] overrides
    "imu, held along-track always": {"odometry": {"prior_weight_along": 1000.0, "degenerate_ratio": 0.0}},
    "imu, along-track free, prior 100": {"odometry": {"prior_weight_along": 100.0, "degenerate_ratio": 0.1}},
}


HARSH = {"odom_scale_error_left": 0.02, "odom_scale_error_right": 0.028, "odom_heading_bias_deg_per_m": 0.3,
         "depth_rate": 10.0}
HARSH_WORLDS = {"office": "office", "corridors": str(REPO / "tools" / "simulate" / "worlds" / "corridors.yaml")}


def harsh_logs(cache: Path, seed: int = 0) -> list[Path]:
    """The office and the long-corridor world with HARSH odometry, simulated into `cache` unless already there."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    cache.mkdir(parents=True, exist_ok=True)
    out = []
    for name, world in HARSH_WORLDS.items():
        log = cache / f"harsh-{name}-{seed}.mcap"
        if not log.exists():
            simulate(load_world(world), SimConfig(seed=seed, **HARSH), log)
        out.append(log)
    return out


def _key(log: Path, rate: float, nearest: str = "surface") -> str:
    st = log.stat()
    kos = f"|{nearest}"
    return hashlib.sha1(f"{log.resolve()}|{st.st_size}|{st.st_mtime_ns}|{rate}{kos}".encode()).hexdigest()[:16]


def record(log: Path, rate: float, cache: Path, nearest: str = "surface") -> dict:
    """The SlamFeed calls of a KOS run of `log` at `rate` Hz (cached), its ground truth and the default run's ATE;
    `nearest`: [kos] nearest, what a KOS bin keeps (frontend/kos.py)."""
    path = cache / f"{log.stem}-{_key(log, rate, nearest)}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    from kosmap.mapping import slam as S
    from kosmap.mapping.config import Config

    events: list = []
    real = S.SlamFeed  # the feed run_slam makes

    class Recorder(real):
        def odom(self, rec):
            events.append(("o", rec.stamp_ns, rec.x, rec.y, rec.yaw))
            super().odom(rec)

        def imu(self, rec):
            if rec.has_angular_velocity:
                events.append(("i", rec.stamp_ns, rec.yaw_rate))
            super().imu(rec)

        def push(self, stamp_ns, pts, deskew=None):
            # as given (float64): float32 copies made the replay diverge from the run it recorded (the survey: 0.76 m
            # replayed against 0.36 m run); the build's own feed recorded as given replayed exactly (0.2177 m both)
            events.append(("p", int(stamp_ns), np.array(pts)))
            super().push(stamp_ns, pts, deskew)

        def advance(self, now):
            if not events or events[-1] != ("a", now):
                events.append(("a", now))
            super().advance(now)

    cfg = Config()
    cfg.build.depth_rate = rate
    cfg.kos.nearest = nearest
    t0 = time.perf_counter()
    S.SlamFeed = Recorder
    try:
        r = S.run_slam(log, cfg, source="kos")
    finally:
        S.SlamFeed = real
    doc = {"events": events, "gt": r.ground_truth, "kos_seconds": time.perf_counter() - t0,
           "ate_full_run": S.evaluate(r)["ate"]["rmse"]}
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".partial")
    tmp.write_bytes(pickle.dumps(doc))
    os.replace(tmp, path)
    return doc


def replay_slam(doc: dict, rate: float, odometry: dict | None = None, **graph):
    """KOS SLAM on recorded inputs with [odometry] and [graph] overrides (over the KOS defaults): the finished
    SlamResult (its ground truth set from the recording) and the seconds the replay took."""
    from kosmap.frontend.records import Odometry
    from kosmap.backend.kosprofile import kos_graph_config, kos_odometry_config
    from kosmap.backend.slam import Slam
    from kosmap.mapping.config import Config
    from kosmap.mapping.slamfeed import SlamFeed

    cfg = Config()
    cfg.build.depth_rate = rate
    gcfg = dataclasses.replace(kos_graph_config(cfg), **graph)
    slam = Slam(dataclasses.replace(kos_odometry_config(cfg), **(odometry or {})), gcfg, map_cell=cfg.grid.resolution)
    has_imu = any(e[0] == "i" for e in doc["events"])
    feed = SlamFeed(slam, True, has_imu)
    period = int(1e9 / rate) - 10_000_000 if rate > 0 else 0
    last = None
    t0 = time.perf_counter()
    for ev in doc["events"]:
        if ev[0] == "o":
            feed.odom(Odometry(ev[1], ev[2], ev[3], ev[4]))
        elif ev[0] == "i":
            if feed.use_imu:
                slam.add_imu(ev[1], ev[2])
        elif ev[0] == "p":
            if last is None or ev[1] - last >= period:
                feed.push(ev[1], ev[2])
                last = ev[1]
        else:
            feed.advance(ev[1])
    feed.advance(None)
    r = slam.finish()
    r.ground_truth = doc["gt"]
    return r, time.perf_counter() - t0


def replay(doc: dict, rate: float, odometry: dict | None = None, **graph) -> dict:
    """SLAM on recorded inputs with [odometry] and [graph] overrides (over the KOS defaults); accuracy and calibration."""
    from kosmap.mapping import slam as S

    r, secs = replay_slam(doc, rate, odometry, **graph)
    m = S.evaluate(r)
    s = S.summary(r)
    return {"ate": m["ate"]["rmse"], "ate_max": m["ate"]["max"], "ate_odometry": m.get("ate_odometry", {}).get("rmse"),
            "odometry_scale": s["odometry_scale"], "gyro_bias_deg_s": s["gyro_bias_deg_s"], "loops": s["loops"],
            "keyframes": s["keyframes"], "gyro_factors": s["imu"]["factors"], "slam_seconds": secs,
            "duration_s": r.duration_s, "warnings": s["warnings"]}


def laser(log: Path, imu: bool) -> dict:
    from kosmap.mapping import slam as S
    from kosmap.mapping.config import Config

    cfg = Config()
    cfg.graph.imu = imu
    t0 = time.perf_counter()
    r = S.run_slam(log, cfg, source="laser")
    secs = time.perf_counter() - t0
    m = S.evaluate(r)
    s = S.summary(r)
    return {"ate": m["ate"]["rmse"], "ate_max": m["ate"]["max"], "odometry_scale": s["odometry_scale"],
            "gyro_bias_deg_s": s["gyro_bias_deg_s"], "loops": s["loops"], "seconds": secs,
            "realtime_factor": r.duration_s / secs}


def _truth(log: Path) -> dict:
    from kosmap.tools.simulate.log import simulation_truth

    t = simulation_truth(log) or {}
    tr = t.get("truth", {})
    c = t.get("config", {})
    bias = (tr.get("imu") or {}).get("gyro_bias_initial_dps")
    return {"seed": c.get("seed"), "rear_camera": c.get("rear_camera", False),
            "odometry_scale": (tr.get("odometry") or {}).get("distance_scale"),
            "gyro_bias_deg_s": bias[2] if isinstance(bias, list) else bias, "imu": tr.get("imu") is not None}


def _f(v, fmt="{:.3f}") -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def markdown(res: list[dict], lasers: list[dict], meta: dict) -> str:
    out = ["# KOS SLAM with a gyro: simulated office", "",
           f"{meta['date']}, {meta['machine']}, {meta['cores']} cores, load {meta['load']}. Generated by "
           "`tools/bench_kos_slam.py` (the method is in its docstring). One front Kinect (or front + rear), wheel "
           "odometry, and the simulator's /imu; ATE RMSE against the log's ground truth, after SE(2) alignment. "
           "Scale: the wheel odometry's distance scale the graph estimated vs the simulator's truth. "
           "SLAM seconds: the replay of recorded KOS scans (FSPF+ and KOS are not in them).", "",
           "| log | seed | cameras | depth Hz | config | ATE m | ATE max m | odometry ATE m | scale | true scale | scale error % "
           "| gyro bias °/s | true bias °/s | loops | SLAM s |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in res:
        t = r["truth"]
        err = (100 * (r["odometry_scale"] - t["odometry_scale"]) / t["odometry_scale"]
               if r["odometry_scale"] is not None and t["odometry_scale"] else None)
        out.append(f"| {r['log']} | {_f(t['seed'], '{}')} | {'front + rear' if t['rear_camera'] else 'front'} | {r['rate']:g} | "
                   f"{r['config']} | {_f(r['ate'])} | {_f(r['ate_max'])} | {_f(r['ate_odometry'])} | "
                   f"{_f(r['odometry_scale'], '{:.4f}')} | {_f(t['odometry_scale'], '{:.4f}')} | {_f(err, '{:+.2f}')} | "
                   f"{_f(r['gyro_bias_deg_s'], '{:+.4f}')} | {_f(t['gyro_bias_deg_s'], '{:+.4f}')} | {r['loops']} | "
                   f"{r['slam_seconds']:.1f} |")
    if lasers:
        out += ["", "Laser SLAM (Hokuyo-like 270°, 30 m) on the same logs, whole run from the log file:", "",
                "| log | IMU | ATE m | ATE max m | scale | gyro bias °/s | loops | seconds | × real time |", "|---|---|---|---|---|---|---|---|---|"]
        for r in lasers:
            out.append(f"| {r['log']} | {'yes' if r['imu'] else 'no'} | {_f(r['ate'])} | {_f(r['ate_max'])} | "
                       f"{_f(r['odometry_scale'], '{:.4f}')} | {_f(r['gyro_bias_deg_s'], '{:+.4f}')} | {r['loops']} | "
                       f"{r['seconds']:.0f} | {r['realtime_factor']:.0f} |")
    ok = [r for r in res if r["config"] == "imu" and not r["truth"]["rear_camera"] and r["rate"] == max(x["rate"] for x in res)]
    if ok:
        worst = max(r["ate"] for r in ok)
        serr = [abs(r["odometry_scale"] / r["truth"]["odometry_scale"] - 1) * 100 for r in ok
                if r["odometry_scale"] is not None and r["truth"]["odometry_scale"]]
        out += ["", f"Acceptance (one front camera + IMU, {ok[0]['rate']:g} Hz, {len(ok)} seeds): worst ATE {worst:.3f} m "
                f"(goal ≤ 0.10 m); scale error {', '.join(f'{e:.2f}' for e in serr)} % (goal ≤ 0.2 %)."]
    if any(r["log"].startswith("harsh-corridors") for r in res):
        out += ["", "The long-corridor world (harsh-corridors): its KOS error is the wheel odometry's scale, not a missing "
                "loop. A ring closes whatever its scale, so loops cannot observe it; a narrow scan sees along a bare "
                "corridor only at corners and rooms. Held along-track to the wheels always (`held along-track always`), the "
                "front end's matches repeat the scale it was given and the graph's estimate stays near it (compare "
                "`scale` with `true scale`). Held only where the scan's own surfaces leave that direction open "
                "(the default), the corners and rooms measure the scale in the corridors; in the plain office the "
                "free matches come out a little short and the scale ~0.3 % too large."]
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--harsh", action="store_true", help="also the office and the corridor world with harsh wheel odometry")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="simulator seeds of the --harsh logs")
    ap.add_argument("--rates", nargs="+", type=float, default=[10.0, 5.0])
    ap.add_argument("--configs", nargs="+", default=[c for c in CONFIGS if "odometry" not in CONFIGS[c]], choices=list(CONFIGS))
    ap.add_argument("--kos-nearest", nargs="+", default=["surface"], choices=["point", "surface"],
                    help="what a KOS bin keeps ([kos] nearest); 'surface point' replays the nearest point (thesis) too")
    ap.add_argument("--laser", action="store_true", help="also laser SLAM (with and without the IMU) on logs with a laser")
    ap.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "kosmap-bench-kos-slam")
    ap.add_argument("--out", type=Path, default=REPO / "docs")
    a = ap.parse_args()
    if a.harsh:
        a.logs = list(a.logs) + [log for seed in a.seeds for log in harsh_logs(a.cache, seed)]
    if not a.logs:
        ap.error("give a log or --harsh")
    res, lasers = [], []
    top = max(a.rates)
    for log in a.logs:
        truth = _truth(log)
        for nearest in a.kos_nearest:
            doc = record(log, top, a.cache, nearest)
            print(f"{log.name}: KOS scans ({nearest}) recorded ({doc['kos_seconds']:.0f} s; full run ATE "
                  f"{doc['ate_full_run']:.3f} m)", flush=True)
            for rate in a.rates:
                for name in a.configs:
                    label = name if nearest == "surface" else f"{name}, KOS nearest point"
                    r = replay(doc, rate, **CONFIGS[name])
                    r.update(log=log.name, rate=rate, config=label, truth=truth)
                    res.append(r)
                    print(f"  {rate:g} Hz {label:>31}: ATE {r['ate']:.3f} m, scale {_f(r['odometry_scale'], '{:.4f}')} "
                          f"(truth {_f(truth['odometry_scale'], '{:.4f}')}), bias {_f(r['gyro_bias_deg_s'], '{:+.4f}')} "
                          f"°/s, {r['slam_seconds']:.1f} s", flush=True)
        if a.laser:
            from kosmap.frontend.logs import detect_topics, open_log
            from kosmap.mapping.config import Config

            with open_log(log) as lg:
                has_laser = bool(detect_topics(lg.info().types(), Config().topics).scan)
            for imu in (True, False):
                if has_laser:
                    r = laser(log, imu)
                    r.update(log=log.name, imu=imu)
                    lasers.append(r)
                    print(f"  laser imu={imu}: ATE {r['ate']:.3f} m, {r['realtime_factor']:.0f}× real time", flush=True)
    meta = {"date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.machine(), "cores": os.cpu_count(),
            "load": " ".join(f"{x:.1f}" for x in os.getloadavg())}
    from kosmap.mapping.jsonsafe import json_safe

    (a.out / "bench").mkdir(parents=True, exist_ok=True)
    (a.out / "bench" / "kos_slam.json").write_text(json.dumps(json_safe({"meta": meta, "results": res, "laser": lasers}), indent=2))
    (a.out / "bench" / "kos_slam.md").write_text(markdown(res, lasers, meta))
    print(f"wrote {a.out / 'bench' / 'kos_slam.md'}")


if __name__ == "__main__":
    main()
