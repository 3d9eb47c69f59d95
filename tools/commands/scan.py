"""`kosmap scan LOG --levels 0.3,0.75,1.5 --out DIR`: the multi-level Kinect Obstacle Scan of every depth frame."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.frontend.errors import KosmapError
from kosmap.tools import options as O


def register(app: typer.Typer) -> None:
    @app.command()
    def scan(
        log: Annotated[Path, typer.Argument(help="Log with depth images: .mcap (ROS 2) or .bag (ROS 1).")],
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Output folder.")] = Path("kos_out"),
        levels: Annotated[Optional[str], typer.Option(help="Scan heights above the floor, m, comma-separated (e.g. 0.3,0.75,1.5).")] = None,
        band: Annotated[Optional[float], typer.Option(help="Half height of each level's band, m (thesis: 0.1).")] = None,
        source: Annotated[Optional[str], typer.Option(help="'planes' (FSPF+ points, the thesis) or 'depth' (every valid point).")] = None,
        figures: Annotated[int, typer.Option(help="How many top-view figures to draw.")] = 3,
        limit: Annotated[Optional[int], typer.Option(help="Stop after this many frames per camera.")] = None,
        config: O.ConfigOpt = None, set_: O.SetOpt = None, depth_topic: O.DepthTopicOpt = None,
        info_topic: O.InfoTopicOpt = None, scan_topic: O.ScanTopicOpt = None, odom_topic: O.OdomTopicOpt = None,
    ) -> None:
        """FSPF+ → KOS on every depth frame: LaserScans per level (+ obstacle, + fused with the laser) in an MCAP,
        the scan points as CSV, top-view figures, stats and the effective config."""
        from kosmap.mapping.kosscan import run_scan
        from kosmap.tools.progress import items_bar

        sets = list(set_ or [])
        if levels is not None:
            try:
                values = [float(v) for v in levels.split(",") if v.strip()]
            except ValueError:
                raise KosmapError(f"--levels '{levels}' must be heights in metres separated by commas, e.g. 0.3,0.75,1.5") from None
            sets.append(f"kos.levels={values}")
        if band is not None:
            sets.append(f"kos.band={band}")
        if source is not None:
            sets.append(f'kos.source="{source}"')
        if limit is not None and limit < 1:
            raise KosmapError(f"--limit {limit} must be at least 1")
        if figures < 0:
            raise KosmapError(f"--figures {figures} must be 0 or more")
        cfg = O.make_config(config, sets, depth_topic, info_topic, scan_topic, odom_topic)
        with items_bar("KOS", "frames") as tick:
            s = run_scan(log, out, cfg, figures=figures, limit=limit, on_progress=tick)
        fill = ", ".join(f"{k} {100 * v:.0f} %" for k, v in s["filled_fraction"].items())
        print(f"{s['steps']} scans per level written to {out / 'kos.mcap'} (levels {s['levels']}, band ±{s['band']} m)")
        print(f"bins filled: {fill}")
        print(f"median FSPF+ {s['fspf_ms_median']:.1f} ms, KOS {s['kos_ms_median']:.2f} ms per frame"
              + ("; fused with the laser" if s["fused"] else ""))
        if s.get("gravity"):
            print(f"gravity: {s['gravity']['from']}")
        if s.get("laser_alignment"):
            from kosmap.mapping.lasercal import KosLaserCal

            print("\n".join(KosLaserCal.lines(s["laser_alignment"])) + f" ({out / 'mount.toml'})")
        for w in s["warnings"]:
            print(f"warning: {w}")
