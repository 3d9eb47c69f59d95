"""`kosmap compare A.yaml B.yaml|--blueprint BP`: align map A to a reference, score it, write JSON, Markdown,
an overlay picture and the effective config."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.frontend.errors import KosmapError
from kosmap.tools import options as O


def run_compare(a_path: Path, b_path: Path | None, blueprint: Path | None, blueprint_scale: float | None,
                no_align: bool, out: Path, cfg) -> dict:
    """Load, align, score; then write everything (nothing is written when loading or scoring fails)."""
    from kosmap.mapping.compare import compare, metrics_markdown, overlay_picture
    from kosmap.mapping.config import config_dict
    from kosmap.mapping.mapio import _atomic_write_bytes, read_blueprint, read_map_server, write_png
    from kosmap.mapping.runtime.outdir import check_out, writing

    if (b_path is None) == (blueprint is None):
        raise KosmapError("give exactly one reference: a second map (B.yaml) or --blueprint BP")
    if blueprint_scale is not None and blueprint is None:
        raise KosmapError("--blueprint-scale belongs to --blueprint (a plain image's metres per pixel)")
    out = check_out(out)  # empty, a file, under a file, not writable: refused before the maps are read
    if no_align:
        cfg.compare.align = False
    a = read_map_server(a_path)
    if blueprint is not None:
        b = read_blueprint(blueprint, blueprint_scale, cfg.compare.blueprint_dark)
        ref = {"blueprint": str(blueprint), "blueprint_scale": blueprint_scale}
    else:
        b = read_map_server(b_path)
        ref = {"b": str(b_path)}
    result = compare(a, b, cfg.compare)
    metrics = {"a": str(a_path), **ref, **result.metrics}
    md = metrics_markdown(metrics, f"{a_path.name} vs {(blueprint or b_path).name}")
    overlay = overlay_picture(result)

    import tomli_w

    inputs = (a_path, a_path.with_suffix(".png"), a_path.with_suffix(".pgm"), b_path, blueprint)
    with writing(out, COMPARE_FILES, inputs=inputs, command="compare") as stage:  # replace the last comparison's
        _atomic_write_bytes(stage / "compare.json", (json.dumps(metrics, indent=2) + "\n").encode())
        _atomic_write_bytes(stage / "compare.md", md.encode())
        write_png(overlay, stage / "overlay.png")
        _atomic_write_bytes(stage / "config.toml", ("# kosmap effective configuration\n" + tomli_w.dumps(config_dict(cfg))).encode())
    return {"metrics": metrics, "markdown": md}


COMPARE_FILES = ("compare.json", "compare.md", "overlay.png", "config.toml")  # what `kosmap compare` writes


def register(app: typer.Typer) -> None:
    @app.command()
    def compare(
        a: Annotated[Path, typer.Argument(help="Map under test: a map_server .yaml.")],
        b: Annotated[Optional[Path], typer.Argument(help="Reference map: a map_server .yaml.")] = None,
        out: Annotated[Path, typer.Option("--out", "-o", parser=O.out_folder, help="Directory for compare.json, compare.md, overlay.png, config.toml.")] = Path("compare_out"),
        blueprint: Annotated[Optional[Path], typer.Option("--blueprint", help="Reference blueprint: a map_server .yaml or a plain image (walls = dark pixels).")] = None,
        blueprint_scale: Annotated[Optional[float], typer.Option("--blueprint-scale", help="Metres per pixel of a plain-image blueprint.")] = None,
        no_align: Annotated[bool, typer.Option("--no-align", help="The frames already agree: score without aligning.")] = False,
        config: O.ConfigOpt = None, set_: O.SetOpt = None,
    ) -> None:
        """Align map A to map B (or a blueprint) from any start, then print precision, recall, F1, distances and
        free-space agreement at each tolerance; write them with an overlay (A red, B green, agreement black)."""
        cfg = O.make_config(config, set_)
        res = run_compare(a, b, blueprint, blueprint_scale, no_align, out, cfg)
        print(res["markdown"])
        print(f"wrote {out / 'compare.json'}, {out / 'compare.md'}, {out / 'overlay.png'}, {out / 'config.toml'}")
