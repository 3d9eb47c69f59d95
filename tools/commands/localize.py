"""`kosmap localize LOG --map MAP --out DIR`: where the robot was, in a prior map or a blueprint (Monte Carlo
localization, mapping/localize.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.tools import options as O
from kosmap.tools.progress import seconds_bar


def register(app: typer.Typer) -> None:
    @app.command()
    def localize(
        log: Annotated[Path, typer.Argument(help="Log file: .mcap (ROS 2), .bag (ROS 1) or .clf (CARMEN).")],
        map_: Annotated[Path, typer.Option("--map", help="The map: a map_server .yaml (a build's map_*.yaml, any map_saver map) or a plain blueprint image with --map-scale.")],
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder (trajectory, confidence, metrics, report, MCAP, config).")],
        map_scale: Annotated[Optional[float], typer.Option("--map-scale", help="Metres per pixel of a plain blueprint image.")] = None,
        initial_pose: Annotated[Optional[str], typer.Option("--initial-pose", help="x,y,yaw (m, m, degrees) where the log starts, in the map's frame; without it the pose is searched for over the whole map.")] = None,
        source: Annotated[str, typer.Option("--source", help="Scans to localize with: kos (the depth camera's KOS obstacle scan) or laser.")] = "kos",
        ground_truth: Annotated[Optional[Path], typer.Option("--ground-truth", help="TUM trajectory in the map's frame to score against instead of the log's ground-truth topic (e.g. the `kosmap slam` run that built the map).")] = None,
        no_truth: Annotated[bool, typer.Option("--no-truth", help="Ignore the log's ground-truth topic (a map in another frame than the truth).")] = False,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")] = False,
        workers: Annotated[int, typer.Option("--workers", help="--source kos: processes for FSPF+ and KOS (0 = serial, here).")] = 0,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, scan_topic: O.ScanTopicOpt = None, odom_topic: O.OdomTopicOpt = None,
        depth_topic: O.DepthTopicOpt = None, imu_topic: O.ImuTopicOpt = None,
    ) -> None:
        """Monte Carlo localization (KLD-sampling, augmented MCL recovery, poses refined against the map) of LOG's
        scans in MAP; writes trajectory.tum (map frame), confidence.csv, metrics.json, report.md/html with
        localization.png and confidence.png, kosmap.mcap and config.toml into --out."""
        from kosmap.frontend.errors import KosmapError
        from kosmap.mapping import localize as L
        from kosmap.mapping.locinput import read_input
        from kosmap.mapping.localize_output import LOCALIZE_FILES, metrics, save
        from kosmap.mapping.runtime.outdir import check_out, writing

        out = check_out(out)
        if source not in ("kos", "laser"):
            raise KosmapError(f"--source {source!r} must be kos (the depth camera) or laser")
        if not log.is_file():
            raise KosmapError(f"log {log} does not exist; give a .mcap, .bag or .clf file")
        cfg = O.make_config(config, set_, depth_topic=depth_topic, scan_topic=scan_topic, odom_topic=odom_topic,
                            imu_topic=imu_topic)
        grid = L.load_map(map_, map_scale)
        z_max = cfg.depth.max_depth if source == "kos" else cfg.localize.max_range
        f = L.field_for(grid, cfg.localize, min(z_max, cfg.localize.max_range))
        pose0 = None
        if initial_pose is not None:
            pose0 = L.parse_pose(initial_pose)
            L.check_initial_pose(f, pose0)
        with seconds_bar("read", "{task.fields[t]:.0f}/{task.total:.0f} s of log", quiet) as tick:
            inp = read_input(log, cfg, source, progress=tick, workers=workers)
        if ground_truth is not None:
            from kosmap.backend.trajio import read_tum

            inp.ground_truth = read_tum(ground_truth)
        truth = not no_truth and inp.ground_truth is not None
        if truth:
            L.check_truth_frame(f, inp.ground_truth)
        with writing(out, LOCALIZE_FILES, inputs=(log, map_, config), command="localize") as stage:
            with seconds_bar("localize", "{task.fields[t]:.0f}/{task.total:.0f} s of log", quiet) as tick:
                result = L.localize(inp, f, cfg.localize, pose0, progress=tick)
            m = metrics(result, inp, cfg, str(map_), truth)
            save(stage, result, inp, grid, cfg, m, truth)  # moved into --out when complete
        if quiet:
            return
        run, loc = m["run"], m["localization"]
        conv = loc["converged_s"]
        print(f"{run['scans']} {source} scans over {run['duration_s']:.0f} s: "
              + (f"pose found after {conv:.1f} s" if conv is not None else "the pose was never found")
              + f", {len(loc['lost'])} lost stretch(es); {run['realtime_factor']:.0f}× real time")
        if "truth" in m:
            a = m["truth"]["after_convergence"]
            if a["position_m"]["n"]:
                print(f"against the ground truth after that: position RMSE {a['position_m']['rmse']:.3f} m, "
                      f"heading RMSE {a['heading_deg']['rmse']:.2f}°")
        for w in run["warnings"]:
            print(f"warning: {w}", file=sys.stderr)
        print(f"wrote {', '.join(LOCALIZE_FILES)} to {out}")
