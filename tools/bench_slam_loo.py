"""Benchmark: the laser SLAM's held-out protocol. Leave-one-out on the three relation logs (Intel, FR079, MIT CSAIL):
for each log the setting is chosen among a few candidates on the other two logs only, and the left-out log's score
under that choice is reported beside Cartographer's published one. Then every unscored real log
(../shared/data/laser/unscored, imported by tools/laserimport.py where kosmap has no reader) is mapped with the
default setting through `kosmap slam`, and its self-consistency figure (no ground truth) is reported, beside that of
the peer, yag-slam (OpenKarto, tools/peer_yag.py; the `bench` extra), on the same log.

    .venv/bin/python -m kosmap.tools.bench_slam_loo [--candidates default no-degeneracy ...] [--no-unscored]

Writes docs/bench/slam_loo.json and docs/bench/slam_loo.md (tools/bench_slam.py puts the table into
docs/benchmarks.md). A candidate's score on a set of logs is the mean of its abs translational error divided by
Cartographer's published error on each log (so no log dominates by its scale).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from kosmap.backend.metrics import read_relations
from kosmap.mapping.config import load_config
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.slam import evaluate, run_slam
from kosmap.tools.bench_slam import LOGS, PUBLISHED
from kosmap.tools import peer_yag
from kosmap.tools.data import REPO, data_dir

# The candidates: the default, and each of the rules added for buildings the tuning logs did not show turned off or
# back to the constant it replaced (the scan-geometry degeneracy prior, the drift-grown loop window, the loop
# acceptance score from the scan's noise, the odometry noise measured while running).
CANDIDATES: dict[str, dict] = {
    "default": {},
    "no-degeneracy": {"odometry.degenerate_ratio": 0.0},
    "fixed-loop-window": {"graph.loop_max_linear_window": 1.0},
    "fixed-loop-score": {"graph.loop_score": "fixed"},
    "fixed-odometry-noise": {"graph.odom_noise": "fixed"},
}

# The unscored logs: (folder/file, importer format or None when kosmap reads the file itself, what it is)
UNSCORED = [
    ("breezyslam_mines_exp1/exp1.dat", "breezyslam", "Mines ParisTech, URG-04LX 240°, BreezySLAM .dat"),
    ("breezyslam_mines_exp2/exp2.dat", "breezyslam", "Mines ParisTech, URG-04LX 240°, BreezySLAM .dat"),
    ("dpslam_duke_loop5/loop5.log", "dpslam", "Duke, SICK 180°, DP-SLAM text"),
    ("csm_laserazosSM3/laserazosSM3.log", "carmen", "laserazos, SICK 180°, CARMEN without times"),
    ("orebro_gfs/orebro.gfs.log", "carmen", "Örebro, SICK 180°, CARMEN/GFS without times"),
    ("btp_ros_rplidar/test.bag", None, "RPLidar 360°, ROS 1 bag, no odometry"),
]


def score_log(name: str, overrides: dict) -> dict:
    lp, rp, _ = LOGS[name]
    path = data_dir() / lp
    cfg = load_config(None, overrides)
    w0, c0 = time.perf_counter(), time.process_time()
    r = run_slam(path, cfg)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    ev = evaluate(r, read_relations(data_dir() / rp))
    return {"abs_trans": ev["relations"]["abs_trans"]["mean"], "abs_rot_deg": ev["relations"]["abs_rot_deg"]["mean"],
            "wall_s": wall, "cpu_s": cpu, "rt_wall": r.duration_s / wall, "rt_cpu": r.duration_s / cpu,
            "loops": len(r.loops)}


def _ratio(res: dict, cand: str, logs: list[str]) -> float:
    return sum(res[cand][n]["abs_trans"] / PUBLISHED[n]["cartographer"]["abs_trans"][0] for n in logs) / len(logs)


def leave_one_out(res: dict) -> dict:
    """For each log: the candidate best on the other logs, and the left-out log's score under it."""
    out = {}
    for held in LOGS:
        rest = [n for n in LOGS if n != held]
        pick = min(res, key=lambda c: _ratio(res, c, rest))
        out[held] = {"chosen": pick, "chosen_on": rest, "train_ratio": _ratio(res, pick, rest), **res[pick][held]}
    return out


