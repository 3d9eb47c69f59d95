"""The report of a `kosmap build` run: report.html (self-contained, images embedded) and report.md (beside the PNGs).

Read top to bottom it says what was mapped and how well: headline numbers, the maps side by side, the overlays of
KOS vs laser vs blueprint, the trajectories (with ATE when the log has ground truth), the thesis's Table 5.2
(plane filtering per frame) and Table 5.5 (speed) analogues, and every comparison metric. Everything comes from
metrics.json and the files beside it, so a report can be rewritten from a finished run (`write_report`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from kosmap.backend.consistency import RECOVERY_SHARE
from kosmap.mapping.mapio import save_figure
from kosmap.mapping.reportdoc import to_html, to_markdown

TOL = "0.10"  # the tolerance of the headline numbers


def _f(v, digits: int = 3, unit: str = "") -> str:
    if v is None:
        return "–"
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
        return f"{v}{unit}"
    try:
        return f"{float(v):.{digits}f}{unit}"
    except (TypeError, ValueError):
        return str(v)


def _label(name: str, metrics: dict) -> str:
    if name == "blueprint":
        return "blueprint"
    m = metrics.get("maps", {}).get(name, {})
    return m.get("label", name)


# ---- the figures ----------------------------------------------------------------------------------------------------

def _read_tum(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    if not path.is_file():
        return None
    from kosmap.backend.trajio import read_tum

    t, p = read_tum(path)
    return (t, p) if len(t) else None


def trajectory_figure(out: Path, metrics: dict) -> Path | None:
    """trajectories.png: every trajectory of the run, in the ground truth's frame over the blueprint when the log
    has ground truth (each aligned to it as ATE aligns it), else in the laser's frame, else as it is."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kosmap.backend.metrics import align_se2, associate

    tr = {name: _read_tum(out / f"trajectory_{name}.tum") for name in ("kos", "laser")}
    tr["odometry"] = _read_tum(out / "odometry.tum")
    tr = {k: v for k, v in tr.items() if v is not None}
    gt = _read_tum(out / "ground_truth.tum")
    if not tr:
        return None
    ref_name, ref = ("ground truth", gt) if gt is not None else (("laser SLAM", tr["laser"]) if "laser" in tr else (None, None))
    fig, ax = plt.subplots(figsize=(9, 5.2), dpi=110)
    bp = metrics.get("sources", {}).get("blueprint")
    if bp and gt is not None:
        try:
            from kosmap.mapping.mapio import read_blueprint

            g = read_blueprint(bp, metrics["sources"].get("blueprint_scale"),
                               metrics.get("config", {}).get("compare", {}).get("blueprint_dark", 0.5))
            walls = (g.data[::-1] >= 65).astype(float)
            x0, y0 = g.origin[0], g.origin[1]
            ext = (x0, x0 + g.width * g.resolution, y0, y0 + g.height * g.resolution)
            ax.imshow(np.ma.masked_where(walls == 0, walls), cmap="Greys", vmin=0, vmax=2.5, extent=ext,
                      interpolation="nearest")
        except Exception:  # noqa: BLE001 - the figure is still useful without its backdrop
            pass
    style = {"kos": ("tab:red", "KOS SLAM"), "laser": ("tab:blue", "laser SLAM"), "odometry": ("tab:orange", "wheel odometry")}
    if gt is not None:
        ax.plot(gt[1][:, 0], gt[1][:, 1], color="k", lw=2.2, alpha=0.35, label="ground truth")
    for name, (t, p) in tr.items():
        xy = p[:, :2]
        if ref is not None and not (name == "laser" and ref_name == "laser SLAM"):
            ie, ir = associate(t, ref[0], 0.02)
            if len(ie) >= 3:
                R, tt = align_se2(xy[ie], ref[1][ir, :2])
                xy = xy @ R.T + tt
        c, lab = style.get(name, ("tab:green", name))
        ax.plot(xy[:, 0], xy[:, 1], color=c, lw=1.0, label=lab, ls="--" if name == "odometry" else "-")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    where = {"ground truth": "aligned to the ground truth (as ATE aligns them), over the blueprint",
             "laser SLAM": "aligned to the laser SLAM's trajectory"}.get(ref_name, "each in its own frame")
    ax.set_title(f"Trajectories, {where}", fontsize=10)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, out / "trajectories.png")


