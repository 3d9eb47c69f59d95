"""`kosmap planes` options and failures: --camera and --depth-scale act on dataset folders, image folders and logs
(or are refused in one line), a failed run leaves no output behind, and the printed shares cover every pixel."""

from __future__ import annotations

import csv
import json
import math
import re

import cv2
import numpy as np
import pytest

from kosmap.frontend.logs.writer import McapWriter
from kosmap.frontend.records import CameraModel, DepthFrame
from kosmap.mapping.runtime.outdir import MANIFEST
from tests.conftest import require_data
from kosmap.tools.boxroom import BoxRoom, default_mount, render_depth
from kosmap.tools.cli import main

SLAMBOOK_K = (518.0, 519.0, 325.5, 253.5)  # the intrinsics tools.datasets gives slambook2_ch5_rgbd


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code: int, err: str, *words: str) -> None:
    assert code == 2 and err.startswith("kosmap: error:") and len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err


def _depth_mm(n: int) -> list[np.ndarray]:
    """n renders of the box room by a 640×480 camera with slambook2's intrinsics, in millimetres."""
    fx, fy, cx, cy = SLAMBOOK_K
    cam = CameraModel(640, 480, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.zeros(5), "plumb_bob", "camera")
    imgs = []
    for i in range(n):
        d, _ = render_depth(BoxRoom(), (0.6 + 0.2 * i, 0.3, 0.05 * i), default_mount(0.0), cam,
                            np.random.default_rng(i))
        imgs.append(np.round(d * 1000).astype(np.uint16))
    return imgs


@pytest.fixture(scope="module")
def slambook(tmp_path_factory):
    """A folder laid out (and named) like ../shared/data/depth/slambook2_ch5_rgbd: depth/N.pgm in millimetres."""
    root = tmp_path_factory.mktemp("data") / "slambook2_ch5_rgbd"
    (root / "depth").mkdir(parents=True)
    imgs = _depth_mm(2)
    for i, img in enumerate(imgs):
        assert cv2.imwrite(str(root / "depth" / f"{i + 1}.pgm"), img)
    return root, imgs


@pytest.fixture(scope="module")
def plain_folder(tmp_path_factory):
    """A folder of depth PNGs without a camera file, in TUM's units (5000 per metre)."""
    folder = tmp_path_factory.mktemp("plain") / "depth"
    folder.mkdir()
    imgs = [(img.astype(np.uint32) * 5).clip(0, 65535).astype(np.uint16) for img in _depth_mm(2)]
    for i, img in enumerate(imgs):
        cv2.imwrite(str(folder / f"{i}.png"), img)
    return folder, imgs


def _z_at_pixels(out, frame: str = "000000") -> tuple[np.ndarray, np.ndarray]:
    z = np.load(out / "planes" / f"{frame}.npz")
    return z["points"][:, 2], z["pixels"]


QUICK = ("--figures", "0", "--no-mcap", "--set", "fspf.drop_classes=[]")


# ---- 1. --camera and --depth-scale ------------------------------------------------------------------------------------

def test_missing_camera_file_is_an_error_on_a_dataset_folder(capsys, tmp_path, slambook):
    code, _, err = run(capsys, "planes", slambook[0], "--out", tmp_path / "o", "--camera", tmp_path / "nope.yaml")
    one_line_error(code, err, "cannot read camera file", "nope.yaml")
    assert not (tmp_path / "o").exists()


def test_missing_camera_file_is_an_error_on_a_log(capsys, tmp_path):
    log = tmp_path / "one.mcap"
    with McapWriter(log) as w:
        w.write(DepthFrame(1, _depth_mm(1)[0], "16UC1", "camera", "/camera/depth/image"))
    code, _, err = run(capsys, "planes", log, "--out", tmp_path / "o", "--camera", tmp_path / "nope.yaml")
    one_line_error(code, err, "cannot read camera file")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("scale", ["0", "-1", "nan", "inf"])
def test_nonsense_depth_scale_is_refused(capsys, tmp_path, slambook, plain_folder, scale):
    for src in (slambook[0], plain_folder[0]):
        code, _, err = run(capsys, "planes", src, "--out", tmp_path / "o", "--depth-scale", scale)
        one_line_error(code, err, f"--depth-scale {scale}", "units per metre")
        assert not (tmp_path / "o").exists()


