"""What `kosmap batch` writes beside the per-log folders: the merged map and the change map of the runs
(mapping/fleet.py), and the fleet's table as batch.json, batch.md and batch.html (rendered like report.html)."""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path

from kosmap.frontend.errors import KosmapError
from kosmap.mapping.batch import TOL, LogRecord
from kosmap.mapping.config import Config
from kosmap.mapping.grid import OccupancyGrid
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.reportdoc import to_html, to_markdown

MERGED, CHANGES = "map_merged", "changes"
BATCH_FILES = ("batch.json", "batch.md", "batch.html", f"{MERGED}.png", f"{MERGED}.pgm", f"{MERGED}.yaml",
               f"{CHANGES}.png", f"{CHANGES}.pgm", f"{CHANGES}.yaml")


def fleet_map_name(records: list[LogRecord], cfg: Config, requested: str | None) -> str | None:
    """The map the runs are merged and compared by: `requested` (--map); else the laser map when every run has one
    (the laser measures farther and wider than the depth camera: it scores the higher F1 in every build,
    docs/build.md), else the KOS map SLAM ran on; None when no run that built has it."""
    have = [set(r.maps) for r in records if r.ok]
    names = [requested] if requested else ["laser", f"kos_{cfg.build.slam_scan}"]
    for name in names:
        if have and all(name in h for h in have):
            return name
    counts = {n: sum(n in h for h in have) for n in names}
    best = max(names, key=lambda n: counts[n])
    return best if counts[best] else None


def fleet_outputs(out: Path, dest: Path, records: list[LogRecord], blueprint: OccupancyGrid | None, cfg: Config,
                  map_name: str | None) -> dict:
    """Merge and compare the runs' `map_name` maps (in out/<log name>/); write map_merged.* and changes.* into
    `dest`; what batch.json says of them."""
    from kosmap.mapping.compare import CompareError, compare
    from kosmap.mapping.fleet import change_picture, fleet
    from kosmap.mapping.gridlog import read_build_grid
    from kosmap.mapping.mapio import grid_picture, write_map_server, write_png

    runs = [r for r in records if r.ok and map_name in r.maps]
    if map_name is None or not runs:
        what = f"map_{map_name}" if map_name else "a map"
        return {"map": map_name, "error": f"no log that built made {what} to merge"}
    grids, names, unread = [], [], []
    for r in runs:  # each cell's probability, the evidence the merge sums (the map_server files keep 3 values)
        try:
            grids.append(read_build_grid(out / r.name / "kosmap.mcap", map_name))
            names.append(r.name)
        except KosmapError as e:
            unread.append({"name": r.name, "error": str(e)})
    if not grids:
        return {"map": map_name, "error": "; ".join(u["error"] for u in unread)}
    try:
        f = fleet(names, grids, blueprint, cfg.compare, cfg.grid)
    except CompareError as e:
        return {"map": map_name, "error": str(e)}
    write_map_server(f.merged, dest / f"{MERGED}.yaml")
    write_png(grid_picture(f.merged), dest / f"{MERGED}.png")
    write_map_server(f.changes, dest / f"{CHANGES}.yaml")
    write_png(change_picture(f), dest / f"{CHANGES}.png")
    doc = {"map": map_name, "reference": "blueprint" if blueprint is not None else runs[0].name,
           "tolerance_m": f.tolerance_m,
           "runs": [{"name": fr.name, "error": fr.error, **(fr.alignment.as_dict() if fr.alignment else {})}
                    for fr in f.frames] + unread,
           "merged": {"yaml": f"{MERGED}.yaml", "png": f"{MERGED}.png",
                      "runs": sum(fr.alignment is not None for fr in f.frames)},
           "changes": {"yaml": f"{CHANGES}.yaml", "png": f"{CHANGES}.png",
                       "cells": int((f.changes.data == 100).sum()), "regions": [asdict(g) for g in f.regions]}}
    if blueprint is not None:
        try:
            t = compare(f.merged, blueprint, cfg.compare).metrics["tolerances"][TOL]
            doc["merged"].update(f1=t["f1"], f1_seen=t["f1_observed"])
        except CompareError as e:
            doc["merged"]["f1_error"] = str(e)
    return doc