def _summary_panels(metrics: dict) -> list[str]:
    """The maps summary.png shows: the KOS SLAM scan's and the laser's, those the run made."""
    main = f"kos_{metrics.get('slam_scan', 'obstacle')}"
    return [k for k in (main, "laser") if k in metrics.get("maps", {})]


def summary_caption(metrics: dict) -> str:
    """summary.png's caption, naming only the maps it shows (a laser-only log has no depth camera map)."""
    kinds = ["kos" if k.startswith("kos") else "laser" for k in _summary_panels(metrics)]
    if kinds == ["kos", "laser"]:
        return "the depth camera's (KOS) map and the laser's, each from its own SLAM"
    return "the depth camera's (KOS) map, from its SLAM" if kinds == ["kos"] else "the laser's map, from its SLAM"


def map_warnings(metrics: dict) -> list[str]:
    """Maps without a single occupied cell: a KOS level the camera never reaches draws every cell it passes as free
    floor, which says nothing about that height (the console and the report say so beside the run's warnings)."""
    out = []
    max_depth = metrics.get("config", {}).get("depth", {}).get("max_depth")
    for name, mp in metrics.get("maps", {}).items():
        if mp.get("occupied_cells") != 0 or not mp.get("known_cells"):
            continue
        kos = mp.get("source") == "kos"
        what = f"the KOS level {mp.get('level')}" if kos and mp.get("level") != "obstacle" else mp.get("label", name)
        out.append(f"map_{name}: {what} saw no obstacle in its {mp.get('scans')} scans, so its {mp['known_cells']} "
                   f"known cells are all drawn free"
                   + ("; check that the camera sees that height (its mount's height and pitch, its vertical field of "
                      f"view, [depth] max_depth = {max_depth:g} m) or choose other [kos] levels"
                      if kos and isinstance(max_depth, (int, float)) else ""))
    return out


def consistency_text(c: dict) -> str:
    """A SLAM run's self-consistency in a few words (backend/consistency.py), for the report and the console."""
    if not c:
        return "–"
    med = c.get("median_m")
    head = ("no revisits" if med is None or med != med else
            f"revisits {med:.3f} m off (90 %: {c['p90_m']:.3f} m, {c['revisit_keyframes']} keyframes)")
    loops = f", {c['loops_disagreeing']}/{c['loops']} loops missed" if c.get("loops") else ""
    unsure = (f", the scan matcher re-searched {100 * c['recovery_share']:.0f} % of its matches"
              if c.get("recovery_share", 0.0) > RECOVERY_SHARE else "")
    wrong = c.get("bent") and c.get("recovery_share", 0.0) > RECOVERY_SHARE  # the front end could not follow
    verdict = (": likely wrong" if wrong else ": likely bent" if c.get("bent") else
               ": too few revisits to tell" if c.get("too_few") else "")
    return head + loops + unsure + verdict


def odometry_noise_text(n: dict | None) -> str:
    """The wheel odometry's noise measured against the scans while the SLAM ran (backend/odomnoise.py), in a few
    words, for the report and the console; "–" when it was not measured (no odometry, too few intervals the
    scans saw on their own, or a front end held to the odometry)."""
    if not n or not n.get("measured"):
        return "–"
    return (f"distance {100 * n['scale_error']:+.2f} %, heading drift {math.degrees(n['heading_drift']):+.3f}°/m, "
            f"random {100 * n['trans_sigma']:.2f} cm/√m and {math.degrees(n['yaw_sigma']):.2f}°/√m "
            f"({n['samples']} intervals)")


