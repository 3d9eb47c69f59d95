"""Map files: map_server PGM+YAML round trips and conventions, other tools' maps, blueprints, PNG, MCAP."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from kosmap.mapping.grid import OccupancyGrid
from kosmap.mapping.mapio import (MapError, grid_picture, read_blueprint, read_map_server, write_grid_mcap, write_map_server,
                           write_png)


def _trinary_grid(seed=0, h=37, w=53) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    data = rng.choice(np.array([-1, 0, 100], np.int8), size=(h, w), p=[0.3, 0.5, 0.2])
    return OccupancyGrid(data, 0.05, (-3.725, 12.3125, 0.0))


@pytest.mark.parametrize("ext", [".pgm", ".png"])
def test_map_server_round_trip_is_exact(tmp_path, ext):
    g = _trinary_grid()
    y = write_map_server(g, tmp_path / "m.yaml", image_ext=ext)
    back = read_map_server(y)
    assert np.array_equal(back.data, g.data)
    assert back.resolution == g.resolution and back.origin == g.origin


def test_map_server_conventions(tmp_path):
    g = _trinary_grid(h=4, w=3)
    g.data[0, 0], g.data[-1, -1] = 100, 0  # bottom-left occupied, top-right free
    y = write_map_server(g, tmp_path / "m.yaml")
    meta = yaml.safe_load(y.read_text())
    assert meta == {"image": "m.pgm", "mode": "trinary", "resolution": 0.05, "origin": [-3.725, 12.3125, 0.0],
                    "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}
    raw = (tmp_path / "m.pgm").read_bytes()
    assert raw.startswith(b"P5")
    img = cv2.imread(str(tmp_path / "m.pgm"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == (4, 3)
    assert img[-1, 0] == 0 and img[0, -1] == 254  # image row 0 is the map's top
    lut = {-1: 205, 0: 254, 100: 0}
    assert np.array_equal(img[::-1], np.vectorize(lut.get)(g.data))


def test_graded_values_are_thresholded_like_map_saver(tmp_path):
    data = np.array([[-1, 0, 19, 20, 50, 64, 65, 100]], np.int8)
    back = read_map_server(write_map_server(OccupancyGrid(data, 0.1), tmp_path / "g.yaml"))
    assert back.data.tolist() == [[-1, 0, 0, -1, -1, -1, 100, 100]]


def _write_other(tmp_path, img, **meta):
    cv2.imwrite(str(tmp_path / "o.png"), img)
    m = {"image": "o.png", "resolution": 0.1, "origin": [1.0, 2.0, 0.5], **meta}
    (tmp_path / "o.yaml").write_text(yaml.safe_dump(m))
    return tmp_path / "o.yaml"


def test_other_tools_maps_negate_scale_raw_colour(tmp_path):
    v = np.array([[0, 50, 100, 128, 200, 205, 230, 255]], np.uint8)
    # trinary: occ = (255 − v)/255; > 0.65 → 100, < 0.196 → 0, else −1 (map_server)
    g = read_map_server(_write_other(tmp_path, v))
    assert g.data.tolist() == [[100, 100, -1, -1, -1, -1, 0, 0]]
    assert g.origin == (1.0, 2.0, 0.5)
    # negate: occ = v/255
    g = read_map_server(_write_other(tmp_path, v, negate=1))
    assert g.data.tolist() == [[0, -1, -1, -1, 100, 100, 100, 100]]  # 50/255 = 0.19608 is not < 0.196
    # scale: in between → rint(1 + 98·(occ − free)/(occ − free thresholds))
    g = read_map_server(_write_other(tmp_path, v, mode="scale", occupied_thresh=0.65, free_thresh=0.196))
    occ = (255 - 128) / 255
    assert g.data[0, 3] == int(np.rint(1 + 98 * (occ - 0.196) / (0.65 - 0.196)))
    assert g.data[0, 0] == 100 and g.data[0, 7] == 0
    # raw: the pixel value is the occupancy; above 100 unknown
    g = read_map_server(_write_other(tmp_path, v, mode="raw"))
    assert g.data.tolist() == [[0, 50, 100, -1, -1, -1, -1, -1]]
    # colour images: channels averaged
    g = read_map_server(_write_other(tmp_path, cv2.cvtColor(v, cv2.COLOR_GRAY2BGR)))
    assert g.data.tolist() == [[100, 100, -1, -1, -1, -1, 0, 0]]


def test_blueprint_from_plain_image_and_yaml(tmp_path):
    img = np.full((20, 30), 255, np.uint8)
    cv2.rectangle(img, (2, 2), (27, 17), 0, 1)  # a closed room (dark walls), white outside
    img[2:12, 10] = 90  # darker than half white: an inner wall
    img[3:17, 20] = 180  # light grey inside: not a wall
    cv2.imwrite(str(tmp_path / "bp.png"), img)
    bp = read_blueprint(tmp_path / "bp.png", scale=0.025)
    assert bp.resolution == 0.025 and bp.origin == (0.0, 0.0, 0.0)
    top = bp.data[::-1]  # image orientation
    assert (top[2, 2:28] == 100).all() and (top[2:12, 10] == 100).all() and (top[3:17, 20] == 0).all()
    assert (top[3:17, 3:27][top[3:17, 3:27] != 100] == 0).all()  # the inside is free
    assert (top[:2] == -1).all() and (top[:, :2] == -1).all()  # the outside unknown
    assert set(np.unique(bp.data)) == {-1, 0, 100}
    y = write_map_server(bp, tmp_path / "bp.yaml")
    bp2 = read_blueprint(y)
    assert np.array_equal(bp2.data, bp.data)
    with pytest.raises(MapError, match="scale"):
        read_blueprint(tmp_path / "bp.png")
    with pytest.raises(MapError, match="positive"):
        read_blueprint(tmp_path / "bp.png", scale=0.0)
    with pytest.raises(MapError, match="drop the blueprint scale"):
        read_blueprint(y, scale=0.05)


@pytest.mark.parametrize("content, match", [
    (None, "does not exist"),
    ("image: m.pgm\nresolution: 0.05\n", "lacks origin"),
    ("image: m.pgm\nresolution: 0\norigin: [0, 0, 0]\n", "resolution 0 must be a positive"),
    ("image: m.pgm\nresolution: -0.1\norigin: [0, 0, 0]\n", "must be a positive"),
    ("image: m.pgm\nresolution: 0.05\norigin: [0, 0]\n", "origin"),
    ("image: nothere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "missing or not an image"),
    ("image: notimage.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "missing or not an image"),
    ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n", "mode"),
    ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n", "thresholds"),
    ("[1, 2", "not valid YAML"),
    ("just a string", "not a map_server YAML"),
])
def test_bad_map_files_give_one_clear_line(tmp_path, content, match):
    (tmp_path / "notimage.pgm").write_text("hello")
    cv2.imwrite(str(tmp_path / "m.pgm"), np.zeros((2, 2), np.uint8))
    p = tmp_path / "x.yaml"
    if content is not None:
        p.write_text(content)
    with pytest.raises(MapError, match=match) as e:
        read_map_server(p)
    assert "\n" not in str(e.value)


def test_png_picture_and_trajectory(tmp_path):
    g = OccupancyGrid(np.array([[-1, 0, 40], [50, 100, 70]], np.int8), 1.0, (10.0, 20.0, 0.0))
    img = grid_picture(g)
    assert img[1, :, 0].tolist() == [160, 255, 255]  # bottom row: unknown, free, likely free
    assert img[0, :, 0].tolist() == [160, 0, 0]  # top row: undecided, occupied, occupied
    img = grid_picture(g, graded=True)
    assert img[1, :, 0].tolist() == [160, 255, 153] and img[0, :, 0].tolist() == [128, 0, 77]
    big = OccupancyGrid(np.zeros((100, 100), np.int8), 0.1, (-5.0, -5.0, 0.0))
    traj = np.array([[-4.0, 0.05], [4.0, 0.05]])  # a horizontal line through the map's middle
    pic = grid_picture(big, trajectory=traj, color=(255, 0, 0))
    blue = (pic[:, :, 0] > 200) & (pic[:, :, 2] < 100)
    rows = np.nonzero(blue.any(axis=1))[0]
    assert set(rows) <= {48, 49, 50} and blue.sum() >= 70
    p = write_png(pic, tmp_path / "sub" / "map.png")
    assert cv2.imread(str(p)).shape == (100, 100, 3)


def test_grid_into_mcap_reads_back(tmp_path):
    from mcap.reader import make_reader

    from kosmap.frontend.logs.convert import typestore

    g = _trinary_grid()
    g = OccupancyGrid(g.data, g.resolution, (1.0, 2.0, 0.3))
    traj = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.2]])
    p = write_grid_mcap(g, tmp_path / "map.mcap", stamp_ns=123, trajectory=traj, stamps_ns=np.array([1, 2]))
    ts = typestore(2)
    with open(p, "rb") as f:
        msgs = {ch.topic: (sc.name, ts.deserialize_cdr(m.data, sc.name.replace("/msg/", "/msg/")))
                for sc, ch, m in make_reader(f).iter_messages()}
    name, msg = msgs["/map"]
    assert name == "nav_msgs/msg/OccupancyGrid"
    assert msg.info.width == g.width and msg.info.height == g.height and msg.info.resolution == pytest.approx(0.05)
    assert np.array_equal(np.asarray(msg.data, np.int8).reshape(g.height, g.width), g.data)  # row 0 = bottom
    q = msg.info.origin.orientation
    assert msg.info.origin.position.x == 1.0 and 2 * np.arctan2(q.z, q.w) == pytest.approx(0.3)
    assert len(msgs["/trajectory"][1].poses) == 2
    assert not (tmp_path / "map.mcap.partial").exists()
