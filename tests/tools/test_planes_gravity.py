"""`kosmap planes` takes gravity from where it can (the mount, a gravity file, else the frames), says which, and
calibrates the depth camera's mount from the floor planes: a mount mis-specified by 3° of pitch and 5 cm of
height is recovered within 0.3° and 1 cm (box rooms of tools/boxroom.py, Kinect-like noise)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from kosmap.frontend.camera import mount_transform
from kosmap.tools.boxroom import BoxRoom, kinect_v2, render_depth
from kosmap.tools.cli import main

pytestmark = pytest.mark.slow


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _folder(root, name, n, room, pitch, roll, height, seed, handheld=False):
    """n depth PNGs (mm) of `room` with a camera file; handheld: pitch, roll and height change frame to frame."""
    cam = kinect_v2()
    folder = root / name
    folder.mkdir()
    (folder / "camera.json").write_text(json.dumps({"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
                                                    "depth_scale": 0.001}))
    rng = np.random.default_rng(seed)
    for i in range(n):
        p, r, h = (pitch + 10 * np.sin(i), roll * np.cos(i), height + 0.2 * np.sin(2 * i)) if handheld else (pitch, roll, height)
        mount = mount_transform([0.1, 0.0, h], np.radians([r, p, 0.0]))
        pose = (0.6 + rng.uniform(0, 1.5), rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.5))
        d, _ = render_depth(room, pose, mount, cam, np.random.default_rng(100 * seed + i))
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.round(d * 1000).astype(np.uint16))
    return folder


@pytest.mark.parametrize("case", [(15.0, 0.0, 1.00, 0, 4.5), (20.0, 2.0, 1.25, 1, 3.2)])
def test_a_misspecified_mount_is_recovered_from_the_floor(capsys, tmp_path, case):
    pitch, roll, height, seed, length = case
    folder = _folder(tmp_path, "log", 6, BoxRoom(length=length + 2.0, width=length), pitch, roll, height, seed)
    given = ("--set", f"depth.mount_rpy_deg={roll},{pitch - 3.0},0", "--set", f"depth.mount_xyz=0.1,0,{height - 0.05}")
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o", "--figures", "0", "--no-mcap", *given)
    assert code == 0, err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert set(s["gravity"]) == {"config"} and "gravity: the [depth] mount" in stdout
    m = s["mount_estimate"]
    assert m["frames"] >= 5
    assert abs(m["pitch_deg"] - pitch) <= 0.3 and abs(m["roll_deg"] - roll) <= 0.3 and abs(m["height_m"] - height) <= 0.01, m
    assert m["differs"] and "more than 1° or 2 cm apart" in stdout
    toml = (tmp_path / "o" / "mount.toml").read_text()
    assert f"{m['pitch_deg']:.2f}" in toml and "static_transform_publisher" in toml
    # the same run with the estimate as the mount: no warning
    rpy = f"{m['roll_deg']:.3f},{m['pitch_deg']:.3f},0"
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o2", "--figures", "0", "--no-mcap",
                            "--set", f"depth.mount_rpy_deg={rpy}", "--set", f"depth.mount_xyz=0.1,0,{m['height_m']:.4f}")
    assert code == 0 and "more than 1° or 2 cm apart" not in stdout, stdout


def test_handheld_folder_takes_gravity_from_the_frames(capsys, tmp_path):
    """No mount, no gravity file: the frames (a second apart, --fps 1) give gravity, the floor is dropped as ground
    (the thesis's default)."""
    folder = _folder(tmp_path, "hand", 5, BoxRoom(), 26.0, 4.0, 1.2, 2, handheld=True)
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o", "--figures", "0", "--no-mcap",
                            "--fps", "1")
    assert code == 0, err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert set(s["gravity"]) == {"frames"} and "gravity: the frames" in stdout
    assert s["dropped_pct"] > 10.0  # the floor, recognised as ground
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "lvl", "--figures", "0", "--no-mcap",
                            "--set", 'depth.gravity="mount"')
    s2 = json.loads((tmp_path / "lvl" / "summary.json").read_text())
    assert code == 0 and s2["dropped_pct"] < 0.5 * s["dropped_pct"]  # a level camera at 1 m: the floor 'slanted'
    # a gravity file beside the images (gravity, pointing down, in the optical frame) is used when present
    (folder / "gravity-direction.txt").write_text("0 1 0\n")  # a level camera
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "file", "--figures", "0", "--no-mcap",
                            "--fps", "1")
    s3 = json.loads((tmp_path / "file" / "summary.json").read_text())
    assert code == 0 and set(s3["gravity"]) == {"file"} and s3["dropped_pct"] < 0.5 * s["dropped_pct"]


