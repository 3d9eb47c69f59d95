"""Map files with impossible headers or fields: one line naming the file and the field, before any allocation or
alignment (a PGM claiming 10^10 pixels, an origin of NaN that kept `compare` coarsening its canvas for ever)."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.mapping.compare import CompareError, make_canvas
from kosmap.mapping.grid import OccupancyGrid
from kosmap.mapping.mapio import MAX_MAP_PIXELS, MapError, read_blueprint, read_map_server, write_map_server
from kosmap.tools.cli import main


def _room(tmp_path, name="room") -> OccupancyGrid:
    data = np.zeros((60, 80), np.int8)
    data[[0, -1], :] = 100
    data[:, [0, -1]] = 100
    data[20:25, 30:50] = 100
    g = OccupancyGrid(data, 0.05, (1.0, -2.0, 0.0))
    write_map_server(g, tmp_path / f"{name}.yaml")
    return g


def _yaml(tmp_path, name: str, image: str, resolution="0.05", origin="[0.0, 0.0, 0.0]"):
    p = tmp_path / f"{name}.yaml"
    p.write_text(f"image: {image}\nresolution: {resolution}\norigin: {origin}\nnegate: 0\n"
                 f"occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return p


def _one_line(capsys, code) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("kosmap: error: "), err
    return err[0]


@pytest.mark.parametrize("header", [b"P5\n100000 100000\n255\n", b"P5\n# a comment\n100000 100000\n255\n"])
def test_pgm_header_claiming_10_10_pixels_is_one_line(tmp_path, capsys, header):
    _room(tmp_path)
    (tmp_path / "huge.pgm").write_bytes(header + bytes(1000))
    y = _yaml(tmp_path, "huge", "huge.pgm")
    with pytest.raises(MapError, match=r"huge\.pgm: its header claims 100000×100000 pixels, more than a map"):
        read_map_server(y)
    line = _one_line(capsys, main(["compare", str(y), str(tmp_path / "room.yaml"), "--out", str(tmp_path / "o")]))
    assert f"({MAX_MAP_PIXELS} pixels)" in line
    assert not (tmp_path / "o").exists()


def test_png_header_claiming_10_10_pixels_is_one_line(tmp_path):
    import cv2

    ok, png = cv2.imencode(".png", np.full((4, 4), 254, np.uint8))
    b = bytearray(png.tobytes())
    b[16:24] = (100000).to_bytes(4, "big") * 2  # IHDR width and height (its CRC is then wrong: never decoded)
    (tmp_path / "huge.png").write_bytes(bytes(b))
    with pytest.raises(MapError, match=r"claims 100000×100000 pixels"):
        read_map_server(_yaml(tmp_path, "huge", "huge.png"))
    with pytest.raises(MapError, match=r"claims 100000×100000 pixels"):
        read_blueprint(tmp_path / "huge.png", scale=0.05)


@pytest.mark.parametrize("origin,resolution,words", [
    ("[.nan, 0.0, 0.0]", "0.05", "origin [nan, 0.0, 0.0] must be finite numbers"),
    ("[0.0, .inf, 0.0]", "0.05", "origin [0.0, inf, 0.0] must be finite numbers"),
    ("[0.0, 0.0, .nan]", "0.05", "must be finite numbers"),
    ("[1.0e+300, 0.0, 0.0]", "0.05", "x and y within ±1e+08 m"),
    ("[0.0, 0.0, 0.0]", ".nan", "resolution nan must be a positive number"),
    ("[0.0, 0.0, 0.0]", "1.0e-12", "resolution 1e-12 m/pixel is not a map's: give one between 0.0001 and 1000"),
    ("[0.0, 0.0, 0.0]", "1.0e+9", "is not a map's"),
])
def test_map_yaml_fields_are_validated(tmp_path, capsys, origin, resolution, words):
    _room(tmp_path)
    y = _yaml(tmp_path, "bad", "room.pgm", resolution, origin)
    with pytest.raises(MapError) as e:
        read_map_server(y)
    assert str(e.value).startswith(str(y)) and words in str(e.value)
    line = _one_line(capsys, main(["compare", str(y), str(tmp_path / "room.yaml"), "--out", str(tmp_path / "o")]))
    assert words in line


def test_canvas_of_a_nan_origin_is_an_error_not_a_hang(tmp_path):
    """The reported hang: make_canvas coarsened a canvas of NaN extent for ever (1.4 GB after 180 s)."""
    g = _room(tmp_path)
    bad = OccupancyGrid(g.data, g.resolution, (float("nan"), 0.0, 0.0))
    with pytest.raises(CompareError, match="not a finite number"):
        make_canvas(bad, g, np.eye(3), 1 << 24)
    c = make_canvas(g, g, np.eye(3), 1 << 24)  # a whole map: its own extent at its resolution
    assert (c.width, c.height, c.resolution) == (80, 60, 0.05)
