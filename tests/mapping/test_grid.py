"""The log-odds grid builder: a known room from exact poses, free space along beams, no-return beams, mounts,
growing bounds."""

from __future__ import annotations

import numpy as np
import pytest

from kosmap.frontend.records import Scan
from kosmap.mapping.compare import CompareConfig, compare
from kosmap.mapping.grid import GridBuilder, GridConfig, build_grid
from tests.mapping.worlds import room, scan_at, wall_grid

WORLD = room() + np.array([0.012, 0.017, 0.012, 0.017])
POSES = np.array([(x, y, th) for x, y in [(1.5, 1.5), (1.5, 5.5), (5, 2), (8.5, 3), (5, 4.5), (2, 3.5), (6, 6.5)]
                  for th in (0.0, 2.1, 4.2)])


def _value_at(grid, x, y):
    c, r = grid.cell_of(np.array([[x, y]]))[0]
    return int(grid.data[r, c])


def test_known_room_from_exact_poses_matches_true_walls():
    rng = np.random.default_rng(1)
    scans = [scan_at(p, WORLD, noise=0.005, rng=rng) for p in POSES]
    g = build_grid(POSES, scans, config=GridConfig(resolution=0.05))
    m = compare(g, wall_grid(WORLD, 0.05), CompareConfig(align=False)).metrics
    assert m["tolerances"]["0.10"]["f1"] >= 0.95, m["tolerances"]
    assert m["tolerances"]["0.05"]["f1"] >= 0.95
    assert m["distance_a_to_b"]["median"] <= 0.025
    assert m["free"]["a_free_on_b_walls"] < 0.01  # beams do not clear the walls they end on


def test_free_along_beam_occupied_at_end():
    """One beam along +x from (1, 1) to a wall at x = 4.012: cells before it are free, its cell occupied."""
    segs = np.array([[4.012, -2.0, 4.012, 4.0]])
    scan = Scan(0, np.array([3.012], np.float32), 0.0, 0.01, 0.05, 30.0)
    b = GridBuilder(GridConfig(resolution=0.1, p_hit=0.7, p_miss=0.4))
    b.add((1.0, 1.05, 0.0), scan)
    g = b.to_occupancy()
    assert _value_at(g, 4.05, 1.05) == 70  # one hit: p_hit
    for x in np.arange(1.05, 4.0, 0.1):
        assert _value_at(g, x, 1.05) == 40  # one miss per cell per scan: p_miss
    assert g.width == 31 and g.height == 1  # nothing else was seen
    # many scans: free cells clamp at p_min, the wall at p_max
    for _ in range(30):
        b.add((1.0, 1.05, 0.0), scan)
    g = b.to_occupancy()
    assert _value_at(g, 2.05, 1.05) == 12 and _value_at(g, 4.05, 1.05) == 97
    del segs


def test_every_cell_a_beam_crosses_is_cleared():
    """A fan of beams in the room: no cell strictly between the sensor and a beam's end stays unknown or occupied."""
    pose = (5.0, 2.0, 0.3)
    scan = scan_at(pose, WORLD, n=181, fov=np.radians(180))
    g = build_grid([pose], [scan], config=GridConfig(resolution=0.05))
    pts = scan.points()
    c, s = np.cos(0.3), np.sin(0.3)
    ends = pts @ np.array([[c, s], [-s, c]]) + pose[:2]
    for e in ends[::10]:
        d = np.hypot(*(e - pose[:2]))
        t = np.arange(0.0, d - 0.08, 0.02) / d  # stop short of the end cell's neighbourhood
        for p in np.asarray(pose[:2]) + t[:, None] * (e - pose[:2]):
            assert 0 <= _value_at(g, *p) < 50