def test_a_log_with_an_imu_on_the_camera_takes_gravity_from_it(capsys, tmp_path):
    """A handheld camera with an IMU on its body (tied to the depth frame in /tf_static, no mount to base_link):
    the IMU's specific force gives gravity; without the tie it is not used (the frames are)."""
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import CameraModel, DepthFrame, Imu, Transform, Transforms
    from scipy.spatial.transform import Rotation

    cam, room = kinect_v2(), BoxRoom()
    t0 = 1_700_000_000_000_000_000
    imu_in_cam = Rotation.from_euler("xyz", [90, 0, 90], degrees=True)  # the IMU's axes: turned against the optical
    for tied in (True, False):
        path = tmp_path / f"hand{tied}.mcap"
        with McapWriter(path) as w:
            if tied:
                tf = Transform("cam_optical", "cam_imu", np.array([0.02, 0.0, 0.0]), imu_in_cam.as_quat(), t0)
                w.write(Transforms(t0, (tf,), True, "/tf_static"))
            w.write(CameraModel(cam.width, cam.height, cam.K, np.zeros(5), "plumb_bob", "cam_optical",
                                "/cam/depth/camera_info", t0))
            for i in range(4):
                pitch, roll, h = 26 + 8 * np.sin(i), 4 * np.cos(i), 1.2 + 0.1 * i
                mount = mount_transform([0.1, 0.0, h], np.radians([roll, pitch, 0.0]))
                d, _ = render_depth(room, (0.8 + 0.3 * i, 0.2, 0.1 * i), mount, cam, np.random.default_rng(i))
                up_cam = mount.matrix()[:3, :3].T @ np.array([0.0, 0.0, 1.0])
                t = t0 + (i + 1) * 100_000_000
                for j in range(5):  # 50 Hz: specific force = +g up, in the IMU's axes, a little noise
                    acc = imu_in_cam.inv().apply(9.81 * up_cam) + np.random.default_rng(j).normal(0, 0.05, 3)
                    w.write(Imu(t - (5 - j) * 20_000_000, np.zeros(3), acc, frame_id="cam_imu", topic="/imu"))
                w.write(DepthFrame(t, np.round(d * 1000).astype(np.uint16), "16UC1", "cam_optical", "/cam/depth/image"))
        code, stdout, err = run(capsys, "planes", path, "--out", tmp_path / f"o{tied}", "--figures", "0", "--no-mcap")
        assert code == 0, err
        s = json.loads((tmp_path / f"o{tied}" / "summary.json").read_text())
        if tied:
            assert set(s["gravity"]) == {"imu"} and "gravity: the log's IMU" in stdout
            assert s["dropped_pct"] > 10.0  # the floor, as ground
        else:
            assert set(s["gravity"]) == {"frames"} and "is not tied to the depth frame" in stdout