def peer_unscored(log: Path) -> dict:
    """yag-slam on an unscored log: keyframes, loops, real-time factor and the same self-consistency figure."""
    why = peer_yag.unavailable()
    if why is not None:
        return {"unavailable": why}
    try:
        peer_yag.run_peer(log, max_seconds=10.0)  # warm-up, as tools/bench_slam.py's (numba, the C++ modules)
        p = peer_yag.run_peer(log)
    except ValueError as e:  # a log the peer cannot take (no wheel odometry): the reason is the message
        return {"unavailable": str(e)}
    except Exception as e:  # the peer's own failure is a cell of the table, not the end of the benchmark
        return {"unavailable": f"yag-slam failed: {type(e).__name__}: {e}"}
    return {"keyframes": p.keyframes, "loops": p.loops, "wall_s": p.wall_s, "realtime_factor": p.duration_s / p.wall_s,
            "consistency": p.consistency}


def map_unscored(tmp: Path) -> list[dict]:
    """`kosmap slam` on each unscored log (imported first where needed); its metrics.json's run summary."""
    from kosmap.tools.laserimport import import_log

    rows = []
    for rel, fmt, what in UNSCORED:
        src = data_dir() / "laser" / "unscored" / rel
        log = src
        if fmt is not None:
            log = tmp / (src.name + ".clf")
            import_log(src, log, fmt)
        out = tmp / ("out_" + src.name)
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "kosmap.tools.cli", "slam", str(log), "--source", "laser", "--out", str(out)],
                           capture_output=True, text=True)
        row = {"log": rel, "what": what, "exit": p.returncode, "wall_s": time.perf_counter() - t0,
               "stderr_tail": p.stderr.strip().splitlines()[-1:] if p.returncode else []}
        mj = out / "metrics.json"
        if p.returncode == 0 and mj.exists():
            run = json.loads(mj.read_text())["run"]
            row.update({k: run.get(k) for k in ("scans", "keyframes", "loops", "duration_s", "realtime_factor", "consistency",
                                                "loop_search", "odometry_noise")})
        row["yag_slam"] = peer_unscored(log)
        rows.append(row)
        print(f"{rel}: exit {p.returncode}, {row.get('loops')} loops, consistency {row.get('consistency')}", flush=True)
    return rows