def test_depth_scale_overrides_a_dataset_folder(capsys, tmp_path, slambook):
    root, imgs = slambook
    code, stdout, err = run(capsys, "planes", root, "--out", tmp_path / "mm", *QUICK)
    assert code == 0, err
    z, px = _z_at_pixels(tmp_path / "mm")
    assert len(z) > 1000 and np.allclose(z, imgs[0][px[:, 0], px[:, 1]] / 1000.0, atol=1e-4)
    assert "warning" not in stdout
    code, stdout, err = run(capsys, "planes", root, "--out", tmp_path / "half", "--depth-scale", "2000", *QUICK)
    assert code == 0, err
    z, px = _z_at_pixels(tmp_path / "half")
    assert len(z) > 1000 and np.allclose(z, imgs[0][px[:, 0], px[:, 1]] / 2000.0, atol=1e-4)
    notes = [ln for ln in stdout.splitlines() if ln.startswith("warning:")]
    assert notes == ["warning: --depth-scale 2000 replaces slambook2_ch5_rgbd's own depth scale "
                     "(1000 image units per metre)"]


def test_camera_file_overrides_a_dataset_folder(capsys, tmp_path, slambook):
    root, imgs = slambook
    cam = tmp_path / "cam.yaml"
    cam.write_text("fx: 600\nfy: 601\ncx: 320\ncy: 240\n")  # no depth_scale: the dataset's own (mm) stays
    code, stdout, err = run(capsys, "planes", root, "--out", tmp_path / "o", "--camera", cam, *QUICK)
    assert code == 0, err
    npz = np.load(tmp_path / "o" / "planes" / "000000.npz")
    assert np.allclose(npz["K"], [[600, 0, 320], [0, 601, 240], [0, 0, 1]])
    z, px = npz["points"][:, 2], npz["pixels"]
    assert np.allclose(z, imgs[0][px[:, 0], px[:, 1]] / 1000.0, atol=1e-4)
    assert f"warning: --camera {cam} replaces the intrinsics of slambook2_ch5_rgbd" in stdout
    # a depth_scale in the camera file counts as given, and --depth-scale beats it
    cam.write_text("fx: 600\nfy: 601\ncx: 320\ncy: 240\ndepth_scale: 4000\n")
    for extra, scale in (((), 4000.0), (("--depth-scale", "500"), 500.0)):
        out = tmp_path / f"o{int(scale)}"
        code, stdout, err = run(capsys, "planes", root, "--out", out, "--camera", cam, *extra, *QUICK)
        assert code == 0, err
        z, px = _z_at_pixels(out)
        assert np.allclose(z, imgs[0][px[:, 0], px[:, 1]] / scale, atol=1e-4), scale


def test_plain_folder_warning_tells_the_scale_used(capsys, tmp_path, plain_folder):
    folder, imgs = plain_folder
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o", "--depth-scale", "5000", *QUICK)
    assert code == 0, err
    warn = [ln for ln in stdout.splitlines() if ln.startswith("warning:") and "--fps" not in ln]  # (names 0, 1)
    assert len(warn) == 1 and "5000 image units per metre" in warn[0] and "millimetres" not in warn[0], warn
    z, px = _z_at_pixels(tmp_path / "o")
    assert np.allclose(z, imgs[0][px[:, 0], px[:, 1]] / 5000.0, atol=1e-4)


def test_depth_scale_and_camera_override_a_log(capsys, tmp_path):
    img = _depth_mm(1)[0]
    log = tmp_path / "one.mcap"
    fx, fy, cx, cy = SLAMBOOK_K
    with McapWriter(log) as w:
        w.write(CameraModel(640, 480, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.zeros(5), "plumb_bob",
                            "camera", "/camera/depth/camera_info", 1))
        w.write(DepthFrame(2, img, "16UC1", "camera", "/camera/depth/image"))
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": 600, "fy": 601, "cx": 320, "cy": 240}))
    code, stdout, err = run(capsys, "planes", log, "--out", tmp_path / "o", "--camera", cam, "--depth-scale", "2000",
                            *QUICK)
    assert code == 0, err
    npz = np.load(tmp_path / "o" / "planes" / "000000.npz")
    assert np.allclose(npz["K"], [[600, 0, 320], [0, 601, 240], [0, 0, 1]])
    z, px = npz["points"][:, 2], npz["pixels"]
    assert len(z) > 1000 and np.allclose(z, img[px[:, 0], px[:, 1]] / 2000.0, atol=1e-4)