def _f(v, digits: int = 3) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def log_table(records: list[LogRecord], map_name: str | None) -> tuple[list[str], list[list[str]]]:
    """The fleet table: one row per log."""
    maps = [m for m in dict.fromkeys([map_name, "laser"]) if m]
    head = ["log", "status", "log s", "build s", "× real time"]
    for m in maps:
        head += [f"F1 {m}", f"F1 seen {m}"]
    head += ["ATE KOS m", "ATE laser m", "warnings", "failure"]
    rows = []
    for r in records:
        row = [r.name, r.status, _f(r.duration_s, 1), _f(r.build_s, 1), _f(r.realtime_factor, 1)]
        for m in maps:
            row += [_f(r.f1.get(m)), _f(r.f1_seen.get(m))]
        row += [_f(r.ate.get("kos")), _f(r.ate.get("laser")), "; ".join(r.warnings) or "–", r.error or "–"]
        rows.append(row)
    return head, rows


def _blocks(out: Path, doc: dict) -> list[tuple]:
    """batch.md / batch.html as report.py's blocks."""
    recs = [LogRecord(**r) for r in doc["logs"]]
    s = doc["summary"]
    fl = doc["fleet"]
    B: list[tuple] = [("h", 1, f"kosmap batch: {s['logs']} logs"),
                      ("p", f"{s['built']} built, {s['skipped']} unchanged since the last batch (skipped), "
                            f"{s['failed']} failed; {s['log_s']:.0f} s of log; the whole batch took "
                            f"{doc['wall_s']:.1f} s on {doc['cluster']['where']}. F1 at {TOL} m against the blueprint.")]
    if s["failed"]:
        failed = "; ".join(f"{r.name}: {r.error}" for r in recs if not r.ok)
        B.append(("warn", f"{s['failed']} log(s) failed: {failed}"))
    B += [("h", 2, "Logs"), ("table", *log_table(recs, fl.get("map")))]
    B.append(("h", 2, f"All runs in one frame ({fl.get('map')} maps)"))
    if fl.get("error"):
        B.append(("warn", f"no merged or change map: {fl['error']}"))
        return B
    m = fl["merged"]
    first = fl["runs"][0]["name"]
    onto = f"the run {first}" + (", then together onto the blueprint," if fl["reference"] == "blueprint" else "")
    f1 = f"; the merged map's F1 {_f(m.get('f1'))}, over the walls seen {_f(m.get('f1_seen'))}" if "f1" in m else ""
    B.append(("p", f"{m['runs']} run(s) aligned onto {onto} and merged (log-odds summed){f1}."))
    B.append(("table", ["run", "aligned", "x m", "y m", "yaw °", "inliers", "rms m"],
              [[r["name"], "yes" if r.get("aligned") else f"no: {r.get('error')}", _f(r.get("x")), _f(r.get("y")),
                _f(r.get("yaw_deg"), 2), _f(r.get("inliers")), _f(r.get("rms"))] for r in fl["runs"]]))
    ch = fl["changes"]
    B.append(("h", 2, "Changes between runs"))
    B.append(("p", f"Cells occupied in some runs and clearly free (no wall within {fl['tolerance_m']:.2f} m) in "
                   f"others: {len(ch['regions'])} region(s), largest first."))
    if ch["regions"]:
        B.append(("table", ["#", "x m", "y m", "area m²", "size m", "occupied in", "free in"],
                  [[k, _f(g["x"], 2), _f(g["y"], 2), _f(g["area_m2"], 3),
                    f"{g['box'][2] - g['box'][0]:.2f} × {g['box'][3] - g['box'][1]:.2f}",
                    ", ".join(g["occupied_in"]), ", ".join(g["free_in"])] for k, g in enumerate(ch["regions"], 1)]))
    B.append(("images", [(out / m["png"], "The merged map"),
                         (out / ch["png"], "Changes (red), numbered as in the table, over the merged map")]))
    return B


def write_batch_report(out: Path, doc: dict) -> None:
    """batch.json (everything), batch.md and batch.html (the table, the merged map and the changes)."""
    blocks = _blocks(out, doc)
    for name, text in (("batch.json", json.dumps(json_safe(doc), indent=1) + "\n"), ("batch.md", to_markdown(blocks)),
                       ("batch.html", to_html(blocks))):
        tmp = out / (name + ".partial")
        tmp.write_text(text)
        os.replace(tmp, out / name)


def summary(records: list[LogRecord]) -> dict:
    return {"logs": len(records), "built": sum(r.status == "built" for r in records),
            "skipped": sum(r.status == "skipped" for r in records), "failed": sum(not r.ok for r in records),
            "log_s": float(sum(r.duration_s or 0.0 for r in records)),
            "build_s": float(sum(r.build_s or 0.0 for r in records if r.status == "built"))}