def test_no_return_clears_up_to_the_configured_distance_only():
    """An open world (REP 117: +inf = nothing within range_max): free to no_return_clear, unknown beyond, no walls."""
    r = np.full(91, np.inf, np.float32)
    r[45] = np.nan  # an erroneous reading is ignored
    scan = Scan(0, r, -np.pi / 4, np.pi / 180, 0.05, 30.0)
    g = build_grid([(0.0, 0.0, 0.0)], [scan], config=GridConfig(resolution=0.05, no_return_clear=2.0))
    assert (g.data == 100).sum() == 0 and (g.data >= 65).sum() == 0
    assert _value_at(g, 1.9, 0.3) == 40
    xy = g.center_of(*np.nonzero(g.data >= 0)[::-1])
    assert np.hypot(*xy.T).max() <= 2.0 + 0.05 * 1.5
    # with no_return_clear 0 such beams leave the map untouched
    g0 = build_grid([(0.0, 0.0, 0.0)], [scan], config=GridConfig(resolution=0.05, no_return_clear=0.0))
    assert (g0.data >= 0).sum() == 0
    # returns beyond max_range clear free space up to it and mark no wall
    hit = Scan(0, np.full(91, 5.0, np.float32), -np.pi / 4, np.pi / 180, 0.05, 30.0)
    g1 = build_grid([(0.0, 0.025, 0.0)], [hit], config=GridConfig(resolution=0.05, max_range=3.0))
    assert (g1.data >= 65).sum() == 0 and _value_at(g1, 2.9, 0.025) == 40


def test_mount_offset_is_applied():
    """A laser mounted 0.3 m ahead of base_link, facing backwards, sees what a base_link laser sees from there."""
    mount = (0.3, 0.0, np.pi)
    base = (4.0, 2.0, 0.5)
    sensor = (4.0 + 0.3 * np.cos(0.5), 2.0 + 0.3 * np.sin(0.5), 0.5 + np.pi)
    scan = scan_at(sensor, WORLD)
    g_mount = build_grid([base], [scan], mount=mount)
    g_direct = build_grid([sensor], [scan])
    assert g_mount.origin == g_direct.origin
    assert np.array_equal(g_mount.data, g_direct.data)


def test_bounds_grow_and_keep_what_was_seen():
    rng = np.random.default_rng(2)
    b = GridBuilder(GridConfig(resolution=0.05))
    b.add(POSES[0], scan_at(POSES[0], WORLD, max_range=3.0, rng=rng))
    shape0 = b.log_odds.shape
    before = b.to_occupancy()
    far = np.array([60.0, -40.0, 0.0])  # a second room far away
    b.add(far, scan_at(far, WORLD + np.array([57.0, -42.0, 57.0, -42.0]), max_range=3.0))
    after = b.to_occupancy()
    assert b.log_odds.shape[0] > shape0[0] and b.log_odds.shape[1] > shape0[1]
    # the first scan's cells are unchanged in the grown map
    rows, cols = np.nonzero(before.data >= 0)
    xy = before.center_of(cols, rows)
    c2 = after.cell_of(xy)
    assert np.array_equal(after.data[c2[:, 1], c2[:, 0]], before.data[rows, cols])
    assert after.origin[0] < 1.0 and after.origin[1] < -40.0


def test_memory_is_the_maps_not_the_logs():
    """Re-observing the same room 200 times does not grow the arrays."""
    b = GridBuilder(GridConfig(resolution=0.05))
    scans = [scan_at(p, WORLD) for p in POSES]
    for p, s in zip(POSES, scans):
        b.add(p, s)
    shape = b.log_odds.shape
    for i in range(200):
        b.add(POSES[i % len(POSES)], scans[i % len(POSES)])
    assert b.log_odds.shape == shape and b.n_scans == 221


def test_bad_probability_config_is_rejected():
    from kosmap.frontend.errors import ConfigError

    with pytest.raises(ConfigError, match="p_hit"):
        GridConfig(p_hit=0.4)
    with pytest.raises(ConfigError, match="resolution"):
        GridConfig(resolution=0.0)


def test_numba_and_numpy_engines_give_the_same_map():
    rng = np.random.default_rng(3)
    poses = POSES + np.column_stack((rng.uniform(-0.2, 0.2, (len(POSES), 2)), np.zeros(len(POSES))))
    scans = [scan_at(p, WORLD, max_range=6.0, noise=0.01, rng=rng) for p in poses]
    maps = []
    for engine in ("numba", "numpy"):
        b = GridBuilder(GridConfig(resolution=0.05, no_return_clear=3.0), engine=engine)
        for p, s in zip(poses, scans):
            b.add(p, s)
        maps.append(b.to_occupancy())
    assert maps[0].origin == maps[1].origin and maps[0].data.shape == maps[1].data.shape
    assert np.mean(maps[0].data == maps[1].data) > 0.9995