def run_warnings(metrics: dict) -> list[str]:
    """The run's warnings (metrics.json) and the maps' (map_warnings), each once."""
    return list(dict.fromkeys(list(metrics.get("warnings", [])) + map_warnings(metrics)))


def summary_figure(out: Path, metrics: dict, path: Path | None = None) -> Path | None:
    """summary.png: the KOS map and the laser map side by side (each with its trajectory), titled with their F1
    against the blueprint and their SLAM's ATE: the run at a glance."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = _summary_panels(metrics)
    if not panels:
        return None
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 4.4 * len(panels)), dpi=110, squeeze=False)
    for ax, name in zip(axes[:, 0], panels):
        img = cv2.imread(str(out / f"map_{name}.png"))[:, :, ::-1]
        ax.imshow(img, interpolation="nearest")
        ax.set_axis_off()
        src = "kos" if name.startswith("kos") else "laser"
        bits = [metrics["maps"][name].get("label", name).replace(" (SLAM scan)", "") + " map"]
        c = metrics.get("comparisons", {}).get(f"{name}_vs_blueprint")
        if c:
            bits.append(f"F1 vs blueprint {c['tolerances'][TOL]['f1']:.2f} at 0.10 m")
        ate = metrics.get("slam", {}).get(src, {}).get("ate")
        if ate:
            bits.append(f"{'KOS' if src == 'kos' else 'laser'} SLAM ATE {ate['rmse']:.2f} m")
        ax.set_title(" · ".join(bits), fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path or out / "summary.png")


def frames_figure(out: Path) -> Path | None:
    """frames.png: per-frame FSPF+ / KOS time and the inlier / outlier / ineligible shares over the log."""
    p = out / "stats.csv"
    if not p.is_file():
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = np.genfromtxt(p, delimiter=",", names=True, dtype=None, encoding="utf-8")
    if d.size < 2:
        return None
    t = d["stamp"] - d["stamp"][0]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 4.6), dpi=110, sharex=True)
    for key, c, lab in (("ineligible_pct", "0.5", "ineligible"), ("inlier_pct", "tab:green", "inliers (kept planes)"),
                        ("dropped_pct", "tab:olive", "dropped (floor, ceiling)"), ("outlier_pct", "tab:red", "outliers")):
        a1.plot(t, d[key], lw=0.7, color=c, label=lab)
    a1.set_ylabel("% of pixels")
    a1.set_ylim(0, 100)
    a1.legend(fontsize=7, ncol=4, loc="upper center")
    a1.grid(alpha=0.3)
    a2.plot(t, d["fspf_ms"], lw=0.6, color="tab:blue", label="FSPF+")
    a2.plot(t, d["kos_ms"], lw=0.6, color="tab:purple", label="KOS, all levels")
    a2.set_ylabel("ms per frame (wall, worker)")
    a2.set_xlabel("log time (s)")
    a2.legend(fontsize=7, loc="upper right")
    a2.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, out / "frames.png")


# ---- the content, once, for both formats ----------------------------------------------------------------------------

def headline(metrics: dict) -> dict:
    """The numbers a person looks at first: F1 at 0.10 m of each comparison (and, against the blueprint, the F1 of
    the walls the robot saw: a plan's rooms never entered count as missed in the plain F1), ATE of each SLAM,
    real-time factor."""
    c = metrics.get("comparisons", {})
    h = {"f1": {k: v["tolerances"][TOL]["f1"] for k, v in c.items() if TOL in v.get("tolerances", {})},
         "f1_seen": {k: v["tolerances"][TOL].get("f1_observed") for k, v in c.items()
                     if TOL in v.get("tolerances", {}) and v.get("b") == "blueprint"},
         "ate": {k: s["ate"]["rmse"] for k, s in metrics.get("slam", {}).items() if s.get("ate")},
         "realtime_factor": metrics.get("timing", {}).get("realtime_factor"),
         "total_s": metrics.get("timing", {}).get("total_s"), "partial": metrics.get("partial", False)}
    return h


def _sections(out: Path, metrics: dict, traj_png: Path | None, frames_png: Path | None) -> list[tuple]:
    """The report as a list of blocks: ("h", level, text), ("p", text), ("table", header, rows), ("images", [(path,
    caption)]), ("warn", text)."""
    m = metrics
    return (_intro_blocks(m) + _headline_blocks(m) + _map_blocks(out, m) + _comparison_blocks(out, m)
            + _slam_blocks(m, traj_png) + _frame_blocks(m, frames_png) + _closing_blocks(m))


def _intro_blocks(m: dict) -> list[tuple]:
    """The title, a partial run's warning, and what was read."""
    B: list[tuple] = []
    log = m["log"]
    name = Path(log["path"]).name
    B.append(("h", 1, f"kosmap build: {name}"))
    if m.get("partial"):
        B.append(("warn", f"PARTIAL RESULT: the run was interrupted after {_f(m.get('interrupted_at_s'), 1)} s of "
                          f"{_f(log['duration_s'], 1)} s of log. Everything below covers only the part that was read."))
    src = m["sources"]
    fr = m["frames"]
    what = []
    if src["kos"]:
        what.append(f"{fr['processed']} depth frames of {fr['cameras']} camera(s) (of {fr['in_log']} in the log"
                    + (f", at most {fr['depth_rate_hz']:g} Hz per camera" if fr["depth_rate_hz"] else "")
                    + f") through FSPF+ and KOS, giving {fr['steps']} KOS steps; SLAM on the '{m['slam_scan']}' scan")
    if src["laser"]:
        what.append(f"{fr['laser_scans_used']} laser scans (of {fr['laser_scans_in_log']}"
                    + (f", at most {fr['laser_rate_hz']:g} Hz" if fr["laser_rate_hz"] else "") + ") through SLAM")
    B.append(("p", f"Log: {log['path']} ({_f(log['duration_s'], 1)} s). " + "; ".join(what) + ". "
              + ("Ground truth: yes (ATE below). " if src["ground_truth"] else "No ground truth in the log. ")
              + (f"Blueprint: {src['blueprint']}" + (f" ({src['blueprint_scale']:g} m per pixel)."
                                                        if src.get("blueprint_scale") else ".")
                 if src["blueprint"] else "No blueprint given.")))
    return B


def _headline_blocks(m: dict) -> list[tuple]:
    """F1 against each reference (and of the walls seen), ATE, the real-time factor."""
    B: list[tuple] = []
    src = m["sources"]
    h = headline(m)
    B.append(("h", 2, "Headline"))
    t = m["timing"]
    if h["f1"]:
        rows = []
        for key in h["f1"]:
            c = m["comparisons"][key]
            v = c["tolerances"][TOL]
            rows.append([f"{_label(c['a'], m)} vs {_label(c['b'], m)}", _f(v["f1"]), _f(v["precision"]), _f(v["recall"]),
                         _f(v["coverage"]), _f(v["recall_observed"]), _f(v.get("f1_observed"))])
        B.append(("table", ["map A vs reference B, at 0.10 m", "F1", "precision", "recall", "walls seen",
                            "recall of seen walls", "F1 of seen walls"], rows))
        low = [(m["comparisons"][k], m["comparisons"][k]["tolerances"][TOL]["coverage"]) for k in h["f1"]
               if m["comparisons"][k]["b"] == "blueprint"]
        low = [(c, cov) for c, cov in low if cov is not None and cov < 0.95]
        if low:
            seen = ", ".join(f"{_label(c['a'], m)} {100 * cov:.0f} %" for c, cov in low)
            B.append(("p", f"Coverage bounds recall: on this path the maps saw only part of the blueprint's wall faces "
                           f"({seen}); faces never in view (rooms not entered, the far side of a wall) count as missed, "
                           f"so recall and F1 cannot exceed what was seen. 'Recall/F1 of seen walls' score the map "
                           f"against the faces it saw: how right the map is, apart from how much the robot explored."))
    rows = [[f"{'KOS' if k == 'kos' else 'laser'} SLAM", _f(v, 3, " m"),
             _f(m["slam"][k].get("ate_odometry", {}).get("rmse"), 3, " m")] for k, v in h["ate"].items()]
    if rows:
        B.append(("table", ["trajectory", "ATE RMSE", "wheel odometry's ATE"], rows))
    workers = _workers(m["table_5_5"]["workers"], src["kos"])
    B.append(("p", f"Whole run, up to this report: {_f(t.get('total_s'), 1)} s for {_f(t.get('log_s'), 1)} s of log = "
                   f"{_f(t.get('realtime_factor'), 1)}× real time ({workers})."))
    return B


def _map_blocks(out: Path, m: dict) -> list[tuple]:
    """Every map with its trajectory."""
    B: list[tuple] = []
    maps = m.get("maps", {})
    B.append(("h", 2, "Maps"))
    B.append(("p", "Each map is a log-odds occupancy grid (white free, black occupied, grey unknown) built from the "
                   "optimised poses of the SLAM named in its caption; the blue line is that trajectory. "
                   "Files: map_<name>.png for people, map_<name>.pgm + .yaml for ROS map_server."))
    order = sorted(maps, key=lambda k: (k != f"kos_{m['slam_scan']}", k != "laser", k))
    B.append(("images", [(out / Path(maps[k]["png"]).name,
                          f"{maps[k].get('label', k)} — {maps[k]['width']}×{maps[k]['height']} cells of "
                          f"{maps[k]['resolution']:g} m, poses from the {maps[k].get('poses')} SLAM"
                          + (" — saw no obstacle: every known cell drawn free (see Warnings)"
                             if maps[k].get("occupied_cells") == 0 and maps[k].get("known_cells") else ""))
                         for k in order]))
    return B


def _comparison_blocks(out: Path, m: dict) -> list[tuple]:
    """Overlays, and each comparison's scores, alignment and distances."""
    B: list[tuple] = []
    comps = m.get("comparisons", {})
    if comps:
        B.append(("h", 2, "Overlays and comparison"))
        B.append(("p", "Map A (red) aligned onto reference B (green); black where they agree within the smallest "
                       "tolerance; pale cells are occupied but unscored (inside thick walls). Precision: share of A's "
                       "wall cells with a B wall within the tolerance; recall: the same from B to A; walls seen: share "
                       "of B's wall faces in front of space both maps call free (a blueprint's rooms the robot never "
                       "looked into lower recall, not precision); 'recall/F1 of seen walls' score those faces only."))
        imgs = [(out / f"overlay_{k}.png", f"A = {_label(c['a'], m)}, B = {_label(c['b'], m)}") for k, c in comps.items()]
        B.append(("images", imgs))
        for k, c in comps.items():
            rows = []
            for tol, v in c["tolerances"].items():
                rows.append([f"{float(tol):.2f} m", _f(v["precision"]), _f(v["recall"]), _f(v["f1"]), _f(v["coverage"]),
                             _f(v["recall_observed"]), _f(v.get("f1_observed"))])
            al = c["alignment"]
            B.append(("h", 3, f"{_label(c['a'], m)} vs {_label(c['b'], m)}"))
            B.append(("table", ["tolerance", "precision", "recall", "F1", "walls seen", "recall of seen walls",
                                "F1 of seen walls"], rows))
            fr_ = c["free"]
            B.append(("p", (f"Alignment A→B: x {_f(al.get('x'), 3)} m, y {_f(al.get('y'), 3)} m, yaw "
                            f"{_f(al.get('yaw_deg'), 2)}°, RMS {_f(al.get('rms'), 3)} m"
                            + (f" (the {_label(al['from'], m)} map's: made on the same poses, it shares their frame). "
                               if al.get("from") else ". ") if al.get("aligned") else "Not aligned. ")
                      + f"Wall distance A→B mean {_f(c['distance_a_to_b']['mean'])} m (median "
                        f"{_f(c['distance_a_to_b']['median'])}), B→A mean {_f(c['distance_b_to_a']['mean'])} m. "
                      + f"Free space agreement {_f(fr_['agreement'])}, IoU {_f(fr_['iou'])}."))
    return B


def _slam_blocks(m: dict, traj_png: Path | None) -> list[tuple]:
    """Trajectories and each SLAM's statistics."""
    B: list[tuple] = []
    src = m["sources"]
    slam = m.get("slam", {})
    if slam:
        B.append(("h", 2, "Trajectories and SLAM"))
        if traj_png is not None:
            B.append(("images", [(traj_png, "trajectories")]))
        rows = []
        for k, s in slam.items():
            sec = s.get("seconds", {})
            hd = s.get("heading")
            rows.append([f"{'KOS' if k == 'kos' else 'laser'} SLAM", s["scans"], s["keyframes"], s["loops"],
                         "off" if not hd else (hd["priors"] if not hd["disabled"] else "not Manhattan"),
                         _f(s.get("ate", {}).get("rmse"), 3), _f(s.get("ate", {}).get("max"), 3),
                         _f(s.get("ate_frontend", {}).get("rmse"), 3), _f(s.get("ate_odometry", {}).get("rmse"), 3),
                         consistency_text(s.get("consistency") or {}), odometry_noise_text(s.get("odometry_noise")),
                         _f(sum(v for v in sec.values()), 1)])
        B.append(("table", ["source", "scans", "keyframes", "loops", "heading priors", "ATE RMSE (m)", "ATE max (m)",
                            "front end alone (m)", "wheel odometry (m)", "self-consistency",
                            "wheel odometry measured against the scans", "SLAM time (s)"], rows))
        B.append(("p", "Self-consistency needs no ground truth: where the robot came back (30 s or more later), how "
                       "far one rigid move brings its scans onto the earlier ones' walls (median, and 90th percentile), and how "
                       "many loops the solution misses by more than their own covariance allows; a map is likely bent when "
                       "its revisits are off by more than a grid cell plus what the scans' own noise hides "
                       "(backend/consistency.py, docs/consistency.md)."))
        if not src["ground_truth"]:
            B.append(("p", "The log has no ground truth (/ground_truth/odom): no ATE."))
    return B


def _frame_blocks(m: dict, frames_png: Path | None) -> list[tuple]:
    """The thesis's Table 5.2 and 5.5 analogues."""
    B: list[tuple] = []
    src, t = m["sources"], m["timing"]
    if src["kos"] and m["frames"]["processed"]:
        t52 = m["table_5_2"]
        B.append(("h", 2, "Plane filtering per frame (thesis Table 5.2)"))
        rows = [[lab, _f(t52[k]["mean"], 2), _f(t52[k]["std"], 2), _f(t52[k]["median"], 2)]
                for k, lab in (("ineligible_pct", "ineligible %"), ("inlier_pct", "inlier % (planes kept)"),
                               ("dropped_pct", "dropped % (floor, ceiling planes)"), ("outlier_pct", "outlier %"),
                               ("planes", "planes per frame"), ("fspf_ms", "FSPF+ ms"), ("kos_ms", "KOS ms"))]
        B.append(("table", ["per frame", "mean", "std", "median"], rows))
        if frames_png is not None:
            B.append(("images", [(frames_png, "per frame over the log (stats.csv)")]))
        t55 = m["table_5_5"]
        B.append(("h", 2, "Speed (thesis Table 5.5)"))
        rows = [["FSPF+ per frame (wall time in a worker)", f"{_f(t55['fspf_ms']['mean'], 2)} ms (median {_f(t55['fspf_ms']['median'], 2)})"],
                ["KOS per frame, all levels (wall time in a worker)", f"{_f(t55['kos_ms']['mean'], 2)} ms (median {_f(t55['kos_ms']['median'], 2)})"],
                ["frames per second per worker (1000 / (FSPF+ + KOS ms))", _f(t55["per_core_hz"], 1, " Hz")],
                ["system: frames per second read and processed", f"{_f(t55['system_hz'], 1)} Hz with {t55['workers']} worker process(es)"],
                ["map creation (SLAM solve + grids)", _f(t55["map_creation_s"], 2, " s")],
                ["comparisons", _f(t.get("compare_s"), 2, " s")],
                ["whole run", f"{_f(t.get('total_s'), 1)} s = {_f(t.get('realtime_factor'), 1)}× real time"]]
        mem = m.get("memory")
        if mem:
            main = mem["peak_rss_mb_main"]
            rows.append(["peak memory (resident)", f"main process {_f(main.get('after_read'), 0)} MB after reading, "
                         f"{_f(main.get('after_maps_and_compare'), 0)} MB at the end; largest worker "
                         f"{_f(mem.get('peak_rss_mb_workers'), 0)} MB"
                         + "".join(f"; {n} SLAM process {_f(v, 0)} MB" for n, v in (mem.get("peak_rss_mb_slam") or {}).items())])
        B.append(("table", ["stage", "time"], rows))
    return B


def _closing_blocks(m: dict) -> list[tuple]:
    """The run's warnings and the files it wrote."""
    B: list[tuple] = []
    src = m["sources"]
    warns = run_warnings(m)
    if warns:
        B.append(("h", 2, "Warnings"))
        B.append(("list", warns))
    B.append(("h", 2, "Files"))
    mcap = (["KOS scans"] if src["kos"] else []) + (["laser scans"] if src["laser"] else []) \
        + (["plane points"] if src["kos"] else [])
    B.append(("list", ["map_<name>.png / .pgm / .yaml: the maps", "trajectory_<source>.tum (TUM, for evo)"
                       + (", ground_truth.tum" if src["ground_truth"] else "")]
              + (["stats.csv: per-frame Table 5.2 columns and timings"] if src["kos"] else [])
              + [f"kosmap.mcap: {', '.join(mcap)}, /tf, paths and maps for Foxglove", "metrics.json: every number here",
                 "config.toml: the effective configuration"]))
    return B


def _workers(n: int, depth: bool) -> str:
    """What the worker processes did: FSPF+ and KOS on the depth frames, or in a laser-only run the maps alone."""
    if not n:
        return "serial, in one process"
    procs = f"{n} worker process{'es' if n != 1 else ''}"
    return (f"{procs} for FSPF+, KOS, the maps and comparisons" if depth
            else f"laser only: {procs} for the maps and comparisons")


def write_report(out: str | Path, metrics: dict, frames_png: Path | None | bool = True,
                 traj_png: Path | None | bool = True) -> dict[str, Path]:
    """Write trajectories.png, frames.png, report.md and report.html into `out` (beside the run's files).
    `frames_png`, `traj_png`: frames.png, trajectories.png when the caller drew them already (None: there is
    none), True: draw it here."""
    out = Path(out)
    traj = trajectory_figure(out, metrics) if traj_png is True else traj_png
    if frames_png is True:
        frames_png = frames_figure(out) if metrics.get("sources", {}).get("kos") else None
    frames = frames_png
    summary = summary_figure(out, metrics)
    blocks = _sections(out, metrics, traj, frames)
    if summary is not None:  # the run at a glance, right under the headline numbers
        at = next((i for i, b in enumerate(blocks) if b[0] == "h" and b[2] == "Maps"), len(blocks))
        blocks.insert(at, ("images", [(summary, summary_caption(metrics))]))
    files = {}
    for name, text in (("report.md", to_markdown(blocks)), ("report.html", to_html(blocks))):
        p = out / name
        tmp = p.with_name(p.name + ".partial")
        tmp.write_text(text)
        os.replace(tmp, p)
        files[name.replace(".", "_")] = p
    if traj is not None:
        files["trajectories_png"] = traj
    if frames is not None:
        files["frames_png"] = frames
    if summary is not None:
        files["summary_png"] = summary
    return files
