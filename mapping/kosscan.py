"""`kosmap scan`: a log's depth frames → FSPF+ → multi-level KOS scans, fused with the laser, written out.

Outputs (thesis §5.3, Fig. 5.13–5.20): an MCAP with sensor_msgs/LaserScan per level on /kinect_scan/<level>
(plus the obstacle and fused scans, the laser and /tf_static, so Foxglove overlays them), the scan points as
CSV (the thesis stored them in text files), top-view figures of laser and levels, stats and the config. The
scans themselves come from the KOS stream (mapping/kosstream.py).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kosmap.frontend.errors import LogError, TopicError
from kosmap.frontend.kos import OBSTACLE
from kosmap.frontend.kosframe import KosFrame
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.records import Transform
from kosmap.mapping.config import Config, write_config
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.kosstream import KosStep, ScanRun, kos_steps
from kosmap.mapping.lasercal import KosLaserCal, write_mount_toml
from kosmap.mapping.mapio import save_figure
from kosmap.mapping.runtime.outdir import check_out, writing


def _figure(path: Path, step: KosStep, laser_mount: Transform | None, levels: list[str], t0_ns: int) -> None:
    """Top view like the thesis's Fig. 5.13–5.20: the laser scan and the KOS of each level, overlaid."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6), dpi=110)
    if step.laser is not None:
        p = step.laser.points()
        if laser_mount is not None:
            p = laser_mount.apply(np.column_stack((p, np.zeros(len(p)))))[:, :2]
        ax.scatter(p[:, 0], p[:, 1], s=2, c="0.6", label="laser")
    colours = plt.cm.viridis(np.linspace(0, 0.9, max(1, len(levels))))
    for name, col in zip(levels, colours):
        pts = step.scans[name].points()
        ax.scatter(pts[:, 0], pts[:, 1], s=3, color=col, label=f"KOS {name}")
    pts = step.scans[OBSTACLE].points()
    ax.scatter(pts[:, 0], pts[:, 1], s=6, facecolors="none", edgecolors="r", linewidths=0.5, label="KOS obstacle")
    ax.plot([0], [0], "k^", ms=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, base_link)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"KOS levels and laser, t = {(step.stamp_ns - t0_ns) * 1e-9:.2f} s")
    ax.legend(loc="upper right", fontsize=7, markerscale=3)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def run_scan(log_path: Path, out: Path, cfg: Config, *, figures: int = 3, limit: int | None = None,
             on_progress: Callable[[int, int], None] | None = None) -> dict:
    """Write the KOS scans of every depth frame of `log_path` into `out`; returns (and writes) the summary.
    `on_progress(frames done, frames expected)` is called after each frame."""
    out = check_out(out)
    with open_log(log_path, cfg.topics.on_damage) as log:  # refuse a log without depth before writing anything
        if not detect_topics(log.info().types(), cfg.topics).depth:
            raise TopicError(f"{Path(log_path).name} has no depth image topic; kosmap scan needs one (name it with --depth-topic)")
    with writing(out, SCAN_FILES, inputs=(log_path,), command="scan") as stage:  # replace the last scan's when done
        return _scan_into(log_path, stage, cfg, figures, limit, on_progress)


def laser_alignment(cal: KosLaserCal, run: ScanRun, out: Path) -> dict | None:
    """The camera's yaw and x, y against the laser (mapping/lasercal.py), its warning into the run's, the whole
    mount in out/mount.toml."""
    res = cal.result(next(iter(run.mounts.values()))) if len(run.mounts) == 1 else None
    write_mount_toml(out, res, run.warnings)
    return res


SCAN_FILES = ("config.toml", "kos.mcap", "scan_points.csv", "kos_top_*.png", "summary.json", "mount.toml")  # what a scan writes


