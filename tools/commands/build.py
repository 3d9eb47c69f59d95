"""`kosmap build LOG --out DIR [--blueprint BP.yaml]`: every map of a log, compared, with a report (mapping/build/)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.frontend.errors import KosmapError
from kosmap.tools import options as O


def print_headline(metrics: dict, out: Path) -> None:
    """The report's place and its headline numbers (what `kosmap build` and `kosmap demo` print)."""
    from kosmap.mapping.report import consistency_text, headline, odometry_noise_text, run_warnings

    h = headline(metrics)
    if h["partial"]:
        print(f"PARTIAL: interrupted after {metrics['interrupted_at_s']:.1f} s of {metrics['log']['duration_s']:.1f} s "
              f"of log; the outputs cover only that part")
    labels = {k: f"{metrics['maps'].get(c['a'], {}).get('label', c['a'])} vs {c['b'] if c['b'] == 'blueprint' else metrics['maps'].get(c['b'], {}).get('label', c['b'])}"
              for k, c in metrics["comparisons"].items()}
    width = max([len(v) for v in labels.values()] + [10])
    for k, f1 in h["f1"].items():
        seen = h["f1_seen"].get(k)
        print(f"  F1 at 0.10 m  {labels[k]:<{width}}  {f1:.3f}" + ("" if seen is None else f"   (walls seen: {seen:.3f})"))
    for k, ate in h["ate"].items():
        print(f"  ATE RMSE      {('KOS' if k == 'kos' else 'laser') + ' SLAM':<{width}}  {ate:.3f} m")
    for k, s in metrics.get("slam", {}).items():  # without ground truth too
        print(f"  consistency   {('KOS' if k == 'kos' else 'laser') + ' SLAM':<{width}}  "
              f"{consistency_text(s.get('consistency') or {})}")
        if (s.get("odometry_noise") or {}).get("measured"):  # against the scan matcher while running
            print(f"  odometry      {('KOS' if k == 'kos' else 'laser') + ' SLAM':<{width}}  "
                  f"{odometry_noise_text(s['odometry_noise'])}")
    t = metrics["timing"]
    print(f"  {t['total_s']:.1f} s for {t['log_s']:.1f} s of log: {t['realtime_factor']:.1f}× real time")
    for w in run_warnings(metrics):  # the run's, and a map that saw no obstacle (a KOS level out of the camera's sight)
        print(f"warning: {w}", file=sys.stderr)
    print(f"report: {out / 'report.html'} (and report.md; maps, trajectories, metrics.json, kosmap.mcap in {out})")


def _auto_mount(log: Path, cfg, quiet: bool):
    """--set depth.mount=auto: the depth camera's pitch, roll and height from the log's floor planes (kosmap planes'
    mount calibration, docs/planes.md) replace the given mount for this build."""
    from dataclasses import replace

    from kosmap.mapping.planes.classes import estimate_mount

    est, n = estimate_mount(log, cfg)
    if est is None:
        raise KosmapError(f"depth.mount=auto: no floor plane in {n} depth frames of {log}; give the mount in "
                          f"[depth] mount_xyz / mount_rpy_deg (or /tf_static) instead")
    xyz = est["given_xyz"]
    if not quiet:
        print(f"mount from the floor ({est['frames']} frames): pitch {est['pitch_deg']:.2f}°, roll "
              f"{est['roll_deg']:.2f}°, height {est['height_m']:.3f} m (given: pitch {est['given_pitch_deg']:.2f}°, "
              f"roll {est['given_roll_deg']:.2f}°, height {est['given_height_m']:.3f} m)", file=sys.stderr)
    depth = replace(cfg.depth, mount="config", mount_xyz=[xyz[0], xyz[1], est["height_m"]],
                    mount_rpy_deg=[est["roll_deg"], est["pitch_deg"], est["given_yaw_deg"]])
    return replace(cfg, depth=depth)


def register(app: typer.Typer) -> None:
    @app.command()
    def build(
        log: Annotated[Path, typer.Argument(help="Log: .mcap (ROS 2) or .bag (ROS 1) with depth images and/or a laser, or .clf (CARMEN: laser and odometry).")],
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder (maps, trajectories, report, MCAP, metrics).")] = Path("build_out"),
        blueprint: Annotated[Optional[Path], typer.Option("--blueprint", help="Floor blueprint to compare the maps with: a map_server .yaml, or a plain image (walls = dark pixels) with --blueprint-scale.")] = None,
        blueprint_scale: Annotated[Optional[float], typer.Option("--blueprint-scale", help="Metres per pixel of a plain-image blueprint (as for `kosmap compare`).")] = None,
        workers: Annotated[Optional[int], typer.Option("--workers", "-j", help="Processes for FSPF+ and KOS (default: every core; 0 = serial). The maps are the same.")] = None,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")] = False,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, depth_topic: O.DepthTopicOpt = None,
        info_topic: O.InfoTopicOpt = None, scan_topic: O.ScanTopicOpt = None, odom_topic: O.OdomTopicOpt = None,
        imu_topic: O.ImuTopicOpt = None,
    ) -> None:
        """FSPF+ → KOS → SLAM → maps for the depth camera(s) and, when the log has one, the laser; the maps compared
        with each other and the blueprint; a report (report.html) with maps, overlays, trajectories and timings.
        Ctrl-C stops reading and writes what is done, marked partial (exit code 130), unless --out holds a complete
        earlier build, which is then kept; a second Ctrl-C aborts. A run that fails or is stopped leaves --out as it
        was: its files replace the previous build's only when it completes."""
        from kosmap.mapping.build import build as run
        from kosmap.tools.progress import build_bar

        cfg = O.make_config(config, set_, depth_topic, info_topic, scan_topic, odom_topic, imu_topic)
        if blueprint_scale is not None and blueprint is None:
            raise KosmapError("--blueprint-scale belongs to --blueprint (a plain image's metres per pixel)")
        if cfg.depth.mount == "auto":
            cfg = _auto_mount(log, cfg, quiet)
        with build_bar(quiet) as tick:
            res = run(log, out, cfg, blueprint=blueprint, workers=workers, on_progress=tick,
                      say=None if quiet else (lambda m: print(m, file=sys.stderr)), blueprint_scale=blueprint_scale,
                      reads=() if config is None else (config,))
        if not quiet:
            print_headline(res.metrics, out)
        else:  # what was skipped or doubtful is never silent
            from kosmap.mapping.report import run_warnings

            for w in run_warnings(res.metrics):
                print(f"warning: {w}", file=sys.stderr)
        if res.partial:
            raise typer.Exit(130)  # like an interrupted command, though its outputs were written (marked partial)
