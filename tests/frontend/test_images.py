"""The depth-image folder reader: camera files in their formats, stamps from names, one-line errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs.images import ImageFolder, read_camera_file
from kosmap.frontend.records import CameraModel, DepthFrame
from kosmap.mapping.planes.outputs import normal_quaternions


def test_camera_files(tmp_path):
    (tmp_path / "o3d.json").write_text(json.dumps({"width": 640, "height": 480,
                                                   "intrinsic_matrix": [525.0, 0, 0, 0, 526.0, 0, 319.5, 239.5, 1]}))
    cam, scale = read_camera_file(tmp_path / "o3d.json")
    assert (cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam["width"], scale) == (525.0, 526.0, 319.5, 239.5, 640, 1000.0)
    (tmp_path / "c.yaml").write_text("fx: 518.0\nfy: 519.0\ncx: 325.5\ncy: 253.5\ndepth_scale: 5000\n")
    cam, scale = read_camera_file(tmp_path / "c.yaml")
    assert cam["fx"] == 518.0 and scale == 5000.0
    (tmp_path / "bad.yaml").write_text("fx: 518.0\n")
    with pytest.raises(LogError, match="fx, fy, cx, cy"):
        read_camera_file(tmp_path / "bad.yaml")


def test_folder_stamps_scale_and_camera(tmp_path):
    d = tmp_path / "seq" / "depth"
    d.mkdir(parents=True)
    img = np.full((6, 8), 5000, np.uint16)
    for name in ("1305031102.226738", "1305031102.160407"):
        cv2.imwrite(str(d / f"{name}.png"), img)
    (tmp_path / "seq" / "camera.yaml").write_text("fx: 10\nfy: 10\ncx: 3.5\ncy: 2.5\ndepth_scale: 5000\n")
    log = ImageFolder(tmp_path / "seq")
    recs = list(log.read())
    assert isinstance(recs[0], CameraModel) and recs[0].width == 8 and recs[0].fx == 10
    frames = [r for r in recs if isinstance(r, DepthFrame)]
    assert [f.stamp_ns for f in frames] == [1305031102160407000, 1305031102226738000]  # sorted by time
    assert frames[0].encoding == "32FC1" and np.allclose(frames[0].meters(), 1.0)
    assert log.info().count("/camera/depth/image") == 2
    with pytest.raises(LogError, match="no depth images"):
        ImageFolder(tmp_path)


def test_normal_quaternions_turn_x_onto_the_normal():
    n = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, -1.0], [0.3, -0.5, 0.8]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    q = normal_quaternions(n)
    assert np.allclose(Rotation.from_quat(q).apply([1.0, 0, 0]), n, atol=1e-9)


def test_depth_image_whose_header_claims_10_10_pixels_is_one_line(tmp_path):
    """OpenCV refuses a PGM header claiming 100000×100000 pixels with cv2.error: a LogError naming the file."""
    d = tmp_path / "seq" / "depth"
    d.mkdir(parents=True)
    cv2.imwrite(str(d / "1305031102.160407.png"), np.full((6, 8), 5000, np.uint16))
    (d / "1305031102.226738.pgm").write_bytes(b"P5\n100000 100000\n65535\n" + bytes(1000))
    log = ImageFolder(tmp_path / "seq")
    with pytest.raises(LogError, match=r"cannot read depth image .*1305031102\.226738\.pgm \(.*\); check the file"):
        list(log.read())


def test_names_are_times_only_when_they_read_as_one(tmp_path):
    """TUM's seconds with a fraction and integer Unix times (s, ms, µs, ns) stamp the frames; a numbered sequence
    (000, 001, ...) is no time and plays at fps."""
    img = np.full((6, 8), 1000, np.uint16)
    cases = {"sec": ["1305031102", "1305031103"], "ms": ["1305031102160", "1305031102226"],
             "us": ["1305031102160407", "1305031102226738"], "ns": ["1305031102160407000", "1305031102226738000"],
             "counter": ["000", "001"], "short": ["12", "13"]}
    stamps = {}
    for name, stems in cases.items():
        d = tmp_path / name
        d.mkdir()
        for s in stems:
            cv2.imwrite(str(d / f"{s}.png"), img)
        log = ImageFolder(d, fps=4.0)
        stamps[name] = (log.timed, log.stamps_ns)
    assert stamps["sec"] == (True, [1305031102000000000, 1305031103000000000])
    assert stamps["ms"] == (True, [1305031102160000000, 1305031102226000000])
    assert stamps["us"] == stamps["ns"] == (True, [1305031102160407000, 1305031102226738000])
    assert stamps["counter"] == stamps["short"] == (False, [0, 250_000_000])
    with pytest.raises(LogError, match="is no rate"):
        ImageFolder(tmp_path / "sec", fps=0.0)