@pytest.mark.data
def test_real_datasets_follow_the_depth_scale(capsys, tmp_path):
    """The tester's runs: --depth-scale changed nothing on slambook2 and tum_fr1_xyz."""
    for name in ("slambook2_ch5_rgbd", "tum_fr1_xyz"):
        src = require_data(f"depth/{name}")
        res = {}
        for scale in ("1000", "5000"):
            out = tmp_path / f"{name}_{scale}"
            code, _, err = run(capsys, "planes", src, "--out", out, "--max-frames", "1", "--depth-scale", scale, *QUICK)
            assert code == 0, err
            res[scale] = json.loads((out / "summary.json").read_text())["ineligible_pct"]
        assert res["1000"] != res["5000"], name
    code, _, err = run(capsys, "planes", require_data("depth/slambook2_ch5_rgbd"), "--out", tmp_path / "o",
                       "--camera", tmp_path / "nope.yaml")
    one_line_error(code, err, "cannot read camera file")


# ---- 2. a failed run leaves no output --------------------------------------------------------------------------------

@pytest.mark.parametrize("n", ["0", "-3"])
def test_max_frames_below_one_is_refused_before_writing(capsys, tmp_path, slambook, n):
    out = tmp_path / "o"
    code, _, err = run(capsys, "planes", slambook[0], "--out", out, "--max-frames", n)
    one_line_error(code, err, f"--max-frames {n}")
    assert not out.exists()


def test_rgb_folder_leaves_nothing_and_keeps_the_users_files(capsys, tmp_path):
    rgb = tmp_path / "rgb"
    rgb.mkdir()
    cv2.imwrite(str(rgb / "1.png"), np.zeros((48, 64, 3), np.uint8))
    out = tmp_path / "o"
    code, _, err = run(capsys, "planes", rgb, "--out", out)
    one_line_error(code, err, "not a single-channel 16-bit depth image")
    assert not out.exists()
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, _, err = run(capsys, "planes", rgb, "--out", out)
    assert code == 2
    assert [p.name for p in out.iterdir()] == ["notes.txt"] and (out / "notes.txt").read_text() == "mine"


