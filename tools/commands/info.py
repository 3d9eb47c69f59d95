"""`kosmap info LOG`: what a log holds, like `mcap info` and `rosbag info`, plus the topics kosmap would use."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from kosmap.frontend.errors import TopicError
from kosmap.frontend.logs import LogInfo, detect_topics, open_log
from kosmap.frontend.records import CameraModel, DepthFrame
from kosmap.tools import options as O


def log_summary(path: Path, cfg) -> dict:
    """Everything `info` prints, as a dict (also the --json output)."""
    with open_log(path, cfg.topics.on_damage) as log:
        info: LogInfo = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.depth and not det.scan:
            listed = ", ".join(f"{t.name} ({t.type})" for t in info.topics) or "none"
            raise TopicError(f"{path.name} has no depth images and no laser scans (topics: {listed}); if they are "
                             f"there under other names or types, pass --depth-topic / --scan-topic")
        cameras = {}
        for depth_topic in det.depth:
            want = [t for t in (det.info.get(depth_topic), depth_topic) if t]
            cam, frame = None, None
            for rec in log.read(want):
                if isinstance(rec, CameraModel) and cam is None:
                    cam = rec
                elif isinstance(rec, DepthFrame) and frame is None:
                    frame = rec
                if (cam is not None or not det.info.get(depth_topic)) and frame is not None:
                    break
            entry: dict = {}
            if frame is not None:
                entry.update(width=int(frame.image.shape[1]), height=int(frame.image.shape[0]), encoding=frame.encoding,
                             frame_id=frame.frame_id)
            if cam is not None:
                entry.update(width=cam.width, height=cam.height, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy,
                             fov_h_deg=float(__import__("numpy").degrees(cam.fov_h)),
                             fov_v_deg=float(__import__("numpy").degrees(cam.fov_v)), intrinsics="camera_info")
            else:
                entry["intrinsics"] = "field-of-view model ([depth] fov_h_deg, fov_v_deg)"
            cameras[depth_topic] = entry
        dur = info.duration
        return {
            "path": str(path), "format": info.format, "truncated": info.truncated, "notes": info.notes,
            "start": info.start_ns * 1e-9, "end": info.end_ns * 1e-9, "duration": dur, "messages": info.message_count,
            "topics": [{"name": t.name, "type": t.type, "count": t.count,
                        "rate_hz": (t.count / dur if dur > 0 else 0.0)} for t in info.topics],
            "detected": det.as_dict(), "cameras": cameras, "warnings": list(log.warnings),
        }


def check_log(path: Path, cfg) -> dict:
    """Read every message of the log once (what a build would meet): how many were read, and the damage found on
    the way (damaged chunks with their time ranges, undecodable messages), which the index alone does not show."""
    with open_log(path, cfg.topics.on_damage) as log:
        expected = log.info().message_count
        read = sum(1 for _ in log.read())
        return {"messages_read": read, "messages_indexed": expected, "problems": list(log.warnings)}


def _print(s: dict) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    con = Console(highlight=False, soft_wrap=True)
    con.print(f"[bold]path[/]:      {s['path']}")
    con.print(f"[bold]format[/]:    {s['format']}" + ("  [red](truncated)[/]" if s["truncated"] else ""))
    con.print(f"[bold]duration[/]:  {s['duration']:.1f} s  (start {s['start']:.3f}, end {s['end']:.3f})")
    con.print(f"[bold]messages[/]:  {s['messages']}")
    table = Table(box=None, pad_edge=False, show_edge=False)
    for col, just in (("topic", "left"), ("type", "left"), ("count", "right"), ("rate", "right")):
        table.add_column(col, justify=just)
    for t in s["topics"]:
        table.add_row(t["name"], t["type"], str(t["count"]), f"{t['rate_hz']:.2f} Hz")
    con.print(table)
    d = s["detected"]
    con.print("[bold]kosmap will use[/]:")
    for name, key in (("depth", "depth"), ("scan", "scan"), ("odometry", "odom"), ("imu", "imu"),
                      ("ground truth", "ground_truth"), ("tf_static", "tf_static")):
        val = d[key]
        if key == "depth":
            val = ", ".join(f"{t} (info: {d['camera_info'].get(t) or 'none'})" for t in val) if val else None
        con.print(f"  {name + ':':14} {val or '[dim]none[/]'}")
    for topic, c in s["cameras"].items():
        if "fx" in c:
            con.print(f"  camera {topic}: {c['width']}×{c['height']} {c.get('encoding', '')}  fx {c['fx']:.2f}  fy {c['fy']:.2f}"
                      f"  cx {c['cx']:.2f}  cy {c['cy']:.2f}  (FOV {c['fov_h_deg']:.1f}°×{c['fov_v_deg']:.1f}°)")
        elif "width" in c:
            con.print(f"  camera {topic}: {c['width']}×{c['height']} {c['encoding']}  intrinsics from the {escape(c['intrinsics'])}")
    for n in s["notes"]:
        con.print(f"[yellow]note[/]: {escape(n)}")
    for w in s["warnings"]:
        con.print(f"[yellow]warning[/]: {escape(w)}")
    if "check" in s:
        c = s["check"]
        state = "[red]damaged[/]" if c["problems"] else "[green]read whole[/]"
        con.print(f"[bold]check[/]:     {state}: {c['messages_read']} of {c['messages_indexed']} indexed messages read")
        for w in c["problems"]:
            con.print(f"  [red]problem[/]: {escape(w)}")


def register(app: typer.Typer) -> None:
    @app.command()
    def info(
        log: Annotated[Path, typer.Argument(help="Log file: .mcap (ROS 2), .bag (ROS 1) or .clf (CARMEN).")],
        as_json: Annotated[bool, typer.Option("--json", help="Print JSON for scripts.")] = False,
        check: Annotated[bool, typer.Option("--check", help="Also read every message once (as long as a read "
                                            "pass of a build) to find damaged chunks the index does not show.")] = False,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, depth_topic: O.DepthTopicOpt = None,
        info_topic: O.InfoTopicOpt = None, scan_topic: O.ScanTopicOpt = None, odom_topic: O.OdomTopicOpt = None,
        imu_topic: O.ImuTopicOpt = None,
    ) -> None:
        """Show a log's format, duration, topics with counts and rates, and the topics kosmap will use."""
        cfg = O.make_config(config, set_, depth_topic, info_topic, scan_topic, odom_topic, imu_topic)
        summary = log_summary(log, cfg)
        if check:
            summary["check"] = check_log(log, cfg)
        if as_json:
            print(json.dumps(summary, indent=2))
        else:
            _print(summary)