def test_build_mount_auto_replaces_a_wrong_tf_static_mount(capsys, tmp_path):
    """--set depth.mount=auto: /tf_static says pitch 12°, 0.95 m; the floor says 15°, 1.00 m, and the build's
    depth config takes the floor's (x, y and yaw kept from /tf_static); other commands refuse auto in one line."""
    from kosmap.frontend.camera import camera_mount
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import CameraModel, DepthFrame, Transform, Transforms
    from kosmap.tools import options as O
    from kosmap.tools.commands.build import _auto_mount

    cam, room = kinect_v2(), BoxRoom()
    t0 = 1_700_000_000_000_000_000
    true = mount_transform([0.1, 0.0, 1.0], np.radians([0.0, 15.0, 0.0]), child="cam")
    wrong = mount_transform([0.1, 0.0, 0.95], np.radians([0.0, 12.0, 0.0]), child="cam")
    path = tmp_path / "robot.mcap"
    with McapWriter(path) as w:
        w.write(Transforms(t0, (Transform("base_link", "cam", wrong.translation, wrong.rotation, t0),), True, "/tf_static"))
        w.write(CameraModel(cam.width, cam.height, cam.K, np.zeros(5), "plumb_bob", "cam", "/cam/camera_info", t0))
        for i in range(6):
            d, _ = render_depth(room, (0.8 + 0.25 * i, 0.3 - 0.1 * i, 0.15 * i), true, cam, np.random.default_rng(i))
            w.write(DepthFrame(t0 + (i + 1) * 10**8, np.round(d * 1000).astype(np.uint16), "16UC1", "cam", "/cam/depth"))
    cfg = O.make_config(None, ["depth.mount=\"auto\""], None, None)
    resolved = _auto_mount(path, cfg, quiet=True)
    assert resolved.depth.mount == "config"
    assert abs(resolved.depth.mount_rpy_deg[1] - 15.0) <= 0.3 and abs(resolved.depth.mount_xyz[2] - 1.0) <= 0.01
    assert resolved.depth.mount_xyz[0] == pytest.approx(0.1) and abs(resolved.depth.mount_rpy_deg[2]) < 1e-6
    mount, src = camera_mount([], "cam", resolved.depth)
    assert src == "config" and abs(mount.translation[2] - 1.0) <= 0.01
    code, _, err = run(capsys, "planes", path, "--out", tmp_path / "o", "--set", 'depth.mount="auto"')
    assert code == 2 and "depth.mount = auto is resolved by `kosmap build`" in err


def test_a_folder_without_times_plays_at_fps(capsys, tmp_path):
    """Gravity from the frames tracks the floor with a motion model over the frames' times: a folder whose names
    are no times plays at --fps (30 by default, said in a warning), and at the camera's true rate it gives the
    same floor, frame by frame, as the same images named by their times; a rate that is none is refused."""
    import csv
    import shutil

    folder = _folder(tmp_path, "hand", 6, BoxRoom(), 26.0, 4.0, 1.2, 3, handheld=True)
    timed = tmp_path / "timed"
    timed.mkdir()
    shutil.copy(folder / "camera.json", timed)
    for i in range(6):  # 2 Hz, as the names say
        shutil.copy(folder / f"{i:03d}.png", timed / f"{1700000000 + i // 2}.{5 * (i % 2)}00000.png")

    def rows(out):
        with open(out / "stats.csv") as f:
            return [r for r in csv.DictReader(f) if r["frame"] != "summary"]

    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o30", "--figures", "0", "--no-mcap")
    assert code == 0 and "play at 30 fps" in stdout and "--fps RATE" in stdout, stdout
    code, stdout, err = run(capsys, "planes", folder, "--out", tmp_path / "o2", "--figures", "0", "--no-mcap",
                            "--fps", "2")
    assert code == 0 and "--fps" not in stdout, stdout
    code, stdout, err = run(capsys, "planes", timed, "--out", tmp_path / "t", "--figures", "0", "--no-mcap",
                            "--fps", "2")
    assert code == 0 and "--fps 2 is not used" in stdout, stdout
    at2, named = rows(tmp_path / "o2"), rows(tmp_path / "t")
    assert [float(r["stamp"]) for r in at2] == pytest.approx([0.5 * i for i in range(6)])
    assert [r["floor_m"] for r in at2] == [r["floor_m"] for r in named]
    assert [r["dropped_pct"] for r in at2] == [r["dropped_pct"] for r in named]
    tracked = [(i, float(r["floor_m"])) for i, r in enumerate(at2) if r["floor_m"]]
    assert len(tracked) >= 3  # the floor confirmed and tracked at the true rate: the camera's height within 2 cm
    assert all(abs(h - (1.2 + 0.2 * np.sin(2 * i))) <= 0.02 for i, h in tracked), tracked
    (tmp_path / "a.mcap").write_bytes(b"")  # a log: refused before it is read
    code, _, err = run(capsys, "planes", tmp_path / "a.mcap", "--out", tmp_path / "log", "--fps", "2")
    assert code == 2 and "--fps 2 applies to a folder of depth images" in err, err
    for bad in ("0", "-5", "nan"):
        code, _, err = run(capsys, "planes", folder, "--out", tmp_path / f"bad{bad}", "--fps", bad)
        assert code == 2 and "is no frame rate" in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / f"bad{bad}").exists()
