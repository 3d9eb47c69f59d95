"""`kosmap compare`: end to end on map files, and one clear line (exit 2, nothing written) for bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from kosmap.mapping.grid import OccupancyGrid
from kosmap.mapping.mapio import grid_picture, write_map_server
from tests.mapping.worlds import room, wall_grid
from kosmap.tools.cli import main

WORLD = room() + np.array([0.012, 0.017, 0.012, 0.017])


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def maps(tmp_path):
    a = write_map_server(wall_grid(WORLD, 0.05), tmp_path / "a.yaml")
    b = write_map_server(wall_grid(WORLD, 0.10, transform=(1.0, 0.5, np.radians(100))), tmp_path / "b.yaml")
    bp = wall_grid(WORLD, 0.02, cells_thick=3)
    cv2.imwrite(str(tmp_path / "plan.png"), grid_picture(bp))
    return a, b, tmp_path / "plan.png", bp


def test_compare_two_maps_writes_everything(capsys, tmp_path, maps):
    a, b, _, _ = maps
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "compare", a, b, "--out", out)
    assert code == 0, err
    assert "| 0.10 m |" in stdout and "precision" in stdout
    assert sorted(p.name for p in out.iterdir()) == [".kosmap-outputs", "compare.json", "compare.md", "config.toml",
                                                    "overlay.png"]  # (the list of what it wrote, first)
    m = json.loads((out / "compare.json").read_text())
    assert m["alignment"]["yaw_deg"] == pytest.approx(100.0, abs=0.5)
    assert np.hypot(m["alignment"]["x"] - 1.0, m["alignment"]["y"] - 0.5) < 0.1
    assert m["tolerances"]["0.10"]["f1"] > 0.97
    assert "[compare]" in (out / "config.toml").read_text()
    assert cv2.imread(str(out / "overlay.png")) is not None


def test_compare_against_plain_image_blueprint(capsys, tmp_path, maps):
    a, _, plan, bp = maps
    out = tmp_path / "bp_out"
    code, stdout, err = run(capsys, "compare", a, "--blueprint", plan, "--blueprint-scale", "0.02", "--out", out,
                            "--set", "compare.tolerances=[0.1]")
    assert code == 0, err
    m = json.loads((out / "compare.json").read_text())
    assert list(m["tolerances"]) == ["0.10"]
    # the plan's walls are 3 px (6 cm) thick, the map's 5 cm cells: all match within 0.10 m
    assert m["tolerances"]["0.10"]["f1"] > 0.97
    # the plan's origin is its lower-left pixel: the alignment finds the map's offset from it
    assert m["alignment"]["x"] == pytest.approx(-bp.origin[0], abs=0.05)


def test_no_align_flag(capsys, tmp_path, maps):
    a, b, _, _ = maps
    code, stdout, err = run(capsys, "compare", a, b, "--no-align", "--out", tmp_path / "na")
    assert code == 0, err
    text = (tmp_path / "na" / "compare.json").read_text()
    assert "NaN" not in text  # strict JSON
    m = json.loads(text)
    assert m["alignment"]["aligned"] is False and m["tolerances"]["0.20"]["f1"] < 0.3
    assert "--no-align" in stdout


def _bad_cases(tmp_path, a, plan):
    (tmp_path / "text.png").write_text("not an image")
    (tmp_path / "nokeys.yaml").write_text("image: a.pgm\nresolution: 0.05\n")
    (tmp_path / "zero.yaml").write_text("image: a.pgm\nresolution: 0\norigin: [0, 0, 0]\n")
    (tmp_path / "notimg.yaml").write_text("image: text.png\nresolution: 0.05\norigin: [0, 0, 0]\n")
    blank = OccupancyGrid(np.zeros((20, 20), np.int8), 0.05)
    write_map_server(blank, tmp_path / "blank.yaml")
    return [
        ((a, tmp_path / "nokeys.yaml"), ("lacks origin",)),
        ((a, tmp_path / "zero.yaml"), ("resolution 0", "positive")),
        ((tmp_path / "notimg.yaml", a), ("not an image",)),
        ((a, "--blueprint", tmp_path / "text.png", "--blueprint-scale", "0.05"), ("not an image",)),
        ((a, "--blueprint", plan), ("--blueprint-scale",)),
        ((a, "--blueprint", plan, "--blueprint-scale", "0"), ("positive",)),
        ((a, "--blueprint", plan, "--blueprint-scale", "-1"), ("positive",)),
        ((a,), ("exactly one reference",)),
        ((a, a, "--blueprint", plan), ("exactly one reference",)),
        ((a, tmp_path / "missing.yaml"), ("does not exist",)),
        ((tmp_path / "text.png", a), ("YAML",)),
        ((a, tmp_path / "blank.yaml"), ("fewer than 3 wall cells",)),
        ((a, a, "--set", "compare.tolerances=[0]"), ("tolerances",)),
    ]


def test_bad_input_one_line_exit_2_nothing_written(capsys, tmp_path, maps):
    a, _, plan, _ = maps
    for i, (args, words) in enumerate(_bad_cases(tmp_path, a, plan)):
        out = tmp_path / f"bad{i}"
        code, stdout, err = run(capsys, "compare", *args, "--out", out)
        assert code == 2, (args, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("kosmap: error: "), (args, err)
        assert "Traceback" not in err
        for w in words:
            assert w in lines[0], (w, lines[0])
        assert not out.exists(), args
