"""What `kosmap localize` writes: the trajectory (TUM, map frame), per-pose confidence (CSV), metrics.json (scored
against the log's ground truth without any alignment: the map's frame is the truth's), figures, report.md/html,
an MCAP for Foxglove (the map, the poses, the particles) and the effective config."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from kosmap.frontend import se2
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.localize import LOST, STATUS_NAMES, TRACKING, LocalizeResult
from kosmap.mapping.reportdoc import to_html, to_markdown

LOCALIZE_FILES = ("trajectory.tum", "confidence.csv", "metrics.json", "report.md", "report.html", "localization.png",
                  "confidence.png", "kosmap.mcap", "config.toml")
TRUTH_GAP_S = 0.1  # a pose is scored only where a ground-truth sample lies within this much time


def truth_at(result: LocalizeResult, truth) -> tuple[np.ndarray, np.ndarray]:
    """(ground-truth poses at the result's stamps, mask of the stamps it covers)."""
    tg, pg = truth
    order = np.argsort(tg)
    tg, pg = np.asarray(tg)[order], np.asarray(pg)[order]
    st = result.stamps
    j = np.clip(np.searchsorted(tg, st), 1, len(tg) - 1)
    near = np.minimum(np.abs(tg[j] - st), np.abs(tg[j - 1] - st)) <= TRUTH_GAP_S
    ok = near & (st >= tg[0]) & (st <= tg[-1])
    return se2.interpolate(tg, pg, st), ok


def _stats(v: np.ndarray) -> dict:
    if not len(v):
        return {"n": 0}
    return {"n": int(len(v)), "rmse": float(np.sqrt(np.mean(v ** 2))), "median": float(np.median(v)),
            "max": float(np.max(v))}


def metrics(result: LocalizeResult, inp, cfg, map_path: str, truth: bool = True) -> dict:
    """The run, the filter's own view (convergence, lost stretches) and, with ground truth, the errors after the
    filter first claimed a pose (no alignment: the map frame is the truth's)."""
    conv = result.converged_s()
    lost = result.lost_stretches()
    dur = inp.duration_s
    m: dict = {"kosmap": "localize",
               "run": {"map": str(map_path), "source": inp.source, "scans": int(len(result.stamps_ns)),
                       "duration_s": dur, "wheel_odometry": inp.has_odom, "gyro": inp.has_gyro,
                       "filter_updates": result.updates, "seconds": {"read": inp.read_s, "localize": result.seconds},
                       "realtime_factor": dur / max(inp.read_s + result.seconds, 1e-9),
                       "warnings": list(inp.warnings)},
               "localization": {"converged_s": conv, "tracking_share": float(np.mean(result.status == TRACKING)),
                                "lost": [{"start_s": s.start_s, "recovered_s": s.end_s,
                                          "lasted_s": None if s.end_s is None else s.end_s - s.start_s} for s in lost],
                                "spread_xy_median_m": float(np.median(result.spread_xy[result.status == TRACKING]))
                                if np.any(result.status == TRACKING) else None,
                                "score_median": float(np.median(result.score)),
                                "search": search_summary(result)}}
    if truth and inp.ground_truth is not None:
        gt, ok = truth_at(result, inp.ground_truth)
        e = np.hypot(result.poses[:, 0] - gt[:, 0], result.poses[:, 1] - gt[:, 1])
        eh = np.degrees(np.abs(se2.wrap(result.poses[:, 2] - gt[:, 2])))
        t = result.stamps - result.t0
        after = ok & (t >= conv) if conv is not None else np.zeros(len(t), bool)
        tracking = ok & (result.status == TRACKING)
        within = ok & (e <= 0.1) & (eh <= 2.0)  # the first pose from which every later one is this close
        bad = np.flatnonzero(ok & ~within)
        first_good = None
        if len(bad) == 0 and ok.any():
            first_good = float(t[np.flatnonzero(ok)[0]])
        elif len(bad) and bad[-1] + 1 < len(t):
            first_good = float(t[bad[-1] + 1])
        m["truth"] = {"frame": "the map's: errors are not aligned", "poses_scored": int(ok.sum()),
                      "after_convergence": {"position_m": _stats(e[after]), "heading_deg": _stats(eh[after])},
                      "while_tracking": {"position_m": _stats(e[tracking]), "heading_deg": _stats(eh[tracking])},
                      "within_0.1m_2deg_from_s": first_good}
    return m


LOOK_ALIKE_P = 0.1  # a place counts as a look-alike of the best while its posterior is at least this


def search_summary(result: LocalizeResult) -> dict:
    """The window's searches (depth camera with odometry): each one's places in the running with their posterior,
    and when the scans fit two or more places about equally (each ≥ LOOK_ALIKE_P): a run that has not claimed a pose
    says why, and which places it could not tell apart."""
    rows = [{"t_s": p.t_s, "claim": p.claim,
             "places": [{"x": float(q[0]), "y": float(q[1]), "yaw_deg": float(math.degrees(q[2])), "p": float(w)}
                        for q, w in zip(p.poses, p.prob)]} for p in result.searches]
    several = [p.t_s for p in result.searches if int(np.sum(p.prob >= LOOK_ALIKE_P)) >= 2]
    last = result.searches[-1] if result.searches else None
    return {"searches": rows,
            "look_alikes_from_s": several[0] if several else None, "look_alikes_until_s": several[-1] if several else None,
            "most_look_alikes": max((int(np.sum(p.prob >= LOOK_ALIKE_P)) for p in result.searches), default=0),
            "last_places": rows[-1]["places"] if last is not None and not last.claim and len(result.status)
            and result.status[-1] != TRACKING else []}


def write_confidence(path: Path, result: LocalizeResult) -> Path:
    rows = ["t,x,y,yaw,spread_xy_m,spread_yaw_deg,mode_share,score,inliers,particles,w_fast_over_w_slow,status"]
    for i in range(len(result.stamps_ns)):
        x, y, th = result.poses[i]
        rows.append(f"{result.stamps[i]:.6f},{x:.4f},{y:.4f},{th:.5f},{result.spread_xy[i]:.4f},"
                    f"{math.degrees(result.spread_yaw[i]):.3f},{result.mode_share[i]:.3f},{result.score[i]:.4f},{result.inliers[i]:.4f},"
                    f"{result.particles[i]},{result.ratio[i]:.4f},{STATUS_NAMES[result.status[i]]}")
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text("\n".join(rows) + "\n")
    os.replace(tmp, path)
    return path


def write_mcap(path: Path, result: LocalizeResult, grid, truth) -> Path:
    """The map (/map), the poses (/localize/pose, /localize/path), the particles after each filter update
    (/localize/particles, a PoseArray subsample) and the ground truth's path, for Foxglove."""
    from kosmap.frontend.logs import convert
    from kosmap.frontend.logs.writer import McapWriter

    t0 = int(result.stamps_ns[0]) if len(result.stamps_ns) else 0
    with McapWriter(path) as w:
        w.write_grid("/map", t0, "map", grid.data, grid.resolution, grid.origin)
        for s, p in zip(result.stamps_ns.tolist(), result.poses):
            w.write_msg("/localize/pose", "geometry_msgs/msg/PoseStamped",
                        convert.pose_stamped_msg(w.ts, s, "map", float(p[0]), float(p[1]), float(p[2])), s)
        for snap in result.snapshots:
            q = snap.particles.astype(np.float64)
            pos = np.column_stack((q[:, 0], q[:, 1], np.zeros(len(q))))
            quat = np.column_stack((np.zeros(len(q)), np.zeros(len(q)), np.sin(q[:, 2] / 2), np.cos(q[:, 2] / 2)))
            w.write_msg("/localize/particles", "geometry_msgs/msg/PoseArray",
                        convert.pose_array_msg(w.ts, snap.stamp_ns, "map", pos, quat), snap.stamp_ns)
        end = int(result.stamps_ns[-1]) if len(result.stamps_ns) else 0
        w.write_path("/localize/path", end, "map", result.poses, result.stamps_ns)
        if truth is not None:
            tg, pg = truth
            w.write_path("/ground_truth/path", end, "map", np.asarray(pg), (np.asarray(tg) * 1e9).astype(np.int64))
    return path


def figures(out: Path, result: LocalizeResult, grid, truth) -> tuple[Path, Path]:
    """localization.png (the trajectory over the map, coloured by status; the truth dashed) and confidence.png
    (the particles' spread, the match score and, with ground truth, the error, over time)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kosmap.mapping.mapio import grid_picture, save_figure

    img = grid_picture(grid)[:, :, ::-1]
    ext = [grid.origin[0], grid.origin[0] + grid.width * grid.resolution,
           grid.origin[1], grid.origin[1] + grid.height * grid.resolution]
    fig, ax = plt.subplots(figsize=(9, 9 * grid.height / max(grid.width, 1) + 0.8), dpi=110)
    ax.imshow(img, extent=ext)
    if truth is not None:
        ax.plot(truth[1][:, 0], truth[1][:, 1], "--", color="0.35", lw=1, label="ground truth")
    colors = {0: "#e69f00", TRACKING: "#0072b2", LOST: "#d55e00"}
    for code, name in enumerate(STATUS_NAMES):
        sel = result.status == code
        if sel.any():
            ax.plot(result.poses[sel, 0], result.poses[sel, 1], ".", ms=2.5, color=colors[code], label=name)
    ax.set_xlabel("x (m, map)")
    ax.set_ylabel("y (m, map)")
    ax.set_title("kosmap localize: a pose per scan")
    ax.legend(loc="best", fontsize=8)
    traj = save_figure(fig, out / "localization.png")
    t = result.stamps - result.t0
    n = 3 if truth is not None else 2
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.2 * n + 0.6), sharex=True, dpi=110)
    axes[0].semilogy(t, np.maximum(result.spread_xy, 1e-3), lw=1, label="particles' spread (m)")
    axes[0].semilogy(t, np.maximum(np.degrees(result.spread_yaw), 1e-2) / 100, lw=1, label="heading spread (°/100)")
    axes[0].legend(fontsize=8)
    axes[1].plot(t, result.score, lw=0.8, label="match score")
    axes[1].plot(t, np.minimum(result.ratio, 2.0) / 2, lw=0.8, label="w_fast / w_slow (÷2, capped)")
    axes[1].set_ylim(0, 1.05)
    axes[1].legend(fontsize=8)
    if truth is not None:
        gt, ok = truth_at(result, truth)
        e = np.hypot(result.poses[:, 0] - gt[:, 0], result.poses[:, 1] - gt[:, 1])
        axes[2].semilogy(t[ok], np.maximum(e[ok], 1e-3), lw=0.8, color="k", label="position error (m)")
        axes[2].legend(fontsize=8)
    for a in axes:
        for s in result.lost_stretches():
            a.axvspan(s.start_s, s.end_s if s.end_s is not None else t[-1], color="#d55e00", alpha=0.15)
        conv = result.converged_s()
        if conv is not None:
            a.axvline(conv, color="#0072b2", lw=0.8, ls=":")
    axes[-1].set_xlabel("log time (s); dotted: first pose found; shaded: lost")
    fig.tight_layout()
    conf = save_figure(fig, out / "confidence.png")
    return traj, conf


def _fmt(v, unit="", digits=3) -> str:
    return "—" if v is None else f"{v:.{digits}f}{unit}"


def _look_alike_text(search: dict | None) -> str:
    if not search or search["look_alikes_from_s"] is None:
        return ""
    text = (f"The scans fitted up to {search['most_look_alikes']} places of the map about equally (each with a posterior "
            f"of at least {LOOK_ALIKE_P:g} in the window's search) from {search['look_alikes_from_s']:.1f} s to "
            f"{search['look_alikes_until_s']:.1f} s; no pose is claimed while they do.")
    if search["last_places"]:
        text += " At the end of the log, still in the running: " + "; ".join(
            f"({q['x']:.1f}, {q['y']:.1f}, {q['yaw_deg']:.0f}°) p = {q['p']:.2f}" for q in search["last_places"][:4]) + "."
    return text


def report(out: Path, m: dict, traj: Path, conf: Path) -> None:
    run, loc = m["run"], m["localization"]
    blocks: list[tuple] = [("h", 1, "kosmap localize"),
                           ("p", f"{run['scans']} {run['source'].upper()} scans over {run['duration_s']:.1f} s of log "
                                 f"localized in {run['map']} at {run['realtime_factor']:.1f}× real time "
                                 f"(wheel odometry: {'yes' if run['wheel_odometry'] else 'no'}, gyro: "
                                 f"{'yes' if run['gyro'] else 'no'})."),
                           ("table", ["", "value"],
                            [["first pose found after", _fmt(loc["converged_s"], " s", 1)],
                             ["share of scans tracking", f"{100 * loc['tracking_share']:.1f} %"],
                             ["median spread while tracking", _fmt(loc["spread_xy_median_m"], " m")],
                             ["median match score", _fmt(loc["score_median"])],
                             ["lost stretches", str(len(loc["lost"]))]])]
    look = _look_alike_text(loc.get("search"))
    if look:
        blocks.append(("p", look))
    if loc["lost"]:
        blocks.append(("table", ["lost at (s)", "found again at (s)", "lasted (s)"],
                       [[f"{s['start_s']:.1f}", _fmt(s["recovered_s"], "", 1), _fmt(s["lasted_s"], "", 1)]
                        for s in loc["lost"]]))
    tr = m.get("truth")
    if tr:
        a, w = tr["after_convergence"], tr["while_tracking"]
        blocks += [("h", 2, "Against the log's ground truth (no alignment)"),
                   ("table", ["", "position RMSE", "position max", "heading RMSE", "poses"],
                    [["after the first pose found", _fmt(a["position_m"].get("rmse"), " m"),
                      _fmt(a["position_m"].get("max"), " m"), _fmt(a["heading_deg"].get("rmse"), "°", 2),
                      a["position_m"]["n"]],
                     ["while tracking", _fmt(w["position_m"].get("rmse"), " m"), _fmt(w["position_m"].get("max"), " m"),
                      _fmt(w["heading_deg"].get("rmse"), "°", 2), w["position_m"]["n"]]]),
                   ("p", f"Within 0.1 m and 2° of the truth from {_fmt(tr['within_0.1m_2deg_from_s'], ' s', 1)} on.")]
    if run["warnings"]:
        blocks += [("h", 2, "Warnings"), ("list", run["warnings"])]
    blocks += [("h", 2, "Trajectory and confidence"),
               ("images", [(traj, "The poses over the map, by status (searching, tracking, lost)"),
                           (conf, "Confidence over time: the particles' spread, the match score, augmented MCL's "
                                  "w_fast/w_slow" + (", the error against the truth" if tr else ""))])]
    for name, text in (("report.md", to_markdown(blocks)), ("report.html", to_html(blocks))):
        p = out / name
        tmp = p.with_name(p.name + ".partial")
        tmp.write_text(text)
        os.replace(tmp, p)


def save(out: Path, result: LocalizeResult, inp, grid, cfg, m: dict, truth: bool = True) -> None:
    """Every file of LOCALIZE_FILES into `out`."""
    from kosmap.backend.trajio import write_tum
    from kosmap.mapping.config import write_config

    gt = inp.ground_truth if truth else None
    write_tum(out / "trajectory.tum", result.stamps, result.poses)
    write_confidence(out / "confidence.csv", result)
    tmp = out / "metrics.json.partial"
    tmp.write_text(json.dumps(json_safe(m), indent=2))
    os.replace(tmp, out / "metrics.json")
    traj, conf = figures(out, result, grid, gt)
    report(out, m, traj, conf)
    write_mcap(out / "kosmap.mcap", result, grid, gt)
    write_config(cfg, out / "config.toml")
