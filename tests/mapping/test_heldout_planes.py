"""`kosmap planes` on held-out worlds (tests/worlds/) with a depth camera pitched down at a height the defaults do not
assume, in a log with no /tf_static and no IMU (nothing tells the run the mount): gravity from the frames must make
the floor 'ground'. Scored per plane against the simulator's surface ids (a plane's majority surface): the goals
are ≥ 90 % of the floor planes classified ground and ≥ 98 % of the ground planes on the floor. Only sizeable planes
count, as in tests/frontend/test_gravity.py (1000 of a 512×424 image's pixels there): ≥ 0.5 % of the image, since
small strips cut across corners fit anything."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kosmap.tools.cli import main

WORLDS = Path(__file__).resolve().parents[1] / "worlds"


def _floor_and_ground(log: Path, out: Path, world) -> tuple[int, int, int]:
    """Sizeable planes: on the floor, on the floor and classified ground, classified ground."""
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.planes import PLANE_CLASSES

    with open_log(log) as lg:
        sids = {r.stamp_ns: r.image for r in lg.read(["/kinect2/sd/surface_id"])}
    ground_cls = PLANE_CLASSES.index("ground")
    floor = floor_ground = ground = 0
    for f in sorted((out / "planes").glob("*.npz")):
        z = np.load(f)
        sid = sids[int(z["stamp_ns"])]
        for k, cls in enumerate(z["classes"]):
            if z["counts"][k] < 0.005 * sid.size:
                continue
            px = z["pixels"][z["plane"] == k]
            ids = sid[px[:, 0], px[:, 1]]
            ids = ids[(ids > 0) & (ids < 65535)]  # 0: no depth, 65535: a flying pixel
            if not len(ids):
                continue
            on_floor = world.surface(int(np.bincount(ids).argmax())).cls == "floor"
            floor += on_floor
            ground += cls == ground_cls
            floor_ground += on_floor and cls == ground_cls
    return floor, floor_ground, ground


@pytest.mark.slow
@pytest.mark.parametrize("world, seed, pitch, height", [("ward", 4, 20.0, 1.3), ("atrium", 4, 25.0, 0.8)])
def test_pitched_camera_without_mount_or_imu_sees_the_floor_as_ground(tmp_path, capsys, world, seed, pitch, height):
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    w = load_world(str(WORLDS / f"{world}.yaml"))
    log = tmp_path / f"{world}.mcap"
    simulate(w, SimConfig(seed=seed, duration=30.0, depth_rate=2.0, depth_width=256, depth_height=212, laser=False,
                          imu=False, tf_static=False, surface_ids=True, camera_xyz=[0.1, 0.0, height],
                          camera_rpy_deg=[0.0, pitch, 0.0], compression="lz4"), log)
    out = tmp_path / "planes"
    code = main(["planes", str(log), "--out", str(out), "--figures", "0", "--no-mcap", "--set",
                 "fspf.drop_classes=[]"])  # keep every class, to score them
    assert code == 0, capsys.readouterr().err
    assert "gravity: the frames" in capsys.readouterr().out
    floor, floor_ground, ground = _floor_and_ground(log, out, w)
    assert floor >= 40, floor
    assert floor_ground / floor >= 0.90, (floor_ground, floor)
    assert floor_ground / ground >= 0.98, (floor_ground, ground)
