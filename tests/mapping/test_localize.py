"""`kosmap localize`: simulated depth-camera logs (no laser) of the room and the office localized in their buildings'
blueprints with no initial pose, scored against the log's ground truth without alignment (and the office's look-alike
corridors never claimed); 30 s without any sensor while the robot drives on; a kidnapped robot; a real laser log
localized in the map `kosmap slam` built from it, with worse odometry; the one-line refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kosmap.tools.cli import main


def _simulate(world: str, out, duration: float, seed: int, waypoints=None, **kw):
    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate
    from kosmap.tools.simulate.world import PathSpec

    w = load_world(world)
    # 10 Hz depth at half resolution (same 70.6° view), no laser: the depth camera is all localize may use
    cfg = SimConfig(seed=seed, duration=duration, depth_rate=10.0, depth_width=256, depth_height=212, laser=False,
                    compression="lz4", **kw)
    simulate(w, cfg, out / f"{world}.mcap", None if waypoints is None else PathSpec(np.asarray(waypoints, float)))
    write_map_server(w.blueprint(), out / f"{world}_plan.yaml", image_ext=".png")
    return out / f"{world}.mcap", out / f"{world}_plan.yaml"


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    loop = [[3.8, 1.4], [3.8, 3.6], [1.2, 3.6], [1.2, 1.4]]  # the room's loop round the table, three times
    return _simulate("room", tmp_path_factory.mktemp("loc"), 80.0, seed=1, waypoints=[[1.2, 1.4]] + loop * 3)


def _localize(log, plan, out, capsys, *extra) -> dict:
    code = main(["localize", str(log), "--map", str(plan), "--out", str(out), "--quiet", *extra])
    assert code == 0, capsys.readouterr().err
    return json.loads((out / "metrics.json").read_text())


class Scored:
    """A log localized: its metrics, the per-pose status, log seconds and position error against the log's own truth
    (not aligned)."""

    def __init__(self, log, out, m: dict, truth=None) -> None:
        from kosmap.frontend.logs import open_log
        from kosmap.frontend.records import Odometry

        self.m, self.loc = m, m["localization"]
        self.status = np.genfromtxt(out / "confidence.csv", delimiter=",", names=True, dtype=None,
                                    encoding=None)["status"]
        tum = np.loadtxt(out / "trajectory.tum")
        if truth is not None:  # a TUM file of the truth (x, y in columns 1, 2)
            gt = np.loadtxt(truth)[:, :3]
        else:
            with open_log(log) as lg:
                gt = np.array([(r.stamp_ns * 1e-9, r.x, r.y) for r in lg.read(["/ground_truth/odom"])
                               if isinstance(r, Odometry)])
        self.err = np.hypot(tum[:, 1] - np.interp(tum[:, 0], gt[:, 0], gt[:, 1]),
                            tum[:, 2] - np.interp(tum[:, 0], gt[:, 0], gt[:, 2]))
        self.t = tum[:, 0] - tum[0, 0]
        t0 = tum[0, 0]
        # the truth's position at log seconds t (from the first scan)
        self.truth_xy = lambda t: (np.interp(t0 + t, gt[:, 0], gt[:, 1]), np.interp(t0 + t, gt[:, 0], gt[:, 2]))


@pytest.fixture
def localized(tmp_path, capsys):
    """localized(make, *extra): the log `make(path)` writes, localized in its plan, scored (a Scored)."""

    def run(make, plan, *extra, truth=None) -> Scored:
        log = make(tmp_path / "derived.mcap")
        out = tmp_path / "out"
        if truth is not None:
            extra = (*extra, "--ground-truth", str(truth))
        return Scored(log, out, _localize(log, plan, out, capsys, *extra), truth)

    return run


@pytest.mark.slow
def test_room_localized_in_its_blueprint_without_an_initial_pose(room, tmp_path, capsys):
    log, plan = room
    out = tmp_path / "out"
    m = _localize(log, plan, out, capsys)
    loc, tr = m["localization"], m["truth"]["after_convergence"]
    assert m["run"]["source"] == "kos" and m["run"]["wheel_odometry"] and m["run"]["gyro"]
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0, loc
    # measured (80 s, three loops): found at 5.5 s, then position RMSE 0.016 m (median 0.015 m)
    assert tr["position_m"]["rmse"] <= 0.05 and tr["position_m"]["median"] <= 0.035, tr
    assert tr["heading_deg"]["rmse"] <= 1.0, tr
    assert not loc["lost"], loc
    for name in ("trajectory.tum", "confidence.csv", "report.html", "report.md", "localization.png", "confidence.png",
                 "kosmap.mcap", "config.toml"):
        assert (out / name).is_file(), name
    traj = np.loadtxt(out / "trajectory.tum")
    assert traj.shape == (m["run"]["scans"], 8)
    # a depth frame is read after 0.2 m or 15° of the wheels' motion (AMCL's update_min_d / update_min_a) and at
    # least every 0.5 s: measured 172 of the log's 800 frames, a pose at least every 0.5 s
    assert m["run"]["scans"] <= 0.4 * 800 and np.max(np.diff(traj[:, 0])) <= 0.55, (m["run"]["scans"], traj[:, 0])
    assert "[localize]" in (out / "config.toml").read_text()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [7, 8])
def test_room_claim_at_a_corner_is_matched_on_the_walls_near_face(tmp_path, localized, seed):
    """The room's bundled path, claimed at its south-east corner while turning: the claim's pose can lie a wall's
    thickness off, its rays ending on the east wall's far face, which the matcher's field rewards as its near one,
    and the pull towards the prediction holds it there (0.15 m off for 8 s on these seeds). The refinement takes
    the readings through the walls as impossible: then the match is pulled towards the pose whose rays pass through
    the fewest walls. Measured: found at 7.7-10.0 / 9.2 s, then 0.017-0.020 / 0.020-0.023 m RMSE, at most 0.041 /
    0.057 m off."""
    log, plan = _simulate("room", tmp_path, 50.0, seed=seed)
    r = localized(lambda p: log, plan)
    loc, tr = r.loc, r.m["truth"]["after_convergence"]
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0 and not loc["lost"], loc
    # the goal is 0.05 m; the far face's claim (0.15 m off for 8 s) gave 0.064-0.074 m on these seeds, so the bound
    # sits between the two, and the largest error stays clear of the far face
    assert tr["position_m"]["rmse"] <= 0.035 and tr["position_m"]["max"] <= 0.08, tr
    assert tr["heading_deg"]["rmse"] <= 1.0, tr


@pytest.mark.slow
def test_atrium_tracked_through_scans_with_too_few_end_points(tmp_path, localized):
    """The held-out hall (walls at 30 and 60 degrees, pillars, a glazed gallery), its bundled path: facing the open
    hall beyond the camera's 4.5 m a scan has fewer end points than a match needs, and the track moves on through it
    by the odometry. Restarted at the filter's pose there, it took that pose's error: single scans 0.3-1 m and
    7-55 degrees off, 0.16-0.23 m and 9-10 degrees RMSE on seeds 1-3. Measured: found at 13.0 s, then 0.021 m RMSE,
    at most 0.043 m and 0.59 degrees off (seeds 2, 3: 0.026 / 0.039 m, at most 0.052 / 0.092 m)."""
    from pathlib import Path

    from kosmap.mapping.mapio import write_map_server
    from kosmap.tools.simulate import SimConfig, load_world, simulate

    w = load_world(str(Path(__file__).resolve().parents[1] / "worlds" / "atrium.yaml"))
    log, plan = tmp_path / "atrium.mcap", tmp_path / "atrium_plan.yaml"
    simulate(w, SimConfig(seed=1, duration=50.0, depth_rate=10.0, depth_width=256, depth_height=212, laser=False,
                          compression="lz4"), log, None)
    write_map_server(w.blueprint(), plan, image_ext=".png")
    r = localized(lambda p: log, plan)
    loc, tr = r.loc, r.m["truth"]["after_convergence"]
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0 and not loc["lost"], loc
    assert tr["position_m"]["rmse"] <= 0.05 and tr["position_m"]["max"] <= 0.15, tr
    assert tr["heading_deg"]["rmse"] <= 1.0 and tr["heading_deg"]["max"] <= 3.0, tr


@pytest.mark.slow
def test_without_wheel_odometry_or_gyro_the_depth_camera_alone_finds_the_pose(room, tmp_path, capsys):
    from tests.frontend.synthetic_log import copy_log

    log, plan = room
    bare = copy_log(log, tmp_path / "bare.mcap", lambda r: r.topic not in ("/odom", "/imu"))
    m = _localize(bare, plan, tmp_path / "out", capsys)
    assert not m["run"]["wheel_odometry"] and not m["run"]["gyro"]
    loc, tr = m["localization"], m["truth"]["after_convergence"]
    # measured: found at 9.5 s, then a median 0.15 m off (RMSE 0.88 m: lost 5 times, the random walk between views
    # instead of the odometry lets the set drift onto a look-alike corner for a while before it is found again)
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0, loc
    assert tr["position_m"]["median"] <= 0.3, tr


def _drop(src, dst, t_from: float, t_to: float):
    """The log with every sensor message (depth, odometry, IMU) between t_from and t_to s dropped, while the robot
    drives on: only the ground truth keeps going."""
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.writer import McapWriter

    with open_log(src) as log, McapWriter(dst) as w:
        t0 = None
        for r in log.read(log.info().types()):
            t = getattr(r, "stamp_ns", 0)
            if t:
                t0 = t if t0 is None else t0
                if t_from <= (t - t0) * 1e-9 <= t_to and r.topic != "/ground_truth/odom":
                    continue
            w.write(r, r.topic)
    return dst


@pytest.mark.slow
def test_sensor_gap_while_driving_is_detected_and_the_pose_found_again(room, localized):
    log, plan = room
    gap_from, gap_to = 25.0, 55.0  # 30 s without any sensor while the robot drives on round the table
    r = localized(lambda p: _drop(log, p, gap_from, gap_to), plan)
    loc = r.loc
    assert loc["converged_s"] is not None and loc["converged_s"] < gap_from, loc
    lost = [s for s in loc["lost"] if s["start_s"] >= gap_from - 0.5]
    assert lost and lost[0]["start_s"] <= gap_to + 1.0, loc  # detected as soon as the scans resume
    assert lost[0]["recovered_s"] is not None and lost[0]["recovered_s"] <= gap_to + 15.0, lost
    after = r.t >= lost[0]["recovered_s"]
    assert after.any() and np.mean(r.status[after] == "tracking") >= 0.95, r.status[after]
    assert np.sqrt(np.mean(r.err[after] ** 2)) <= 0.2, r.err[after]
    assert r.err[-1] <= 0.05, r.err[after]


def _splice(src, dst, cut_s: float, resume_s: float):
    """The log up to `cut_s`, then from `resume_s` on, shifted back to follow without a pause: the robot is carried
    from where it was at cut_s to where it was at resume_s (kidnapped). The wheel odometry continues from its last
    pose by the second part's own motion, as the robot's wheels would report it; the truth jumps. The truth is also
    written to `dst`.tum, read from the records before they are written: a reader bridges a pose jump faster than
    any robot drives (frontend/logs/validate.py) on every odometry topic, and a carry over 2 m is one."""
    import dataclasses

    from kosmap.backend.trajio import write_tum
    from kosmap.frontend import se2
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import Odometry

    with open_log(src) as log:
        recs = list(log.read(log.info().types()))
    t0 = min(r.stamp_ns for r in recs if getattr(r, "stamp_ns", 0))
    cut, resume = t0 + int(cut_s * 1e9), t0 + int(resume_s * 1e9)
    odom = [r for r in recs if isinstance(r, Odometry) and r.topic == "/odom"]
    last = next(r for r in reversed(odom) if r.stamp_ns <= cut)
    first = next(r for r in odom if r.stamp_ns >= resume)
    base, ref = np.array([last.x, last.y, last.yaw]), np.array([first.x, first.y, first.yaw])
    truth = []
    with McapWriter(dst) as w:
        for r in recs:
            t = getattr(r, "stamp_ns", 0)
            if t and cut < t < resume:
                continue
            if t and t >= resume:
                r = dataclasses.replace(r, stamp_ns=t - (resume - cut))
                if isinstance(r, Odometry) and r.topic == "/odom":
                    x, y, yaw = se2.compose(base, se2.between(ref, np.array([r.x, r.y, r.yaw])))
                    r = dataclasses.replace(r, x=float(x), y=float(y), yaw=float(yaw))
            if isinstance(r, Odometry) and r.topic == "/ground_truth/odom":
                truth.append((r.stamp_ns * 1e-9, r.x, r.y, r.yaw))
            w.write(r, r.topic)
    tr = np.array(truth)
    write_tum(dst.with_suffix(".tum"), tr[:, 0], tr[:, 1:])
    return dst


@pytest.mark.slow
@pytest.mark.parametrize("cut, resume, detect_s, recover_s", [
    # carried 1.8 m and turned a quarter, onto the room's own quarter-turn symmetry: the bare 5 x 5 m plan fits the
    # held pose as well as the truth until the door to the side room is in view. Measured (seeds 1-3): the wrong
    # pose abandoned (lost) 2.2-22 s after the carry, the right one tracked for good 22-24 s after it, then
    # 0.019-0.079 m RMSE
    (12.0, 20.0, 25.0, 30.0),
    # carried 2.1 m and turned a quarter off the symmetry: the held pose's readings soon pass through its walls.
    # Measured: the right pose held again 0.8 s after the carry (the filter's random particles find it before the
    # pose is called lost), then 0.022 m RMSE
    (30.0, 40.0, 5.0, 15.0),
])
def test_kidnapped_robot_is_detected_found_again_and_held(room, localized, tmp_path, cut, resume, detect_s,
                                                          recover_s):
    """A robot carried while its sensors run on (two stretches of the room log spliced; the wheel odometry continuous):
    the pose it held is abandoned (lost, or replaced by the filter's own recovery) within `detect_s`, and the right
    pose is tracked again within `recover_s` and held to the end of the log."""
    log, plan = room
    r = localized(lambda p: _splice(log, p, cut, resume), plan, truth=tmp_path / "derived.tum")
    _assert_recovered(r, cut, detect_s, recover_s)


@pytest.fixture(scope="module")
def room3(tmp_path_factory):
    loop = [[3.8, 1.4], [3.8, 3.6], [1.2, 3.6], [1.2, 1.4]]
    return _simulate("room", tmp_path_factory.mktemp("loc3"), 80.0, seed=3, waypoints=[[1.2, 1.4]] + loop * 3)


@pytest.mark.slow
def test_kidnapped_robot_off_the_symmetry_is_found_again_on_another_run(room3, localized, tmp_path):
    """The carry off the room's symmetry on another run of the path (seed 3): the particles' heaviest mode jumps
    between the room's look-alike places on one scan's noise, and a track that followed it there whatever its own
    readings said was held at a look-alike place 2-3.5 m off for 38 s after the carry. The track leaves its place for the
    filter's only when its readings pass through the walls. Measured: wrongly tracked for 2.3 s after the carry,
    tracked again for good 2.8 s after it, then 0.018 m RMSE (seeds 1, 2: 0.8 / 2.9 s)."""
    log, plan = room3
    r = localized(lambda p: _splice(log, p, 30.0, 40.0), plan, truth=tmp_path / "derived.tum")
    _assert_recovered(r, 30.0, 5.0, 15.0)


def _assert_recovered(r, cut: float, detect_s: float, recover_s: float) -> None:
    loc = r.loc
    assert loc["converged_s"] is not None and loc["converged_s"] < cut, loc
    tracked = r.status == "tracking"
    before = (r.t >= loc["converged_s"]) & (r.t < cut)
    assert np.all(r.err[before] <= 0.3), r.err[before]
    # no pose more than 0.5 m off is still claimed detect_s after the carry
    wrong = tracked & (r.err > 0.5) & (r.t > cut)
    assert not np.any(wrong & (r.t > cut + detect_s)), (r.t[wrong], loc)
    # from recover_s on, every scan is tracked within 0.3 m of the truth, and the stretch it is held from is accurate
    ok = tracked & (r.err <= 0.3)
    miss = np.flatnonzero(~ok & (r.t > cut))
    back = r.t[miss[-1] + 1] if len(miss) else cut
    assert len(miss) == 0 or miss[-1] + 1 < len(r.t), loc
    assert back <= cut + recover_s, (back, loc)
    held = r.t >= back
    assert np.sqrt(np.mean(r.err[held] ** 2)) <= 0.15, r.err[held]


def _bad(capsys, *args) -> str:
    code = main(["localize", *map(str, args)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.slow  # the simulated room it refuses maps and poses for takes ~8 s to make
def test_refusals_are_one_line(room, tmp_path, capsys):
    log, plan = room
    no_res = tmp_path / "nores.yaml"
    no_res.write_text(f"image: {plan.with_suffix('.png')}\norigin: [0, 0, 0]\n")
    assert "resolution" in _bad(capsys, log, "--map", no_res, "--out", tmp_path / "a")
    err = _bad(capsys, log, "--map", plan, "--out", tmp_path / "b", "--initial-pose", "-3,-3,0")
    assert "--initial-pose" in err and "outside" in err
    assert "x,y,yaw" in _bad(capsys, log, "--map", plan, "--out", tmp_path / "c", "--initial-pose", "1,2")
    assert "--map-scale" in _bad(capsys, log, "--map", plan.with_suffix(".png"), "--out", tmp_path / "d")
    shifted = tmp_path / "shifted.yaml"  # the plan 30 m away: another frame than the log's ground truth
    shifted.write_text(plan.read_text().replace("origin:", "origin: [30.0, 30.0, 0.0]\nold_origin:")
                       .replace("image: ", f"image: {plan.parent}/"))
    assert "frame" in _bad(capsys, log, "--map", shifted, "--out", tmp_path / "f")
    err = _bad(capsys, log, "--map", plan, "--out", tmp_path / "e", "--source", "laser")
    assert "LaserScan" in err
    assert not (tmp_path / "e").exists() or not any((tmp_path / "e").iterdir())


def _perturbed_copy(src, dst, seconds: float, scale: float, drift_deg_per_m: float):
    """The first `seconds` of a log, its wheel odometry re-integrated with a distance scale error and a heading drift
    per metre driven (a worse robot than the one that recorded it)."""
    import dataclasses
    import math

    from kosmap.frontend import se2
    from kosmap.frontend.logs import open_log
    from kosmap.frontend.logs.writer import McapWriter
    from kosmap.frontend.records import Odometry

    prev = cur = None
    with open_log(src) as log, McapWriter(dst) as w:
        t0 = None
        for r in log.read(log.info().types()):
            t = getattr(r, "stamp_ns", 0)
            if t:
                t0 = t if t0 is None else t0
                if t - t0 > seconds * 1e9:
                    break
            if isinstance(r, Odometry):
                p = np.array([r.x, r.y, r.yaw])
                if prev is None:
                    cur = p.copy()
                else:
                    inc = se2.between(prev, p)
                    d = math.hypot(inc[0], inc[1])
                    inc[:2] *= scale
                    inc[2] += math.radians(drift_deg_per_m) * d
                    cur = se2.compose(cur, inc)
                prev = p
                r = dataclasses.replace(r, x=float(cur[0]), y=float(cur[1]), yaw=float(cur[2]))
            w.write(r, r.topic)
    return dst


@pytest.mark.slow
@pytest.mark.data
def test_laser_log_localized_in_its_own_slam_map_with_worse_odometry(tmp_path, capsys):
    from tests.conftest import require_data

    bag = require_data("laser/intel/intel.orig.bag")
    seconds = 200.0
    clean = _perturbed_copy(bag, tmp_path / "intel.mcap", seconds, 1.0, 0.0)
    worse = _perturbed_copy(bag, tmp_path / "intel_worse.mcap", seconds, 1.03, 2.0)  # 3 % and 2°/m
    slam = tmp_path / "slam"
    assert main(["slam", str(clean), "--source", "laser", "--out", str(slam), "--quiet"]) == 0, capsys.readouterr().err
    m = _localize(worse, slam / "map.yaml", tmp_path / "out", capsys, "--source", "laser",
                  "--ground-truth", str(slam / "trajectory.tum"))
    loc, tr = m["localization"], m["truth"]["after_convergence"]
    assert loc["converged_s"] is not None and loc["converged_s"] <= 60.0, loc  # the robot stands still for 24 s
    assert not loc["lost"], loc
    # measured: found after 46 s, then 0.049 m RMSE (median 0.032 m) and 0.35° from the SLAM trajectory; that map
    # is itself off by a median 0.046 m where the robot comes back (slam's own consistency warning), a floor under
    # any agreement with it
    assert tr["position_m"]["rmse"] <= 0.06 and tr["position_m"]["median"] <= 0.035, tr
    assert tr["heading_deg"]["rmse"] <= 1.0, tr


@pytest.mark.slow
def test_office_cross_corridor_found_within_20_s_and_tracked_to_5_cm(tmp_path, localized):
    """The office from its cross corridor, driven north past the labs' doors on its east side: a place the floor's
    half-turn symmetry does not repeat (the doors would be on the west side). The window's search claims it once
    two searches agree; then the refined track, scored against the truth without alignment."""
    log, plan = _simulate("office", tmp_path, 30.0, seed=1, waypoints=[[24, 8], [24, 18], [12, 18]])
    r = localized(lambda p: log, plan)
    loc, tr = r.loc, r.m["truth"]["after_convergence"]
    # measured: found at 8.0 s, then 0.022 m RMSE (median 0.016 m) and 0.19° (seeds 2, 3: 7.0 / 15.0 s, 0.017 /
    # 0.014 m)
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0, loc
    assert tr["position_m"]["rmse"] <= 0.05 and tr["heading_deg"]["rmse"] <= 1.0, tr
    assert not loc["lost"], loc


@pytest.mark.slow
def test_office_cross_corridor_with_wheels_off_by_2_percent_is_tracked_along_it(tmp_path, localized):
    """The cross corridor and the north corridor with wheels that count 2 % more than they roll (and turn 1 % more):
    along a corridor the narrow scan fixes the position only at a door's edges, so the refined track must not be
    pulled along the path towards the odometry's prediction, which carries that error from one scan to the next.
    Measured: found at 8.0 s, then 0.036 m RMSE (seeds 4, 6: 0.048 / 0.039 m; pulled along as hard as across:
    0.056-0.108 m)."""
    log, plan = _simulate("office", tmp_path, 50.0, seed=1, waypoints=[[24, 8], [24, 18], [12, 18]],
                          odom_scale_error=0.02, odom_rot_scale_error=0.01)
    r = localized(lambda p: log, plan)
    loc, tr = r.loc, r.m["truth"]["after_convergence"]
    assert loc["converged_s"] is not None and loc["converged_s"] <= 20.0 and not loc["lost"], loc
    assert tr["position_m"]["rmse"] <= 0.05 and tr["heading_deg"]["rmse"] <= 1.0, tr


@pytest.mark.slow
def test_office_look_alike_corridors_are_not_claimed_before_they_differ(tmp_path, localized):
    """The bundled office path from the south corridor: for its first 30 s the view fits the south corridor 16 m
    further east and the north corridor driven west (a half turn of the floor) as well as the truth; the first
    difference the blueprint has is the lab's door at x = 27 on the inner wall. No pose may be claimed at a wrong
    place meanwhile, and the right one is claimed once that door is in view."""
    log, plan = _simulate("office", tmp_path, 50.0, seed=1)
    r = localized(lambda p: log, plan)
    tracking = r.status == "tracking"
    assert tracking.any(), r.loc
    assert np.max(r.err[tracking]) <= 0.5, r.err[tracking]  # never a look-alike
    assert r.loc["converged_s"] <= 40.0, r.loc  # the door comes into view at ~31 s
    # then held along the corridor, where the particles spread along it (measured: claimed at 38.0 s, 0.018 m RMSE,
    # every scan tracked to the end: a claim is held while the scans fit as well as they did, docs/localize.md; the
    # bench's seeds 4 / 5: 0.053 / 0.006 m)
    after = r.t >= r.loc["converged_s"]
    assert np.all(tracking[after]) and not r.loc["lost"], r.loc
    assert np.sqrt(np.mean(r.err[after] ** 2)) <= 0.05, r.err[after]
    # the run says why it claimed nothing earlier: from 10 s to 25 s every search of the window held the truth and at
    # least one look-alike about equally (measured: three places at 0.25-0.38 each, the scans' log-likelihoods
    # within 0.4 of each other; the plan ahead of the camera is the same cell for cell under a 16 m shift and a half
    # turn), and the claim came from a search that held the truth alone
    search = r.loc["search"]
    gt = r.truth_xy
    mid = [s for s in search["searches"] if 10.0 <= s["t_s"] <= 25.0]
    assert len(mid) >= 4, search
    for s in mid:
        near = [q["p"] for q in s["places"] if np.hypot(q["x"] - gt(s["t_s"])[0], q["y"] - gt(s["t_s"])[1]) <= 0.3]
        assert near and 0.1 <= near[0] <= 0.9 and sum(q["p"] >= 0.1 for q in s["places"]) >= 2, s
    claim = next(s for s in search["searches"] if s["claim"])
    assert claim["places"][0]["p"] >= 0.99 and claim["t_s"] == pytest.approx(r.loc["converged_s"], abs=0.5), claim
    assert search["look_alikes_from_s"] <= 10.0 and search["look_alikes_until_s"] >= 25.0, search