def _scan_into(log_path: Path, out: Path, cfg: Config, figures: int, limit: int | None,
               on_progress: Callable[[int, int], None] | None) -> dict:
    """run_scan's work, into a folder claimed for it."""
    from kosmap.frontend.logs.writer import McapWriter

    write_config(cfg, out / "config.toml")
    run = ScanRun()
    levels = [b[0] for b in cfg.kos.bands() if b[0] != OBSTACLE]
    fspf_ms, kos_ms, fill = [], [], {name: [] for name in levels + [OBSTACLE]}
    csv_tmp = out / "scan_points.csv.partial"
    steps = 0
    figure_steps: list[KosStep] = []
    try:
        with McapWriter(out / "kos.mcap") as writer, open(csv_tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["stamp", "scan", "bearing_rad", "range_m", "x_m", "y_m"])
            statics_written = 0

            def on_frame(f: KosFrame) -> None:
                fspf_ms.append(f.fspf_ms)
                kos_ms.append(f.kos_ms)
                if on_progress is not None:
                    on_progress(len(fspf_ms), run.total_frames)

            cal = KosLaserCal(cfg.kos.bands(), 0)
            for step in kos_steps(log_path, cfg, run, limit=limit, on_frame=on_frame):
                cal.cameras = len(run.topics["depth"])
                cal.add(step.scans, step.laser, run.statics)
                while statics_written < len(run.statics):
                    writer.write(run.statics[statics_written], "/tf_static")
                    statics_written += 1
                steps += 1
                if step.laser is not None:
                    writer.write(step.laser)
                for name, scan in step.scans.items():
                    writer.write(scan)
                    ok = np.isfinite(scan.ranges)
                    if name in fill:
                        fill[name].append(ok.mean())
                    a, r = scan.angles[ok], scan.ranges[ok]
                    t = f"{step.stamp_ns * 1e-9:.6f}"
                    w.writerows((t, name, f"{ai:.5f}", f"{ri:.4f}", f"{ri * math.cos(ai):.4f}", f"{ri * math.sin(ai):.4f}")
                                for ai, ri in zip(a, r))
                n_steps = max(1, run.total_frames // max(1, len(run.topics["depth"])))
                if figures and len(figure_steps) < figures and (steps - 1) % max(1, n_steps // figures) == 0:
                    figure_steps.append(step)
    except BaseException:  # interrupted or failed: leave no CSV that looks complete (the MCAP writer aborts itself)
        csv_tmp.unlink(missing_ok=True)
        raise
    if steps == 0:  # every depth frame skipped by the reader: say why, and leave no output looking valid
        why = run.warnings[0].removeprefix(Path(log_path).name + ": ") if run.warnings else "no depth frame could be read"
        raise LogError(f"{Path(log_path).name}: no depth frame gave a KOS scan: {why}")
    csv_tmp.replace(out / "scan_points.csv")
    run.laser_alignment = laser_alignment(cal, run, out)
    for i, step in enumerate(figure_steps):
        _figure(out / f"kos_top_{i}.png", step, run.laser_mount, levels, figure_steps[0].stamp_ns)
    summary = {
        "log": str(log_path), "steps": steps, "topics": run.topics,
        "bearings": {"angle_min": run.bearings.angle_min, "angle_increment": run.bearings.angle_increment,
                     "bins": run.bearings.n} if run.bearings else None,
        "levels": cfg.kos.levels, "band": cfg.kos.band, "source": cfg.kos.source,
        "fspf_ms_median": float(np.median(fspf_ms)) if fspf_ms else None,
        "kos_ms_median": float(np.median(kos_ms)) if kos_ms else None,
        "filled_fraction": {k: float(np.mean(v)) if v else 0.0 for k, v in fill.items()},
        "fused": run.laser_mount is not None, "gravity": run.gravity.as_dict() if run.gravity else None,
        "laser_alignment": run.laser_alignment,
        "warnings": run.warnings,
    }
    (out / "summary.json").write_text(json.dumps(json_safe(summary), indent=2))
    return summary
