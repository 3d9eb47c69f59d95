"""`kosmap planes` end to end: on an MCAP with a pitched camera in /tf_static, on a folder of depth PNGs
with a camera file, and one clear line for bad input."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.records import CameraModel, DepthFrame, Transform, Transforms
from kosmap.tools.boxroom import default_mount, kinect_v2, render_depth, BoxRoom
from kosmap.tools.cli import main

DEPTH, INFO = "/kinect2/sd/image_depth_rect", "/kinect2/sd/camera_info"


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _frames(n=3, pitch=15.0):
    room, cam = BoxRoom(), kinect_v2()
    mount = default_mount(pitch)
    out = []
    for i in range(n):
        d, _ = render_depth(room, (0.6 + 0.2 * i, 0.3, 0.05 * i), mount, cam, np.random.default_rng(i))
        out.append(np.round(d * 1000).astype(np.uint16))
    return out, cam, mount


@pytest.fixture(scope="module")
def pitched_log(tmp_path_factory):
    imgs, cam, mount = _frames()
    path = tmp_path_factory.mktemp("log") / "room.mcap"
    t0 = 1_700_000_000_000_000_000
    link = Transform("base_link", "kinect2_ir_optical_frame", mount.translation, mount.rotation, t0)
    with McapWriter(path) as w:
        w.write(Transforms(t0, (link,), True, "/tf_static"))
        w.write(CameraModel(cam.width, cam.height, cam.K, np.zeros(5), "plumb_bob", "kinect2_ir_optical_frame", INFO, t0))
        for i, img in enumerate(imgs):
            w.write(DepthFrame(t0 + (i + 1) * 66_666_667, img, "16UC1", "kinect2_ir_optical_frame", DEPTH))
    return path


@pytest.mark.slow
def test_planes_on_a_log_writes_everything(capsys, tmp_path, pitched_log):
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "planes", pitched_log, "--out", out, "--save-depth", "--figures", "1")
    assert code == 0, err
    assert "3 frames" in stdout
    assert {p.name for p in out.iterdir()} >= {"stats.csv", "config.toml", "summary.json", "planes", "planes.mcap",
                                                "depth", "figures"}
    rows = list(csv.DictReader(open(out / "stats.csv")))
    assert [r["frame"] for r in rows] == ["000000", "000001", "000002", "summary"]
    for r in rows[:3]:
        total = float(r["ineligible_pct"]) + float(r["inlier_pct"]) + float(r["dropped_pct"]) + float(r["outlier_pct"])
        assert 90 < total <= 100.01 and float(r["elapsed_ms"]) > 0
        # the 15° pitch comes from /tf_static: the floor is recognised and dropped
        assert float(r["dropped_pct"]) > 20
    z = np.load(out / "planes" / "000001.npz")
    assert z["points"].shape[1] == 3 and len(z["plane"]) == len(z["points"]) and len(z["normals"]) == len(z["counts"])
    assert np.allclose(z["mount"], default_mount(15.0).matrix())
    assert 0 not in z["classes"]  # ground dropped
    depth = cv2.imread(str(out / "depth" / "000001.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and (depth > 0).sum() == len(z["points"])
    assert len(list((out / "figures").glob("*.png"))) == 1
    with open_log(out / "planes.mcap") as log:
        counts = {t.name: t.count for t in log.info().topics}
    assert counts == {"/tf_static": 1, "/kosmap/planes/points": 3, "/kosmap/planes/normals": 3}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 3 and summary["method"] == "fspf+"
    # same seed, same result
    code, _, err = run(capsys, "planes", pitched_log, "--out", tmp_path / "again", "--figures", "0", "--no-mcap")
    assert code == 0, err
    z2 = np.load(tmp_path / "again" / "planes" / "000001.npz")
    assert np.array_equal(z["points"], z2["points"]) and np.array_equal(z["normals"], z2["normals"])


def test_planes_fspf_on_image_folder_with_camera_file(capsys, tmp_path):
    imgs, cam, _ = _frames(2, pitch=0.0)
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i, img in enumerate(imgs):
        cv2.imwrite(str(folder / f"{i}.png"), (img.astype(np.uint32) * 5).clip(0, 65535).astype(np.uint16))
    (folder / "camera.json").write_text(json.dumps({"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
                                                    "depth_scale": 5000}))
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "planes", folder, "--out", out, "--method", "fspf", "--figures", "0",
                            "--set", "fspf.drop_classes=[]")
    assert code == 0, err
    z = np.load(out / "planes" / "000000.npz")
    assert np.allclose(z["K"], cam.K)
    assert 1900 < len(z["points"]) <= 2100  # FSPF stops at n_max = 2000 filtered points
    assert np.allclose(z["points"][:, 2], imgs[0][z["pixels"][:, 0], z["pixels"][:, 1]] / 1000.0, atol=1e-3)
    assert "fspf" in (out / "config.toml").read_text()


def test_planes_bad_input_is_one_line(capsys, tmp_path):
    code, _, err = run(capsys, "planes", tmp_path / "nope.mcap", "--out", tmp_path / "o")
    assert code == 2 and err.startswith("kosmap: error:") and len(err.strip().splitlines()) == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = run(capsys, "planes", empty, "--out", tmp_path / "o")
    assert code == 2 and "no depth images" in err
    code, _, err = run(capsys, "planes", empty, "--out", tmp_path / "o", "--method", "ransac")
    assert code == 2 and "--method" in err
