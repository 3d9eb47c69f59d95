"""Read-time checks of depth, camera and scan records (frontend/logs/validate.py): a record no sensor can produce
is skipped and counted with one warning naming the topic and the first time, in every log format, before the
pipeline divides by its numbers."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import BagWriter, McapWriter
from kosmap.frontend.records import CameraModel, DepthFrame, Scan
from kosmap.tools.cli import main
from tests.frontend.synthetic_log import DEPTH, records


def _log(tmp_path, edit, suffix=".mcap"):
    """The synthetic log (5 steps: a 64×48 Kinect depth image, a second camera, a scan, odometry), each record
    passed through edit(record, index among its type) (None drops it)."""
    seen: dict[type, int] = {}
    path = tmp_path / f"log{suffix}"
    w = BagWriter(path) if suffix == ".bag" else McapWriter(path)
    with w:
        for r in records(n=5):
            i = seen[type(r)] = seen.get(type(r), -1) + 1
            r = edit(r, i)
            if r is not None:
                w.write(r)
    return path


def _read(path) -> tuple[list, list[str]]:
    with open_log(path) as log:
        recs = list(log.read(log.info().types()))
    return recs, log.warnings


def _k(cam: CameraModel, **entries) -> CameraModel:
    K = np.array(cam.K, dtype=float)
    for name, v in entries.items():
        K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[name]] = v
    return dataclasses.replace(cam, K=K)


def _kinect(recs) -> list[DepthFrame]:
    return [r for r in recs if isinstance(r, DepthFrame) and r.topic == DEPTH]


@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
@pytest.mark.parametrize("shape", [(1, 1), (1, 64), (48, 1)])
def test_degenerate_depth_image_is_skipped(tmp_path, suffix, shape):
    def edit(r, i):
        if isinstance(r, DepthFrame) and r.topic == DEPTH and i in (4, 6):  # the Kinect's 3rd and 4th frames
            return dataclasses.replace(r, image=np.ascontiguousarray(r.image[:shape[0], :shape[1]]))
        return r

    recs, warnings = _read(_log(tmp_path, edit, suffix))
    assert len(_kinect(recs)) == 3 and all(f.image.shape == (48, 64) for f in _kinect(recs))
    assert len(warnings) == 1
    assert f"has a depth image of {shape[0]}×{shape[1]} pixels" in warnings[0] and DEPTH in warnings[0]


@pytest.mark.parametrize("entries,words", [
    ({"fx": np.inf}, "non-finite intrinsics"), ({"fx": np.nan}, "non-finite intrinsics"),
    ({"fy": 0.0}, "focal lengths fx="), ({"fx": -50.0}, "(must be > 0)"),
    ({"cx": 1e12}, "a principal point (1e+12, "),
])
def test_unusable_camera_info_is_skipped(tmp_path, entries, words):
    recs, warnings = _read(_log(tmp_path, lambda r, i: _k(r, **entries) if isinstance(r, CameraModel) else r))
    assert not [r for r in recs if isinstance(r, CameraModel)]
    assert len(_kinect(recs)) == 5  # the images stay: the field-of-view model serves them
    assert len(warnings) == 1 and words in warnings[0] and "field-of-view model" in warnings[0]


@pytest.mark.parametrize("field,value,words", [
    ("angle_increment", float("nan"), "a non-finite angle_min or angle_increment"),
    ("angle_min", float("inf"), "a non-finite angle_min or angle_increment"),
    ("angle_increment", 0.0, "an angle_increment of 0 rad for 1081 beams"),
])
def test_scan_with_unusable_beam_geometry_is_skipped(tmp_path, field, value, words):
    recs, warnings = _read(_log(tmp_path, lambda r, i: dataclasses.replace(r, **{field: value})
                                if isinstance(r, Scan) and i % 2 else r))
    scans = [r for r in recs if isinstance(r, Scan)]
    assert len(scans) == 3 and all(np.isfinite(s.angle_increment) and s.angle_increment > 0 for s in scans)
    assert len(warnings) == 1 and words in warnings[0] and "/scan" in warnings[0]


def test_depth_image_size_changing_between_frames_is_skipped(tmp_path):
    def edit(r, i):
        if isinstance(r, DepthFrame) and r.topic == DEPTH and i >= 4:
            return dataclasses.replace(r, image=np.ascontiguousarray(r.image[::2, ::2]))
        return r

    recs, warnings = _read(_log(tmp_path, edit))
    assert [f.image.shape for f in _kinect(recs)] == [(48, 64)] * 2
    assert len(warnings) == 1 and "a depth image of 32×24 pixels after ones of 64×48" in warnings[0]


def test_depth_image_of_another_aspect_than_its_camera_info_is_warned(tmp_path):
    recs, warnings = _read(_log(tmp_path, lambda r, i: dataclasses.replace(r, image=np.ascontiguousarray(
        r.image[:, :40])) if isinstance(r, DepthFrame) and r.topic == DEPTH else r))
    assert len(_kinect(recs)) == 5  # kept: the field-of-view model serves them
    assert len(warnings) == 1 and "are 40×48 pixels, the camera info of kinect2_ir_optical_frame says 64×48" in warnings[0]


@pytest.mark.slow
def test_scan_over_a_1x1_depth_frame_completes(tmp_path, capsys):
    """The reported failure: `scan` ended in ZeroDivisionError at the KOS on a 1×1 image. The frame is skipped
    with a warning and every other frame gives its KOS scans."""
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    src = tmp_path / "room.mcap"
    simulate(load_world("room"), SimConfig(seed=3, duration=0.3), src)
    bad = tmp_path / "bad.mcap"
    with open_log(src) as log, McapWriter(bad) as w:
        n = 0
        for r in log.read(log.info().types()):
            if isinstance(r, DepthFrame):
                n += 1
                if n == 3:
                    r = dataclasses.replace(r, image=np.zeros((1, 1), r.image.dtype))
            w.write(r, r.topic)
    code = main(["scan", str(bad), "--out", str(tmp_path / "kos"), "--figures", "0"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "has a depth image of 1×1 pixels" in out + err
    with open_log(tmp_path / "kos" / "kos.mcap") as log:
        assert log.info().count("/kinect_scan/obstacle") == n - 1


def test_transform_with_non_finite_numbers_is_skipped(tmp_path):
    from kosmap.frontend.records import Transform, Transforms

    def edit(r, i):
        if isinstance(r, Transforms):
            bad = Transform("base_link", "laser", np.array([np.nan, 0.0, 0.3]), np.array([0.0, 0.0, 0.0, 1.0]))
            return dataclasses.replace(r, transforms=(*r.transforms[:1], bad))
        return r

    recs, warnings = _read(_log(tmp_path, edit))
    assert not [r for r in recs if isinstance(r, Transforms)]
    assert len(warnings) == 1 and "a transform base_link → laser with non-finite or impossible numbers" in warnings[0]


@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
def test_odometry_jump_is_bridged_alike_in_every_format_and_read(tmp_path, suffix):
    """The same bridging as for CARMEN logs (tests/frontend/test_carmen_bad_numbers.py), here on an MCAP read record
    by record and in column batches, and on a bag: a 5 km reset of the odometry half way becomes a standstill."""
    from kosmap.frontend.records import Odometry, OdometrySamples
    from tests.mapping.synthetic_laser import make_log
    from tests.mapping.synthetic_laser import records as ring_records

    log = make_log(seed=5, laps=1)
    recs = ring_records(log)[:1 + 3 * 80]
    k = 0
    path = tmp_path / f"jump{suffix}"
    w = BagWriter(path) if suffix == ".bag" else McapWriter(path)
    with w:
        for r in recs:
            if isinstance(r, Odometry) and r.topic == "/odom":
                k += 1
                if k > 40:
                    r = dataclasses.replace(r, x=r.x + 5000.0)
            w.write(r)
    from kosmap.frontend import se2

    def steps(poses):  # each pose in the frame of the one before
        return np.array([se2.between(a, b) for a, b in zip(poses[:-1], poses[1:])])

    want = steps(log.odom[:80])
    want[39] = 0.0  # bridged: no motion across the jump, every other increment as the odometry measured it
    reads = ["read", "read_batched"] if suffix == ".mcap" else ["read"]
    for how in reads:
        with open_log(path) as lg:
            got = []
            for r in getattr(lg, how)(["/odom"]):
                got.extend(r.records() if isinstance(r, OdometrySamples) else [r])
        poses = np.array([[o.x, o.y, o.yaw] for o in got])
        assert poses.shape == (80, 3)
        np.testing.assert_allclose(poses[:40], log.odom[:40], atol=1e-6)
        np.testing.assert_allclose(steps(poses), want, atol=1e-6)
        assert len(lg.warnings) == 1 and "jumps 5000.1 m" in lg.warnings[0], (how, lg.warnings)
