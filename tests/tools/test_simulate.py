"""The log simulator: geometry against independent computations, the noise models against their definitions,
the blueprint against the walls, refusals of bad parameters, byte-identical logs, and logs that read back."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from kosmap.frontend.errors import ConfigError
from kosmap.frontend.logs import detect_topics, open_log
from kosmap.frontend.records import CameraModel, DepthFrame, Odometry, Scan, Transforms
from kosmap.tools.cli import main
from kosmap.tools.simulate import (FLYING_ID, DepthNoise, LaserModel, SimConfig, World, WorldError, camera_mount,
                            kinect_v2_model, laser_mount, load_world, render_depth, render_laser, simulate)
from kosmap.tools.simulate.motion import OdometryNoise, Trajectory, odometry, plan
from kosmap.tools.simulate.render import camera_pose, render_depth_geometry
from kosmap.tools.simulate.world import PathSpec, floorplan_rectangles


@pytest.fixture(scope="module")
def room() -> World:
    return load_world("room")


def back_project(depth: np.ndarray, pose, mount, model: CameraModel) -> np.ndarray:
    """World points (H×W×3) of a depth image (optical depth) of a camera at `mount` on a robot at `pose`."""
    pos, R = camera_pose(pose, mount)
    v, u = np.mgrid[0: model.height, 0: model.width]
    rays = np.stack(((u - model.cx) / model.fx, (v - model.cy) / model.fy, np.ones(u.shape)), axis=-1)
    return pos + (rays * depth[..., None].astype(float)) @ R.T


POSES = [(1.2, 1.4, 0.0), (3.8, 3.6, 2.6), (2.0, 4.0, -0.9)]
MOUNTS = [camera_mount(), camera_mount((0.1, 0.0, 0.6), (0.0, math.radians(25), 0.0)),
          camera_mount((0.0, 0.05, 1.3), (math.radians(8), math.radians(-10), math.radians(20)))]


# ---- geometry -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("mount", MOUNTS, ids=["level", "pitched", "rolled"])
def test_exact_depth_back_projects_onto_its_surfaces(room, mount):
    model = kinect_v2_model()
    for pose in POSES:
        depth, sid = render_depth(room, pose, mount, model)
        ok = depth > 0
        assert ok.mean() > 0.99  # a closed room: every ray meets something within 8 m
        pts = back_project(depth, pose, mount, model)[ok]
        d = room.surface_distance(sid[ok], pts)
        assert np.all(np.isfinite(d))
        assert np.max(np.abs(d)) < 2e-5  # float32 depth: a few µm at 5 m
        assert set(np.unique(sid[ok])) <= {s.id for s in room.surfaces}


def test_column_method_equals_3d_casting(room):
    """The per-column 2D shortcut gives exactly what casting every pixel in 3D gives, where it is valid."""
    model = kinect_v2_model()
    for pose in POSES:
        col = render_depth_geometry(room, pose, camera_mount(), model, method="column")
        for method in ("pixels", "naive"):
            ref = render_depth_geometry(room, pose, camera_mount(), model, method=method)
            assert np.array_equal(col[1], ref[1])
            assert np.max(np.abs(col[0] - ref[0])) < 1e-5
    pitched = camera_mount(rpy=(0.0, 0.2, 0.0))
    with pytest.raises(ValueError):
        render_depth_geometry(room, POSES[0], pitched, model, method="column")
    a = render_depth_geometry(room, POSES[0], pitched, model, method="pixels")
    b = render_depth_geometry(room, POSES[0], pitched, model, method="naive")
    assert np.array_equal(a[1], b[1]) and np.max(np.abs(a[0] - b[0])) < 1e-5


def _laser_reference(world: World, origin, angles, height):
    """Independent 2D ray casting at the laser's height: footprints of the solids that reach that height
    (the ramp's slope only where it is taller), as segments and circles."""
    best = np.full(len(angles), np.inf)
    d = np.column_stack((np.cos(angles), np.sin(angles)))
    for s in world.solids:
        if not (s.z0 <= height <= s.z1) or s.kind == "ramp":
            continue
        if s.circle is not None:
            cx, cy, r = s.circle
            f = np.asarray(origin) - [cx, cy]
            b = d @ f
            disc = b * b - (f @ f - r * r)
            t = -b - np.sqrt(np.maximum(disc, 0))
            best = np.where((disc >= 0) & (t > 0), np.minimum(best, t), best)
            continue
        poly = s.polygon
        for k in range(len(poly)):
            a, e = poly[k], poly[(k + 1) % len(poly)] - poly[k]
            den = d[:, 0] * e[1] - d[:, 1] * e[0]
            w = a - origin
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (w[0] * e[1] - w[1] * e[0]) / den
                u = (w[0] * d[:, 1] - w[1] * d[:, 0]) / den
            hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
            best = np.where(hit, np.minimum(best, t), best)
    return best


def test_laser_ranges_match_geometry(room):
    model = LaserModel()
    mount = laser_mount((0.15, 0.0, 0.35))
    for pose in POSES:
        r = render_laser(room, pose, mount, model)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        origin = np.array([pose[0] + 0.15 * c, pose[1] + 0.15 * s])
        ref = _laser_reference(room, origin, model.angles + pose[2], 0.35)
        assert len(r) == 1081 and r.dtype == np.float32
        assert np.all(np.isfinite(r))  # a closed room, 30 m range
        assert np.max(np.abs(r - ref)) < 1e-4
    # straight ahead from (1.2, 1.4): through the door gap (y 0.55..1.45) and over the 0.2 m box to the far wall
    r = render_laser(room, (1.2, 1.4, 0.0), mount, model)
    assert r[540] == pytest.approx(6.925 - 1.35, abs=1e-5)
    # with noise: σ 1 cm (datasheet), unbiased
    rng = np.random.default_rng(5)
    res = np.concatenate([render_laser(room, POSES[0], mount, model, rng=rng) - r for _ in range(20)])
    res = res[np.isfinite(res)]
    assert abs(res.mean()) < 0.001
    assert 0.0095 < res.std() < 0.0105


def test_table_seen_at_table_height_not_under_it(room):
    """The depth camera sees the table top at 0.75 m; under it only the legs (and the floor); the laser at
    0.35 m sees only the legs."""
    pose, mount, model = (0.9, 2.5, 0.0), camera_mount(), kinect_v2_model()
    depth, sid = render_depth(room, pose, mount, model)
    pts = back_project(depth, pose, mount, model)[depth > 0]
    ids = sid[depth > 0]
    over = (np.abs(pts[:, 0] - 2.5) < 0.6) & (np.abs(pts[:, 1] - 2.5) < 0.4)  # the table's footprint
    top = over & (pts[:, 2] > 0.72) & (pts[:, 2] < 0.76)  # the top slab spans 0.71..0.75 m
    assert top.sum() > 5000
    objs = {room.surface(i).obj for i in np.unique(ids[top])}
    assert objs <= {"table 0 top"}
    heights = pts[top & (ids == next(s.id for s in room.surfaces if s.cls == "table_top")), 2]
    assert np.allclose(heights, 0.75, atol=1e-5)
    under = over & (pts[:, 2] > 0.02) & (pts[:, 2] < 0.70)
    assert under.sum() > 100  # the legs
    assert {room.surface(i).obj for i in np.unique(ids[under])} == {"table 0 leg"}
    # laser at 0.35 m: beams towards the table hit legs or pass under it, never the top's edge at x = 1.9
    lm = laser_mount((0.15, 0.0, 0.35))
    r, lid = render_laser(room, pose, lm, LaserModel(), return_ids=True)
    hit_objs = {room.surface(i).obj for i in np.unique(lid) if i}
    assert "table 0 leg" in hit_objs and "table 0 top" not in hit_objs


def test_pitched_camera_sees_the_floor_where_geometry_says(room):
    """A camera 1 m up pitched 30° down: the centre pixel meets the floor 1/tan(30°) m ahead."""
    mount, model = camera_mount((0.0, 0.0, 1.0), (0.0, math.radians(30), 0.0)), kinect_v2_model()
    depth, sid = render_depth(room, (1.2, 3.6, 0.0), mount, model)  # facing +x: 3.7 m of floor to the wall
    v, u = 212, 256  # cy = 211.5: the optical axis lies between rows 211 and 212
    ray_z = (v - model.cy) / model.fy
    # optical depth along the ray of row v: the height drop 1 m = z·(sin30° + ray_z·cos30°)
    expected = 1.0 / (math.sin(math.radians(30)) + ray_z * math.cos(math.radians(30)))
    assert room.surface(sid[v, u]).cls == "floor"
    assert depth[v, u] == pytest.approx(expected, rel=1e-5)


# ---- noise ------------------------------------------------------------------------------------------------------------

def test_depth_noise_model_matches_the_kinect_v2_figures():
    n = DepthNoise()
    assert n.sigma(np.float32(1.0)) == pytest.approx(0.0015, rel=1e-3)
    assert n.sigma(np.float32(4.0)) == pytest.approx(0.010, rel=1e-3)
    # at 60° incidence the angle term adds σ_θ·z^1.5·θ²/(π/2 − θ)² = 0.1 mm·8·4
    th = math.radians(60)
    assert n.sigma(np.float32(4.0), np.float32(math.cos(th))) - n.sigma(np.float32(4.0)) == pytest.approx(
        1e-4 * 8 * th * th / (math.pi / 2 - th) ** 2, rel=1e-3)


def test_noisy_depth_lies_on_surfaces_within_the_noise_model(room):
    model, mount, noise = kinect_v2_model(), camera_mount(), DepthNoise()
    rng = np.random.default_rng(11)
    pose = POSES[0]
    exact, sid0, cos0 = render_depth_geometry(room, pose, mount, model)
    exact, sid0, cos0 = np.asarray(exact), np.asarray(sid0), np.asarray(cos0)
    normed, valid_frac, flying = [], [], []
    for _ in range(4):
        depth, sid = render_depth(room, pose, mount, model, rng=rng)
        valid = depth > 0
        valid_frac.append(valid.mean())
        flying.append((sid == FLYING_ID).mean())
        on = valid & (sid != FLYING_ID)
        assert np.all(sid[on] == sid0[on])  # a pixel that is not flying keeps its surface
        pts = back_project(depth, pose, mount, model)[on]
        d = room.surface_distance(sid[on], pts)
        # an axial error Δz moves the point by Δz·(a, b, 1); its distance to the surface by Δz·|cos θ|·|(a, b, 1)|
        v, u = np.nonzero(on)
        ray = np.sqrt(1 + ((u - model.cx) / model.fx) ** 2 + ((v - model.cy) / model.fy) ** 2)
        sigma = noise.sigma(exact[on], cos0[on]) * cos0[on] * ray
        normed.append(d / sigma)
    r = np.concatenate(normed)
    assert abs(r.mean()) < 0.01
    assert 0.97 < r.std() < 1.03
    assert np.mean(np.abs(r) > 4) < 1e-4
    # dropouts (random 0.5 %, grazing, corners) and flying pixels at depth edges are present, not dominant
    assert 0.85 < np.mean(valid_frac) < 0.97
    assert 0.001 < np.mean(flying) < 0.03


def test_depth_noise_grows_with_distance(room):
    """A frontal wall at ~1 m and ~4 m: measured σ against 1.5 mm and 1 cm."""
    model, mount = kinect_v2_model(), camera_mount((0.0, 0.0, 1.0))
    rng = np.random.default_rng(3)
    for dist, sigma in ((1.0, 0.0015), (4.0, 0.010)):
        pose = (4.925 - dist, 3.6, 0.0)  # facing the partition wall (its face at x = 4.925)
        exact, _ = render_depth(room, pose, mount, model)
        win = (slice(200, 224), slice(246, 266))  # centre: frontal, wall only
        assert np.allclose(exact[win], dist, atol=0.02)
        res = np.concatenate([(render_depth(room, pose, mount, model, rng=rng)[0] - exact)[win].ravel()
                              for _ in range(10)])
        res = res[np.abs(res) < 1.0]  # drop the rare dropouts (0)
        assert res.std() == pytest.approx(sigma, rel=0.08)


def test_depth_limits_and_empty_corners(room):
    model, mount = kinect_v2_model(), camera_mount()
    depth, sid = render_depth(room, (0.4, 2.5, 0.0), mount, model, rng=np.random.default_rng(0))
    assert depth.max() <= 8.0 and depth[depth > 0].min() >= 0.5
    assert np.all(depth[:5, :5] == 0) and np.all(depth[-5:, -5:] == 0)
    assert np.all(sid[depth == 0] == 0)


# ---- motion and odometry ------------------------------------------------------------------------------------------

def test_trajectory_stops_turns_in_place_and_keeps_speed_limits(room):
    traj = plan(room.path, 0.3, 0.6, 0.5, math.radians(45), math.radians(90), np.random.default_rng(0))
    t = np.arange(0.0, traj.duration, 0.01)
    p = traj.pose(t)
    v = np.hypot(*np.diff(p[:, :2], axis=0).T) / 0.01
    w = np.abs(np.diff(np.unwrap(p[:, 2]))) / 0.01
    assert v.max() <= 0.6 + 1e-6 and w.max() <= math.radians(45) + 1e-6
    both = (v > 1e-9) & (w > 1e-9)  # driving and turning at once: only in steps that straddle a turn's start or end
    assert both.sum() <= 2 * len(room.path.waypoints)
    end = traj.pose(traj.duration + 5.0)[0]
    assert np.allclose(end[:2], room.path.waypoints[-1], atol=1e-9)
    for wp in room.path.waypoints:
        assert np.min(np.hypot(*(p[:, :2] - wp).T)) < 0.01


def test_odometry_drifts_with_distance_and_rotation():
    traj = Trajectory((0.0, 0.0, 0.0))
    traj.drive((20.0, 0.0), 0.5, 0.5)
    true = traj.pose(np.append(np.arange(0.0, traj.duration, 0.02), traj.duration))
    exact = odometry(true, OdometryNoise(0, 0, 0, 0, 0, 0, 0, 0), np.random.default_rng(0))
    assert np.max(np.abs(exact - true)) < 1e-9
    scaled = odometry(true, OdometryNoise(0.01, 0, 0, 0, 0, 0, 0, 0), np.random.default_rng(0))
    assert scaled[-1, 0] == pytest.approx(20.2, abs=1e-6)  # 1 % of 20 m
    bias = odometry(true, OdometryNoise(0, 0, 0.1, 0, 0, 0, 0, 0), np.random.default_rng(0))
    assert math.degrees(bias[-1, 2]) == pytest.approx(2.0, abs=1e-6)  # 0.1°/m over 20 m
    # a turn in place: rotation scale error 1.5 % of 90°
    spin = Trajectory((0.0, 0.0, 0.0))
    spin.turn(math.pi / 2, 0.8, 1.5)
    tr = spin.pose(np.arange(0.0, spin.duration + 0.02, 0.02))
    rot = odometry(tr, OdometryNoise(0, 0.015, 0, 0, 0, 0, 0, 0), np.random.default_rng(0))
    assert math.degrees(rot[-1, 2]) == pytest.approx(90 * 1.015, abs=1e-6)
    assert np.allclose(rot[:, :2], 0.0)


# ---- blueprint --------------------------------------------------------------------------------------------------------

def test_blueprint_matches_the_walls(room, tmp_path):
    from kosmap.mapping.mapio import read_map_server, write_map_server

    g = room.blueprint(0.05)
    assert g.resolution == 0.05 and g.origin[2] == 0.0
    rows, cols = np.mgrid[0: g.height, 0: g.width]
    centres = g.center_of(cols.ravel(), rows.ravel())
    wall_d = np.min([w.footprint_distance(centres) for w in room.walls], axis=0).reshape(g.data.shape)
    x, y = centres[:, 0].reshape(g.data.shape), centres[:, 1].reshape(g.data.shape)
    inside = (x > 0.1) & (x < 6.9) & (y > 0.1) & (y < 4.9)
    assert np.all(g.data[wall_d == 0] == 100)  # every cell centred on a wall
    assert np.all(g.data[(wall_d > 0.05) & inside] == 0)  # free inside, furniture left out
    assert np.all(g.data[(x < -0.15) | (x > 7.15) | (y < -0.15) | (y > 5.15)] == -1)  # outside unknown
    # the door at (5, 1.0), 0.9 m wide, is open
    door = (np.abs(x - 5.0) < 0.05) & (np.abs(y - 1.0) < 0.4)
    assert door.any() and np.all(g.data[door] == 0)
    yp = write_map_server(g, tmp_path / "room.yaml", ".png")
    back = read_map_server(yp)
    assert np.array_equal(back.data, g.data) and back.origin == pytest.approx(g.origin)
    furn = room.blueprint(0.05, furniture=True)
    assert (furn.data == 100).sum() > (g.data == 100).sum()


def test_world_from_a_raster_floor_plan(tmp_path):
    """A world built from a map_server floor plan gives the laser what the segment world gives (± a cell)."""
    from kosmap.mapping.mapio import write_map_server

    (tmp_path / "walls.yaml").write_text(
        "walls:\n  - polyline: [[0, 0], [7, 0], [7, 5], [0, 5], [0, 0]]\n  - [5, 0, 5, 5]\n"
        "doors:\n  - {at: [5, 1.0], width: 0.9}\n")
    segs = load_world(tmp_path / "walls.yaml")
    write_map_server(segs.blueprint(0.05), tmp_path / "plan.yaml", ".png")
    (tmp_path / "raster.yaml").write_text("floorplan: plan.yaml\n")
    raster = load_world(tmp_path / "raster.yaml")
    assert len(raster.walls) < 40  # runs merged into rectangles
    for pose in ((1.2, 1.4, 0.0), (3.0, 3.0, 2.0), (6.0, 2.5, -1.0)):
        a, b = render_laser(segs, pose), render_laser(raster, pose)
        diff = np.abs(a - b)[np.isfinite(a) & np.isfinite(b)]
        assert np.median(diff) < 0.03 and np.quantile(diff, 0.95) < 0.08


def test_floorplan_rectangles_cover_exactly():
    rng = np.random.default_rng(0)
    occ = rng.random((30, 40)) < 0.3
    cover = np.zeros_like(occ, int)
    for c0, r0, c1, r1 in floorplan_rectangles(occ):
        cover[r0:r1, c0:c1] += 1
    assert np.array_equal(cover, occ.astype(int))


def test_office_world_has_what_the_issue_asks_for():
    w = load_world("office")
    x0, y0, x1, y1 = w.bounds
    assert x1 - x0 >= 40 and y1 - y0 >= 20
    classes = {s.cls for s in w.surfaces}
    assert {"floor", "ceiling", "wall", "table_top", "box_top", "box_side", "ramp", "cylinder"} <= classes
    tops = {round(s.offset, 3) for s in w.surfaces if s.cls == "table_top"}
    assert 0.75 in tops
    assert any(s.kind == "shelf" and s.z1 == pytest.approx(1.8) for s in w.solids)
    assert any(s.kind == "obstacle" and s.z1 == pytest.approx(0.2) for s in w.solids)
    traj = plan(w.path, 0.3, 0.6, 0.5, math.radians(45), math.radians(90), np.random.default_rng(0))
    assert traj.distance > 100
    p = traj.pose(np.arange(0.0, traj.duration, 1.0))
    # the loop closes: a place revisited more than two minutes later
    d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    dt = np.abs(np.arange(len(p))[:, None] - np.arange(len(p))[None, :])
    assert np.any((d < 0.5) & (dt > 120))


def test_office_survey_path_enters_every_room_and_looks_round():
    """The office's named `survey` path: legal (no wall or furniture within the robot's radius), and within 2.5 m of
    the middle of each of the 16 side rooms, where a {spin} turns the robot round so the camera looks all round."""
    from kosmap.tools.simulate.motion import check_path
    from kosmap.tools.simulate.world import SPIN_SIDE

    w = load_world("office")
    survey = w.paths["survey"]
    check_path(w, survey, SimConfig().robot_radius)
    traj = plan(survey, 0.3, 0.6, 0.5, math.radians(45), math.radians(90), np.random.default_rng(0))
    assert traj.distance > 300
    p = traj.pose(np.arange(0.0, traj.duration, 0.5))
    rooms = [(x + 4.0, y) for x in range(0, 48, 8) for y in (2.5, 21.5)] + [(2.5, 8.5), (2.5, 15.5), (45.5, 8.5), (45.5, 15.5)]
    for cx, cy in rooms:
        near = np.hypot(p[:, 0] - cx, p[:, 1] - cy) < 2.5
        assert near.any(), (cx, cy)
        # bearings the 70.6° camera looked along there, in 5° bins: all but a few
        look = (p[near, 2][:, None] + np.radians(np.arange(-35, 36, 5))[None, :]).ravel()
        assert len(np.unique(np.floor(np.mod(np.degrees(look), 360) / 5))) >= 68, (cx, cy)  # ≥ 340° of 360°
    wps = survey.waypoints  # a spin is a square of SPIN_SIDE back to its start
    k = next(i for i in range(len(wps) - 4) if np.allclose(wps[i + 1] - wps[i], [SPIN_SIDE, 0.0]))
    assert np.allclose(wps[k + 4], wps[k]) and np.allclose(wps[k + 2] - wps[k], [SPIN_SIDE, SPIN_SIDE])


def test_named_path_and_spin_errors(tmp_path, capsys):
    bad = tmp_path / "w.yaml"
    bad.write_text("walls:\n  - [0, 0, 4, 0]\npaths:\n  tour:\n    waypoints: [[1, 1], {turn: [2, 2]}]\n")
    with pytest.raises(WorldError, match=r"waypoint 1 must be \[x, y\] or \{spin"):
        load_world(bad)
    code = main(["simulate", "office", "--out", str(tmp_path / "o.mcap"), "--path", "grand_tour"])
    err = capsys.readouterr().err
    assert code == 2 and "no such file" in err and "survey" in err and not list(tmp_path.glob("o.mcap*"))


# ---- bad parameters -----------------------------------------------------------------------------------------------

def test_bad_parameters_are_refused(room, tmp_path):
    out = tmp_path / "x.mcap"
    with pytest.raises(WorldError, match="passes through wall"):
        simulate(room, SimConfig(), out, PathSpec(np.array([[1.0, 2.5], [6.0, 3.0]])))
    with pytest.raises(WorldError, match="passes through table"):
        simulate(room, SimConfig(), out, PathSpec(np.array([[1.0, 2.5], [4.0, 2.5]])))
    with pytest.raises(WorldError, match="outside the world"):
        simulate(room, SimConfig(), out, PathSpec(np.array([[1.0, 2.5], [9.0, 2.5]])))
    with pytest.raises(WorldError, match="camera .* outside the world"):
        simulate(room, SimConfig(camera_xyz=[0.1, 0.0, 3.5], duration=1.0), out)
    with pytest.raises(WorldError, match="laser would be inside"):
        simulate(room, SimConfig(laser_xyz=[1.0, 0.0, 0.3]), out)  # 1 m ahead: into the shelf
    for bad in ({"depth_rate": -30.0}, {"laser_rate": 0.0}, {"odom_rate": -1.0}, {"speed_min": 0.7},
                {"duration": -1.0}, {"camera_xyz": [0, 1]}, {"compression": "gzip"}):
        with pytest.raises(ConfigError):
            SimConfig(**bad)
    with pytest.raises(WorldError, match="unknown world"):
        load_world("castle")
    bad_door = tmp_path / "w.yaml"
    bad_door.write_text("walls:\n  - [0, 0, 4, 0]\ndoors:\n  - {at: [2, 3]}\n")
    with pytest.raises(WorldError, match="on no wall"):
        load_world(bad_door)
    bad_key = tmp_path / "k.yaml"
    bad_key.write_text("walls:\n  - [0, 0, 4, 0]\nfurnitures: []\n")
    with pytest.raises(WorldError, match="unknown key"):
        load_world(bad_key)
    assert not list(tmp_path.glob("x.mcap*"))


def test_cli_refuses_with_one_line_and_leaves_no_file(capsys, tmp_path):
    (tmp_path / "out").mkdir()
    out = tmp_path / "out" / "log.mcap"
    way = tmp_path / "through_wall.txt"
    way.write_text("1.0 2.5\n6.0 3.0\n")
    for argv, words in (
        (["--path", str(way)], ["passes through wall"]),
        (["--set", "depth_rate=-5"], ["depth_rate", "> 0"]),
        (["--camera-height", "4.0"], ["camera", "outside the world"]),
        (["--duration", "-2"], ["duration"]),
        (["--set", "nonsense=1"], ["unknown simulator setting"]),
    ):
        code = main(["simulate", "room", "--out", str(out), *argv])
        _, err = capsys.readouterr()
        assert code == 2, (argv, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("kosmap: error: ") and "Traceback" not in err
        for w in words:
            assert w in lines[0]
        assert not list((tmp_path / "out").iterdir()), argv


# ---- the log ----------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def room_log(tmp_path_factory, room) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("sim") / "room.mcap"
    cfg = SimConfig(seed=7, duration=1.0, surface_ids=True, rear_camera=True)
    return out, simulate(room, cfg, out)


def test_same_seed_gives_identical_bytes(room, tmp_path):
    cfg = dict(duration=0.4, surface_ids=True, laser_dropout=0.05)
    logs = []
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        simulate(room, SimConfig(seed=seed, **cfg), tmp_path / f"{name}.mcap")
        logs.append((tmp_path / f"{name}.mcap").read_bytes())
    assert logs[0] == logs[1]
    assert logs[0] != logs[2]


def test_log_reads_back_through_open_log(room, room_log):
    out, summary = room_log
    with open_log(out) as log:
        info = log.info()
        counts = {t.name: t.count for t in info.topics}
        assert counts["/kinect2/sd/image_depth_rect"] == 30 and counts["/kinect2_rear/sd/image_depth_rect"] == 30
        assert counts["/kinect2/sd/surface_id"] == 30 and counts["/kinect2/sd/camera_info"] == 30
        assert counts["/scan"] == 40 and counts["/odom"] == 50 and counts["/ground_truth/odom"] == 101
        assert counts["/tf_static"] == 1 and counts["/imu"] == 200  # 1 s at 200 Hz
        det = detect_topics(info.types())
        assert det.depth == ["/kinect2/sd/image_depth_rect", "/kinect2_rear/sd/image_depth_rect"]
        assert det.info["/kinect2_rear/sd/image_depth_rect"] == "/kinect2_rear/sd/camera_info"
        assert det.scan == "/scan" and det.odom == "/odom" and det.ground_truth == "/ground_truth/odom"
        recs = list(log.read(det.wanted() + ["/kinect2/sd/surface_id"]))
    stamps = [r.stamp_ns for r in recs]
    assert stamps == sorted(stamps)
    tf = next(r for r in recs if isinstance(r, Transforms))
    mounts = {t.child: t for t in tf.transforms}
    assert set(mounts) == {"kinect2_ir_optical_frame", "kinect2_rear_ir_optical_frame", "laser", "imu_link"}
    assert np.allclose(mounts["imu_link"].matrix(), np.eye(4)) and mounts["imu_link"].parent == "base_link"
    Rm = mounts["kinect2_ir_optical_frame"].matrix()[:3, :3]
    assert np.allclose(Rm, [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-12)  # REP 103: z forward, x right, y down
    assert np.allclose(mounts["kinect2_rear_ir_optical_frame"].matrix()[:3, 2], [-1, 0, 0], atol=1e-12)
    frames = [r for r in recs if isinstance(r, DepthFrame) and r.topic == "/kinect2/sd/image_depth_rect"]
    assert frames[0].encoding == "16UC1" and frames[0].image.shape == (424, 512)
    assert frames[0].frame_id == "kinect2_ir_optical_frame"
    cam = next(r for r in recs if isinstance(r, CameraModel) and r.topic == "/kinect2/sd/camera_info")
    assert cam.fx == pytest.approx(kinect_v2_model().fx)
    scans = [r for r in recs if isinstance(r, Scan)]
    assert len(scans[0].ranges) == 1081 and scans[0].frame_id == "laser"
    assert scans[0].angle_increment == pytest.approx(math.radians(0.25))
    gt = [r for r in recs if isinstance(r, Odometry) and r.topic == "/ground_truth/odom"]
    odom = [r for r in recs if isinstance(r, Odometry) and r.topic == "/odom"]
    assert gt[0].frame_id == "map" and odom[0].frame_id == "odom" and odom[0].x == 0.0
    # end to end: the logged depth, through CameraInfo, /tf_static and the true pose, lies on its surfaces
    ids = {r.stamp_ns: r for r in recs if isinstance(r, DepthFrame) and r.topic == "/kinect2/sd/surface_id"}
    gt_t = np.array([g.stamp_ns for g in gt], float)
    gt_p = np.array([[g.x, g.y, np.unwrap([g.yaw])[0]] for g in gt])
    f = frames[10]
    pose = [np.interp(f.stamp_ns, gt_t, gt_p[:, k]) for k in range(3)]
    depth = f.meters()
    sid = ids[f.stamp_ns].image
    ok = (depth > 0) & (sid != FLYING_ID)
    assert np.all(sid[depth == 0] == 0)
    mount = mounts["kinect2_ir_optical_frame"]
    pts = back_project(depth, pose, mount, cam)[ok]
    d = room.surface_distance(sid[ok], pts)
    exact, _, cos_inc = render_depth_geometry(room, pose, mount, cam)  # for σ(z, θ) of each pixel
    v, u = np.nonzero(ok)
    ray = np.sqrt(1 + ((u - cam.cx) / cam.fx) ** 2 + ((v - cam.cy) / cam.fy) ** 2)
    normed = d / (DepthNoise().sigma(exact[ok], cos_inc[ok]) * cos_inc[ok] * ray)
    assert abs(np.mean(normed)) < 0.05 and 0.95 < np.std(normed) < 1.1  # 1 mm steps add a little
    assert np.mean(np.abs(normed) > 5) < 1e-3
    assert summary["depth_frames"] == 60 and summary["scans"] == 40


def test_log_reads_with_rosbags(room_log):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out, _ = room_log
    with AnyReader([out], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/kinect2/sd/image_depth_rect"] == "sensor_msgs/msg/Image"
        assert types["/scan"] == "sensor_msgs/msg/LaserScan"
        assert types["/ground_truth/odom"] == "nav_msgs/msg/Odometry"
        n = 0
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            n += 1
            if conn.topic == "/kinect2/sd/image_depth_rect":
                assert (msg.width, msg.height, msg.encoding, msg.step) == (512, 424, "16UC1", 1024)
        assert n == sum(c.msgcount for c in reader.connections)


def test_cli_writes_log_blueprint_and_settings(capsys, tmp_path):
    out, bp, toml = tmp_path / "r.mcap", tmp_path / "bp.yaml", tmp_path / "sim.toml"
    toml.write_text("[simulate]\ndepth_rate = 10.0\nodom_rate = 20\n")
    code = main(["simulate", "room", "--out", str(out), "--duration", "0.3", "--seed", "2", "--no-laser",
                 "--camera-pitch", "10", "--blueprint", str(bp), "--config", str(toml), "--set", "odom_rate=25", "-q"])
    assert code == 0, capsys.readouterr().err
    assert out.is_file() and bp.is_file() and bp.with_suffix(".png").is_file()
    side = out.with_suffix(".sim.yaml")
    import yaml

    doc = yaml.safe_load(side.read_text())
    assert doc["config"]["camera_rpy_deg"] == [0.0, 10.0, 0.0] and doc["config"]["laser"] is False
    assert doc["config"]["depth_rate"] == 10.0 and doc["config"]["odom_rate"] == 25.0  # --set beats the file
    with open_log(out) as log:
        info = log.info()
        assert "/scan" not in info.types()
        assert info.count("/kinect2/sd/image_depth_rect") == 3 and info.count("/odom") == 8
    assert not list(tmp_path.glob("*.partial"))


# ---- any number of depth cameras ---------------------------------------------------------------------------------

LEFT = {"ns": "/kinect2_left/sd", "frame": "kinect2_left_ir_optical_frame", "xyz": [0, 0.1, 1.0], "rpy_deg": [0, 0, 90]}


def test_three_cameras_read_back_each_with_its_info_and_mount(capsys, tmp_path):
    """Front, rear and a left-facing camera from a TOML list of tables (the left one) and --camera (a fourth, pitched
    one on the right, frame from its namespace): each depth topic is matched to its own camera_info and mounted
    in /tf_static where it was put."""
    toml, out = tmp_path / "sim.toml", tmp_path / "cams.mcap"
    toml.write_text('[simulate]\nextra_cameras = [{ns = "/kinect2_left/sd", frame = "kinect2_left_ir_optical_frame", '
                    'xyz = [0, 0.1, 1.0], rpy_deg = [0, 0, 90]}]\n')
    code = main(["simulate", "room", "--out", str(out), "--duration", "0.2", "--rear-camera", "--surface-ids",
                 "--config", str(toml), "--camera", "/kinect2_right/sd:0,-0.1,0.9:0,20,-90", "--no-laser", "-q"])
    assert code == 0, capsys.readouterr().err
    names = ["/kinect2/sd", "/kinect2_rear/sd", "/kinect2_left/sd", "/kinect2_right/sd"]
    frames = ["kinect2_ir_optical_frame", "kinect2_rear_ir_optical_frame", "kinect2_left_ir_optical_frame",
              "kinect2_right_ir_optical_frame"]
    with open_log(out) as log:
        info = log.info()
        det = detect_topics(info.types())
        assert det.depth == [f"{n}/image_depth_rect" for n in ["/kinect2/sd", "/kinect2_left/sd", "/kinect2_rear/sd",
                                                                "/kinect2_right/sd"]]
        for n in names:
            assert det.info[f"{n}/image_depth_rect"] == f"{n}/camera_info"
            assert info.count(f"{n}/image_depth_rect") == 6 and info.count(f"{n}/surface_id") == 6
        recs = list(log.read(det.wanted()))
    tf = next(r for r in recs if isinstance(r, Transforms))
    mounts = {t.child: t.matrix() for t in tf.transforms}
    assert set(mounts) == set(frames) | {"imu_link"}
    # the optical axis (z) of each camera in base_link, and its position
    for frame, pos, axis in (("kinect2_ir_optical_frame", [0.1, 0, 1.0], [1, 0, 0]),
                             ("kinect2_rear_ir_optical_frame", [-0.1, 0, 1.0], [-1, 0, 0]),
                             ("kinect2_left_ir_optical_frame", [0, 0.1, 1.0], [0, 1, 0]),
                             ("kinect2_right_ir_optical_frame", [0, -0.1, 0.9],
                              [0, -math.cos(math.radians(20)), -math.sin(math.radians(20))])):
        assert np.allclose(mounts[frame][:3, 3], pos, atol=1e-12)
        assert np.allclose(mounts[frame][:3, 2], axis, atol=1e-12), frame
    by_topic = {}
    for r in recs:
        if isinstance(r, DepthFrame):
            by_topic.setdefault(r.topic, r.frame_id)
    assert [by_topic[f"{n}/image_depth_rect"] for n in names] == frames
    import yaml

    doc = yaml.safe_load(out.with_suffix(".sim.yaml").read_text())
    assert doc["config"]["extra_cameras"] == [
        {"ns": "/kinect2_left/sd", "frame": "kinect2_left_ir_optical_frame", "xyz": [0.0, 0.1, 1.0],
         "rpy_deg": [0.0, 0.0, 90.0]},
        {"ns": "/kinect2_right/sd", "frame": "kinect2_right_ir_optical_frame", "xyz": [0.0, -0.1, 0.9],
         "rpy_deg": [0.0, 20.0, -90.0]}]


def test_extra_cameras_leave_the_front_camera_bytes_alone(room, tmp_path):
    """Each camera draws from its own random stream: adding one changes nothing the front camera wrote."""
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    simulate(room, SimConfig(seed=5, duration=0.1, laser=False), a)
    simulate(room, SimConfig(seed=5, duration=0.1, laser=False, extra_cameras=[LEFT]), b)
    with open_log(a) as la, open_log(b) as lb:
        fa = [r.image for r in la.read(["/kinect2/sd/image_depth_rect"])]
        fb = [r.image for r in lb.read(["/kinect2/sd/image_depth_rect"])]
    assert len(fa) == len(fb) == 3 and all(np.array_equal(x, y) for x, y in zip(fa, fb))


def test_bad_extra_cameras_are_refused(room, capsys, tmp_path):
    for entry, words in (({"frame": "f", "xyz": [0, 0, 1]}, ["extra_cameras[0]", "missing 'ns'"]),
                         ({**LEFT, "ns": "/kinect2/sd"},
                          ["extra_cameras[0]", "namespace '/kinect2/sd'", "front camera"]),
                         ({**LEFT, "ns": "/other/sd", "frame": "kinect2_ir_optical_frame"}, ["frame", "already used"]),
                         ({**LEFT, "xyz": [0, 1]}, ["xyz must be 3 numbers"]),
                         ({**LEFT, "fov": 90}, ["unknown key 'fov'"])):
        with pytest.raises(ConfigError, match=r"\[simulate\] extra_cameras\[0\]") as e:
            SimConfig(extra_cameras=[entry])
        assert all(w in str(e.value) for w in words) and "\n" not in str(e.value), (entry, e.value)
    with pytest.raises(WorldError, match=r"camera /up/sd would be outside the world .* check extra_cameras\[0\]\.xyz"):
        simulate(room, SimConfig(duration=0.5, extra_cameras=[{"ns": "/up/sd", "xyz": [0, 0, 3.0]}]),
                 tmp_path / "x.mcap")
    with pytest.raises(WorldError, match=r"inside shelf.* check extra_cameras\[0\]\.xyz"):
        simulate(room, SimConfig(extra_cameras=[{"ns": "/far/sd", "xyz": [1.0, 0, 0.3]}]), tmp_path / "x.mcap")
    (tmp_path / "out").mkdir()
    out = tmp_path / "out" / "log.mcap"
    for argv, words in ((["--camera", "/kinect2_rear/sd:0,0"], ["--camera", "NS:x,y,z"]),
                        (["--camera", "/a/sd:0,0,1", "--camera", "/a/sd:0,0,1.2"],
                         ["extra_cameras[1]", "already used"]),
                        (["--camera", "/a/sd:0,0,3.5"], ["outside the world", "extra_cameras[0].xyz"]),
                        (["--set", 'extra_cameras=[{ns = "/a/sd"}]'], ["missing 'xyz'"])):
        code = main(["simulate", "room", "--out", str(out), *argv])
        _, err = capsys.readouterr()
        assert code == 2, (argv, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("kosmap: error: ") and "Traceback" not in err
        assert all(w in lines[0] for w in words), (argv, lines[0])
        assert not list((tmp_path / "out").iterdir()), argv