def test_failure_mid_run_leaves_the_previous_results_untouched(capsys, tmp_path, plain_folder):
    folder, _ = plain_folder
    out = tmp_path / "o"
    code, _, err = run(capsys, "planes", folder, "--out", out, "--depth-scale", "5000", "--figures", "1")
    assert code == 0, err
    before = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    assert {str(p) for p in before} >= {"stats.csv", "summary.json", "config.toml", "planes.mcap",
                                        "planes/000000.npz", "planes/000001.npz"}
    broken = tmp_path / "broken"
    broken.mkdir()
    for i, img in enumerate(_depth_mm(2)):
        cv2.imwrite(str(broken / f"{i}.png"), img)
    (broken / "2.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)  # the third frame fails: not decodable
    for dest in (out, tmp_path / "new"):
        code, _, err = run(capsys, "planes", broken, "--out", dest, "--figures", "3", "--save-depth")
        one_line_error(code, err, "2.png", "cannot read depth image")
    after = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    assert after == before  # the previous run's files, and its manifest (which of them are the run's)
    assert not [p for p in out.iterdir() if p.name.startswith(".") and p.name != MANIFEST]  # no staging left
    assert not (tmp_path / "new").exists()


def test_out_that_is_a_file_is_one_line(capsys, tmp_path, slambook):
    f = tmp_path / "afile"
    f.write_text("x")
    code, _, err = run(capsys, "planes", slambook[0], "--out", f)
    one_line_error(code, err, "--out", "is a file")
    code, _, err = run(capsys, "planes", slambook[0], "--out", f / "sub")
    one_line_error(code, err, "--out", "is a file")
    assert f.read_text() == "x"


# ---- 3. the shares of the pixels -------------------------------------------------------------------------------------

def test_printed_shares_cover_every_pixel(capsys, tmp_path, slambook):
    out = tmp_path / "o"
    # without growing, so that some pixels stay unexamined (grown, the box room leaves none)
    code, stdout, err = run(capsys, "planes", slambook[0], "--out", out, *QUICK, "--set", "fspf.grow=false")
    assert code == 0, err
    line = stdout.splitlines()[-2] if stdout.splitlines()[-1].startswith("wrote") else stdout
    assert "of the pixels:" in line and "not examined" in line, line
    found = dict((k, float(v)) for k, v in re.findall(r"(ineligible|inliers|dropped|outliers|not examined) "
                                                       r"(\d+\.\d) %", line))
    assert set(found) == {"ineligible", "inliers", "dropped", "outliers", "not examined"}, line
    assert found["not examined"] > 0.5 and sum(found.values()) == pytest.approx(100.0, abs=0.3)
    rows = list(csv.DictReader(open(out / "stats.csv")))
    for r in rows:
        total = sum(float(r[c]) for c in ("ineligible_pct", "inlier_pct", "dropped_pct", "outlier_pct",
                                          "unexamined_pct"))
        assert total == pytest.approx(100.0, abs=1e-3), r
    npz = np.load(out / "planes" / "000000.npz")
    pixels = int(np.prod(npz["shape"]))
    assert float(rows[0]["unexamined_pct"]) == pytest.approx(100.0 * float(rows[0]["remaining"]) / pixels, abs=1e-3)
    s = json.loads((out / "summary.json").read_text())
    assert s["unexamined_pct"] == pytest.approx(found["not examined"], abs=0.05)
    assert not math.isnan(s["unexamined_pct"])


def test_depth_scale_on_a_float_log_says_it_does_not_apply(capsys, tmp_path):
    metres = _depth_mm(1)[0].astype(np.float32) / 1000.0
    log = tmp_path / "float.mcap"
    with McapWriter(log) as w:
        w.write(DepthFrame(2, metres, "32FC1", "camera", "/camera/depth/image"))
    code, stdout, err = run(capsys, "planes", log, "--out", tmp_path / "o", "--depth-scale", "2000", *QUICK)
    assert code == 0, err
    assert "warning: --depth-scale 2000 does not apply to /camera/depth/image, whose 32FC1 images are in metres" \
        in stdout.splitlines()
    z, px = _z_at_pixels(tmp_path / "o")
    assert np.allclose(z, metres[px[:, 0], px[:, 1]], atol=1e-4)


def test_a_shorter_rerun_leaves_no_frames_of_the_longer_one(capsys, tmp_path, plain_folder):
    folder, _ = plain_folder
    out = tmp_path / "o"
    code, _, err = run(capsys, "planes", folder, "--out", out, "--max-frames", "2", "--figures", "2", "--save-depth")
    assert code == 0, err
    (out / "planes" / "mine.txt").write_text("mine")
    code, _, err = run(capsys, "planes", folder, "--out", out, "--max-frames", "1", "--figures", "1", "--save-depth")
    assert code == 0, err
    assert sorted(p.name for p in (out / "planes").iterdir()) == ["000000.npz", "mine.txt"]
    assert [p.name for p in (out / "depth").iterdir()] == ["000000.png"]
    assert json.loads((out / "summary.json").read_text())["frames"] == 1


# ---- inputs as users have them: either depth-scale convention, non-depth images, empty frames, --glob, --seed ---------

def test_depth_scale_below_one_is_metres_per_unit(capsys, tmp_path, plain_folder):
    """RealSense's convention (0.0002 m per unit) and TUM's (5000 units per metre) give the same points."""
    folder, imgs = plain_folder
    runs = {}
    for scale in ("5000", "0.0002"):
        code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / scale, "--depth-scale", scale, *QUICK)
        assert code == 0, err
        runs[scale] = _z_at_pixels(tmp_path / scale)
    (z1, p1), (z2, p2) = runs.values()
    assert len(z1) > 1000 and np.array_equal(p1, p2) and np.allclose(z1, z2)
    assert np.allclose(z1, imgs[0][p1[:, 0], p1[:, 1]] / 5000.0, atol=1e-4)


@pytest.mark.parametrize("key,value", [("depth_scale", 0.0002), ("depth_scale", 5000), ("depth_units", 0.0002),
                                       ("units_per_meter", 5000)])
def test_camera_file_scale_in_either_convention(capsys, tmp_path, plain_folder, key, value):
    folder, imgs = plain_folder
    fx, fy, cx, cy = SLAMBOOK_K
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps({"fx": fx, "fy": fy, "cx": cx, "cy": cy, key: value}))
    code, _, err = run(capsys, "planes", folder, "--out", tmp_path / "o", "--camera", cam, *QUICK)
    assert code == 0, err
    z, px = _z_at_pixels(tmp_path / "o")
    assert len(z) > 1000 and np.allclose(z, imgs[0][px[:, 0], px[:, 1]] / 5000.0, atol=1e-4)