def test_grid_set_keeps_one_grid_per_source():
    from dataclasses import replace

    from kosmap.mapping.grid import GridSet

    gs = GridSet(GridConfig(resolution=0.1), mounts={"/kos/level1": (0.3, 0.0, np.pi)})
    base = (4.0, 2.0, 0.5)
    sensor = (4.0 + 0.3 * np.cos(0.5), 2.0 + 0.3 * np.sin(0.5), 0.5 + np.pi)
    laser = replace(scan_at(base, WORLD), topic="/scan")
    kos = replace(scan_at(sensor, WORLD, n=512, fov=np.radians(70.6), max_range=4.5), topic="/kos/level1")
    gs.add(base, laser)
    gs.add(base, kos)
    grids = gs.to_occupancy()
    assert set(grids) == {"/scan", "/kos/level1"}
    direct = build_grid([sensor], [kos], config=GridConfig(resolution=0.1))
    assert np.array_equal(grids["/kos/level1"].data, direct.data)
    assert (grids["/scan"].data >= 0).sum() > 3 * (direct.data >= 0).sum()


def test_compiled_scan_path_equals_beams_then_add_beams():
    """GridBuilder.add's one-call compiled path (_beam_ends) marks exactly the cells that `beams` + `add_beams` mark:
    NaN, ±inf, short and beyond-range returns, a max_range cap, mounts and de-skewed beam-by-beam scans."""
    from dataclasses import replace

    rng = np.random.default_rng(7)
    cfg = GridConfig(resolution=0.05, no_return_clear=3.0, max_range=5.5)
    mount = (0.2, -0.05, 0.1)
    fast, ref = GridBuilder(cfg, mount), GridBuilder(cfg, mount)
    pose = np.array([3.0, 3.0, 0.3])
    for k in range(40):
        pose = pose + np.array([0.04, 0.02, 0.03]) + rng.normal(0.0, 0.01, 3)
        s = scan_at(tuple(pose), WORLD, max_range=6.0, noise=0.01, rng=rng)
        r = s.ranges.copy()
        r[rng.choice(len(r), 12, replace=False)] = rng.choice([np.nan, np.inf, -np.inf, 0.001, 7.0, 5.9], 12)
        s = replace(s, ranges=r, stamp_ns=k * 100_000_000, time_increment=1e-4 if k % 2 else 0.0)
        twist = ((0.4, 0.1), 0.3) if s.time_increment > 0 else None
        fast._last = ref._last = None  # the twist is given below, the same to both
        fast._add_compiled(pose, s, None, twist)
        ref.add_beams(*ref.beams(pose, s, None, twist)[:3])
    assert fast.n_scans == ref.n_scans == 40
    assert (fast.c0, fast.r0) == (ref.c0, ref.r0)
    assert np.array_equal(fast.log_odds, ref.log_odds) and np.array_equal(fast.stamp, ref.stamp)
    assert (fast.stamp > 0).sum() > 5000  # the scans did mark the map


def test_a_map_below_the_scan_rate_deskews_each_scan_from_the_one_before():
    """A grid that takes every other scan (laser_map_rate below the laser's): `previous` hands the builder the skipped
    scan's pose, so each scan is de-skewed with the twist over the 0.1 s before it, not over the 0.2 s since the
    last scan integrated."""
    from dataclasses import replace

    from kosmap.frontend.deskew import sensor_twist

    rng = np.random.default_rng(11)
    cfg = GridConfig(resolution=0.05, no_return_clear=3.0)
    mount = (0.1, 0.0, 0.0)
    poses = [np.array([2.0, 3.0, 0.2]) + k * np.array([0.05, 0.01, 0.08]) for k in range(12)]
    scans = [replace(scan_at(tuple(p), WORLD, max_range=6.0, noise=0.01, rng=rng), stamp_ns=k * 100_000_000,
                     time_increment=2e-4) for k, p in enumerate(poses)]
    got, want, coarse = GridBuilder(cfg, mount), GridBuilder(cfg, mount), GridBuilder(cfg, mount)
    for k in range(0, len(poses), 2):
        if k:
            got.previous(scans[k - 1].stamp_ns, poses[k - 1])
        got.add(poses[k], scans[k])
        coarse.add(poses[k], scans[k])  # without `previous`: the twist over 0.2 s
        want._last = None
        want._add_compiled(poses[k], scans[k], None, sensor_twist(poses[k - 1], poses[k], 0.1, mount) if k else None)
    assert np.array_equal(got.log_odds, want.log_odds)
    assert not np.array_equal(coarse.log_odds, want.log_odds)  # the two twists do differ here