def markdown(loo: dict, res: dict, unscored: list[dict], meta: dict) -> str:
    L = ["## Held out: leave-one-out", "",
         f"Generated by `tools/bench_slam_loo.py` on {meta['date']} ({meta['machine']}, {meta['cores']} cores, shared: "
         "wall-clock real-time factors vary with the other jobs). For each log the setting is chosen among "
         f"{len(res)} candidates ({', '.join(f'`{c}`' for c in res)}) on the two other logs only (mean of abs trans ÷ "
         "Cartographer's), and the left-out log is scored under that choice.", "",
         "| left out | chosen on the others | abs trans (m) | Cartographer (published) | abs rot (°) | real-time (wall) "
         "| real-time (CPU) |",
         "|---|---|---|---|---|---|---|"]
    for n, v in loo.items():
        L.append(f"| {LOGS[n][2]} | `{v['chosen']}` | **{v['abs_trans']:.4f}** | {PUBLISHED[n]['cartographer']['abs_trans'][0]:.4f} "
                 f"| {v['abs_rot_deg']:.3f} | {v['rt_wall']:.0f}× | {v['rt_cpu']:.0f}× |")
    L += ["", "Every candidate on every log (abs trans, m):", "", "| candidate | " + " | ".join(LOGS[n][2] for n in LOGS) + " |",
          "|---|" + "---|" * len(LOGS)]
    for c, per in res.items():
        L.append(f"| `{c}` | " + " | ".join(f"{per[n]['abs_trans']:.4f}" for n in LOGS) + " |")
    L += ["", "Candidates: " + "; ".join(f"`{c}` = {o or 'the defaults'}" for c, o in CANDIDATES.items() if c in res) + "."]
    if unscored:
        L += ["", "## Unscored real logs (no ground truth)", "",
              "Mapped with the defaults by `kosmap slam` (research formats imported by `tools/laserimport.py`). The "
              "self-consistency figure: where the robot came back, how far its scans lie from the earlier ones (median, "
              "90 %); a consistent map gives millimetres to a few centimetres.", "",
              "Beside it, yag-slam (OpenKarto, `tools/peer_yag.py`) on the same log with the same odometry: its loops, the "
              "same figure over its keyframes (0.2 m apart, ours 0.15 m; how many of them revisit) and its real-time "
              "factor.", "",
              "Loop score asked: the score a loop had to reach (`[graph] loop_score = \"derived\"`: 0.6 × the score expected "
              "of a true match given the scan's own scatter), lowest–highest over the run's searches. Odometry measured: "
              "the wheels' scale error and heading drift per metre measured while running against the scan matcher "
              "(backend/odomnoise.py; – where the log has no odometry or too few matched intervals).", "",
              "| log | sensor, format | exit | scans | loops | loop score asked | odometry measured | revisits off, median / "
              "90 % (m) | likely bent | real-time | yag-slam loops | yag-slam revisits off (m) | yag-slam real-time |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in unscored:
            c = r.get("consistency") or {}
            off = _revisits(c)
            rt = r.get("realtime_factor")
            L.append(f"| {r['log']} | {r['what']} | {r['exit']} | {r.get('scans', '–')} | {r.get('loops', '–')} | "
                     f"{_asked(r.get('loop_search'))} | {_odometry(r.get('odometry_noise'))} | {off} | "
                     f"{'yes' if c.get('bent') else 'too few revisits to tell' if c.get('too_few') else 'no'} | {f'{rt:.0f}×' if rt else '–'} | {_peer_cells(r.get('yag_slam'))} |")
    return "\n".join(L) + "\n"


def _asked(ls: dict | None) -> str:
    lo, hi = (ls or {}).get("min_score_lo"), (ls or {}).get("min_score_hi")
    if lo is None or lo != lo:
        return "– (no search)"
    return f"{lo:.3f}" if abs(hi - lo) < 5e-4 else f"{lo:.3f}–{hi:.3f}"


def _odometry(n: dict | None) -> str:
    if not n or not n.get("measured"):
        return "–"
    return f"{100 * n['scale_error']:+.1f} %, {math.degrees(n['heading_drift']):+.2f}°/m"


def _revisits(c: dict) -> str:
    med = c.get("median_m")
    return "no revisits" if med is None or med != med else f"{med:.3f} / {c.get('p90_m', float('nan')):.3f}"


def _peer_cells(y: dict | None) -> str:
    """yag-slam's three cells of an unscored log's row."""
    if not y:
        return "– | – | –"
    if "unavailable" in y:
        return f"peer unavailable: {y['unavailable']} | | "
    c = y.get("consistency") or {}
    n = f" ({c['revisit_keyframes']} keyframes)" if c.get("revisit_keyframes") else ""
    return f"{y['loops']} | {_revisits(c)}{n} | {y['realtime_factor']:.0f}×"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES))
    ap.add_argument("--no-unscored", action="store_true")
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "bench")
    a = ap.parse_args()
    import platform

    run_slam(data_dir() / LOGS["csail"][0], load_config(None, {}), max_seconds=10.0)  # warm-up (numba, gtsam)
    res: dict = {}
    for c in a.candidates:
        res[c] = {}
        for n in LOGS:
            res[c][n] = score_log(n, CANDIDATES[c])
            print(f"{c} {n}: {res[c][n]['abs_trans']:.4f} m, {res[c][n]['rt_wall']:.0f}× real time", flush=True)
    loo = leave_one_out(res)
    for n, v in loo.items():
        print(f"left out {n}: chose {v['chosen']} → {v['abs_trans']:.4f} m (Cartographer "
              f"{PUBLISHED[n]['cartographer']['abs_trans'][0]:.4f})", flush=True)
    unscored = []
    if not a.no_unscored:
        with tempfile.TemporaryDirectory() as tmp:
            unscored = map_unscored(Path(tmp))
    meta = {"date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.processor() or platform.machine(),
            "cores": os.cpu_count()}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "slam_loo.json").write_text(json.dumps(json_safe({"meta": meta, "candidates": res, "leave_one_out": loo,
                                                                "unscored": unscored}), indent=2))
    (a.out / "slam_loo.md").write_text(markdown(loo, res, unscored, meta))
    print(f"wrote {a.out / 'slam_loo.md'} and {a.out / 'slam_loo.json'}")


if __name__ == "__main__":
    main()