def test_wrong_scale_warns_with_the_likely_cause(capsys, tmp_path, plain_folder):
    """Millimetres read as metres (scale 1): no pixel is eligible, and the warning says why."""
    folder, _ = plain_folder
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o", "--depth-scale", "1", *QUICK)
    assert code == 0, err
    assert "no eligible pixel" in stdout and "beyond [depth] max_depth" in stdout and "depth scale" in stdout
    assert "2 of 2 frames had no eligible pixel" in stdout


def test_labels_masks_and_8bit_images_are_skipped_and_counted(capsys, tmp_path, plain_folder):
    folder, imgs = plain_folder
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for i, img in enumerate(imgs):
        cv2.imwrite(str(mixed / f"{i}.png"), img)
        cv2.imwrite(str(mixed / f"{i}_labels.png"), (img // 300).astype(np.uint16))  # 16-bit, but labels
        cv2.imwrite(str(mixed / f"{i}_mask.png"), (img > 0).astype(np.uint8) * 255)
    cv2.imwrite(str(mixed / "9.png"), np.zeros((480, 640, 3), np.uint8))  # colour, not named as such
    code, stdout, err = run(capsys, "planes", mixed, "--out", tmp_path / "o", "--depth-scale", "5000", *QUICK)
    assert code == 0, err
    assert "2 frames" in stdout
    assert "skipped 4 images named as colour, labels or masks" in stdout
    assert "1 images of" in stdout and "not depth (8-bit or colour)" in stdout
    sel = tmp_path / "o2"
    code, stdout, err = run(capsys, "planes", mixed, "--out", sel, "--depth-scale", "5000", "--glob", "?.png", *QUICK)
    assert code == 0 and "2 frames" in stdout and "1 images of" in stdout, stdout + err
    code, _, err = run(capsys, "planes", mixed, "--out", tmp_path / "o3", "--glob", "*.jpg")
    one_line_error(code, err, "no file matching --glob *.jpg")


def test_seed_is_per_frame_whatever_every(capsys, tmp_path, plain_folder):
    """--seed S: frame i uses S + i with i counted before --every, so the folder's third image gives the same
    planes as output frame 2 of a full run and as output frame 1 of an --every 2 run."""
    folder, imgs = plain_folder
    four = tmp_path / "four"
    four.mkdir()
    for i in range(4):
        cv2.imwrite(str(four / f"{i}.png"), imgs[0])  # one image four times: only the seed differs
    code, _, err = run(capsys, "planes", four, "--out", tmp_path / "all", "--seed", "7", "--depth-scale", "5000", *QUICK)
    assert code == 0, err
    code, _, err = run(capsys, "planes", four, "--out", tmp_path / "every", "--seed", "7", "--every", "2", "--depth-scale", "5000",
               *QUICK)
    assert code == 0, err
    z2, p2 = _z_at_pixels(tmp_path / "all", "000002")
    z_ev, p_ev = _z_at_pixels(tmp_path / "every", "000001")
    assert np.array_equal(p2, p_ev) and np.array_equal(z2, z_ev)
    z1, p1 = _z_at_pixels(tmp_path / "all", "000001")
    assert not (len(p1) == len(p2) and np.array_equal(p1, p2))  # another seed, other draws


def test_elapsed_ms_is_the_filters_own_time(capsys, tmp_path, plain_folder):
    """stats.csv elapsed_ms: the first frame pays no compiling or buffer set-up (within 3× of the others' median)."""
    folder, imgs = plain_folder
    many = tmp_path / "many"
    many.mkdir()
    for i in range(6):
        cv2.imwrite(str(many / f"{i}.png"), imgs[i % 2])
    code, _, err = run(capsys, "planes", many, "--out", tmp_path / "o", "--depth-scale", "5000", *QUICK)
    assert code == 0, err
    ms = [float(r["elapsed_ms"]) for r in csv.DictReader(open(tmp_path / "o" / "stats.csv"))][:-1]
    assert len(ms) == 6 and ms[0] <= 3 * np.median(ms[1:]), ms
