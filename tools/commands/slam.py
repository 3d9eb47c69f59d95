"""`kosmap slam LOG --out DIR`: SLAM over a log's laser scans or its depth camera's KOS scans, scored when a
reference is given (or against the log's own ground-truth topic)."""

from __future__ import annotations


import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.tools import options as O
from kosmap.tools.progress import seconds_bar

SLAM_FILES = ("trajectory.tum", "keyframes.tum", "graph.g2o", "metrics.json", "map.png", "map.pgm", "map.yaml",
              "config.toml")  # what `kosmap slam` writes (mapping/slam.py save_run)


def register(app: typer.Typer) -> None:
    @app.command()
    def slam(
        log: Annotated[Path, typer.Argument(help="Log file: .mcap (ROS 2), .bag (ROS 1) or .clf (CARMEN).")],
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder (trajectory, graph, map, metrics, config).")],
        source: Annotated[str, typer.Option("--source", help="Scans to map from: laser, or kos (the depth camera's KOS scan named by [build] slam_scan).")] = "laser",
        relations: Annotated[Optional[Path], typer.Option("--relations", help="Kümmerle .relations file to score against.")] = None,
        ground_truth: Annotated[Optional[Path], typer.Option("--ground-truth", help="TUM ground-truth trajectory to score against.")] = None,
        no_map: Annotated[bool, typer.Option("--no-map", help="Skip the occupancy grid (map.png, map.pgm/yaml).")] = False,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")] = False,
        workers: Annotated[int, typer.Option("--workers", help="--source kos: processes for FSPF+ and KOS (0 = serial, here).")] = 0,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, scan_topic: O.ScanTopicOpt = None, odom_topic: O.OdomTopicOpt = None,
        depth_topic: O.DepthTopicOpt = None, imu_topic: O.ImuTopicOpt = None,
    ) -> None:
        """Scan-to-submap odometry, loop closure and a gtsam pose graph over LOG; writes trajectory.tum,
        keyframes.tum, graph.g2o, metrics.json, map.png + map.pgm/map.yaml and config.toml into --out."""
        from kosmap.mapping.runtime.outdir import check_out, writing
        from kosmap.mapping.slam import build_map, evaluate, run_slam, save_run, summary

        out = check_out(out)  # before the run, not after it
        cfg = O.make_config(config, set_, depth_topic=depth_topic, scan_topic=scan_topic, odom_topic=odom_topic,
                            imu_topic=imu_topic)
        if relations is not None and not relations.is_file():
            from kosmap.backend.metrics import MetricsError

            raise MetricsError(f"relations file {relations} does not exist; give a Kümmerle .relations file")
        with writing(out, SLAM_FILES, inputs=(log, relations, ground_truth, config), command="slam") as stage:
            with seconds_bar("slam", "{task.fields[t]:.0f}/{task.total:.0f} s of log", quiet) as tick:
                result = run_slam(log, cfg, source, progress=tick, keep_scans=not no_map, workers=workers)
            metrics = evaluate(result, relations, ground_truth)
            grid = None if no_map else build_map(result, cfg.grid)
            paths = save_run(result, stage, cfg, metrics, grid)  # moved into --out when complete
        for w in result.warnings:  # also under --quiet: what was skipped or doubtful is never silent
            print(f"warning: {w}", file=sys.stderr)
        if quiet:
            return
        t = result.timings
        print(f"{len(result.stamps_ns)} scans, {len(result.keyframes)} keyframes, {len(result.loops)} loops; "
              f"{t['total']:.1f} s for {result.duration_s:.0f} s of log ({result.realtime_factor:.0f}× real time)")
        if "relations" in metrics:
            m = metrics["relations"]
            print(f"relations ({m['n']}): abs trans {m['abs_trans']['mean']:.4f} ± {m['abs_trans']['std']:.4f} m, "
                  f"abs rot {m['abs_rot_deg']['mean']:.3f} ± {m['abs_rot_deg']['std']:.3f}°")
        if "loop_precision" in metrics:
            lp = metrics["loop_precision"]
            print(f"loop precision: {lp['correct']}/{lp['checked']} = {lp['precision']:.3f} "
                  f"(within {lp['trans_tol']} m and {lp['rot_tol_deg']}°)")
        if "ate" in metrics:
            a = metrics["ate"]
            print(f"ATE: rmse {a['rmse']:.4f} m, max {a['max']:.4f} m ({a['n']} poses)"
                  + (f"; wheel odometry alone {metrics['ate_odometry']['rmse']:.4f} m" if "ate_odometry" in metrics else ""))
        run = summary(result)  # what the graph calibrated: the wheels' distance scale, the gyro's bias
        cal = ([f"wheel odometry distance scale {run['odometry_scale']:.4f}"] if run.get("odometry_scale") is not None else []) + \
              ([f"gyro bias {run['gyro_bias_deg_s']:+.4f} °/s"] if run.get("gyro_bias_deg_s") is not None else [])
        hd = run.get("heading")
        if hd and hd["priors"]:
            cal.append(f"building axes {hd['axis_deg']:+.2f}° (heading priors on {hd['priors']} of {run['keyframes']} keyframes)")
        if cal:
            print("estimated: " + ", ".join(cal))
        from kosmap.mapping.report import consistency_text, odometry_noise_text

        if (run.get("odometry_noise") or {}).get("measured"):  # against the scan matcher (backend/odomnoise.py)
            print(f"wheel odometry measured against the scans: {odometry_noise_text(run['odometry_noise'])}")
        print(f"self-consistency: {consistency_text(result.consistency)}")
        names = [n for k, p in paths.items()  # map.yaml's image, map.pgm, is written beside it
                 for n in ((p.with_suffix(".pgm").name, p.name) if k == "map_yaml" else (p.name,))]
        print(f"wrote {', '.join(names)} to {out}")
