"""Absurd parameters and unusable options are refused before any work, in one line naming the largest (or
smallest) sane value; usage errors are one line; what a run skipped is said even under --quiet."""

from __future__ import annotations

import pytest

from kosmap.frontend.errors import ConfigError
from kosmap.mapping.config import load_config
from kosmap.tools.cli import main
from tests.frontend.synthetic_log import room_laser_log


@pytest.fixture(scope="module")
def laser_log(tmp_path_factory):
    """2 s of the simulated room, its laser, odometry and gyro only."""
    return room_laser_log(tmp_path_factory.mktemp("params"), seed=4, duration=2.0)


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("kosmap: error: ") and err.count("\n") == 1 and len(err) < 400, err
    return err


LEVELS_1500 = ",".join(f"{0.1 + 0.001 * i:.3f}" for i in range(1500))


@pytest.mark.parametrize("argv, words", [
    (["build", "LOG", "--set", "depth.max_depth=1e308"], "at most 50 m"),
    (["build", "LOG", "--set", "grid.resolution=1e-6"], "the smallest cell is 0.001 m"),
    (["build", "LOG", "--set", "fspf.delta_m=inf"], "is not a finite number"),
    (["build", "LOG", "--set", "kos.levels=[0.3,nan]"], "is not a finite number"),
    (["build", "LOG", "--set", "kos.angle_increment_deg=1e-9"], "at least 0.01°"),
    (["build", "LOG", "--set", "odometry.resolution=0.001"], "give resolution ≥ 0.003 m"),
    (["build", "LOG", "--set", "localize.max_particles=1e12"], "at most 1e+07"),
    (["build", "LOG", "--set", "build.depth_rate=1e9"], "at most 1000 Hz"),
    (["build", "LOG", "--set", "graph.optimize_every=1e300"], "at most 1e+09"),  # any count
    (["build", "LOG", "-c", "DIR"], "is a folder; give a TOML file"),
    (["scan", "LOG", "--levels", LEVELS_1500], "levels has 1500 heights: at most 64"),
    (["simulate", "room", "--out", "OUT/s.mcap", "--duration", "1e-9"], "at least 0.0667 s"),
    (["simulate", "room", "--out", "OUT/s.mcap", "--seed", "abc"], "Invalid value for '--seed'"),
    (["simulate", "room", "--out", "OUT/s.mcap", "--set", "laser_beams=1e9"], "at most 10000"),
    (["simulate", "room", "--out", "OUT/s.mcap", "--set", "speed_max=inf"], "is not a finite number"),
    (["simulate", "room", "--out", "OUT/s.mcap", "-c", "DIR"], "is a folder; give a TOML file"),
    (["build", "LOG", "-j", "100000"], "give at most"),  # processes beyond 4 × the cores only cost memory
    (["compare", "BP", "--blueprint", "BP", "--blueprint-scale", "1e-12", "--out", "OUT"], "is not a floor plan's"),
    (["build"], "Missing argument 'log'; see `kosmap build --help`"),
    (["nosuch"], "No such command 'nosuch'; see `kosmap --help`"),
])
def test_an_absurd_parameter_is_one_line_before_any_work(laser_log, tmp_path, capsys, argv, words):
    out = tmp_path / "out"
    if "BP" in argv:  # a plain image (that a map_server YAML also names)
        from kosmap.mapping.grid import OccupancyGrid
        from kosmap.mapping.mapio import write_map_server

        import numpy as np

        data = np.zeros((40, 40), np.int8)
        data[5, 5:35] = 100
        bp = write_map_server(OccupancyGrid(data, 0.05), tmp_path.parent / f"{tmp_path.name}_bp.yaml", ".png")
        argv = [str(bp) if a == "BP" and i == 1 else str(bp.with_suffix(".png")) if a == "BP" else a
                for i, a in enumerate(argv)]
    argv = [str(laser_log) if a == "LOG" else str(tmp_path) if a == "DIR" else a.replace("OUT", str(out))
            for a in argv]
    if argv[0] in ("build", "scan") and len(argv) > 1:
        argv += ["--out", str(out)]
    assert main(argv) == 2
    assert words in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []  # no folder, no log, no partial file


def test_every_configured_default_is_within_its_limit_and_the_limits_bite_at_their_edge():
    """The defaults pass; a value just past a limit is refused, one at it is taken (the limits are not off by
    a unit)."""
    load_config(None, [])
    assert load_config(None, ["depth.max_depth=50"]).depth.max_depth == 50
    with pytest.raises(ConfigError, match="at most 50 m"):
        load_config(None, ["depth.max_depth=50.001"])
    assert load_config(None, ["grid.resolution=0.001"]).grid.resolution == 0.001
    assert load_config(None, ["kos.angle_increment_deg=0"]).kos.angle_increment_deg == 0  # 0: a bin per column
    assert load_config(None, ["odometry.resolution=0.003"]).odometry.resolution == 0.003  # 1e8 cells in 30 m
    with pytest.raises(ConfigError, match="odometry.*0.0029"):
        load_config(None, ["odometry.resolution=0.0029"])


def test_a_map_larger_than_the_cell_limit_is_refused_with_the_resolution_that_fits():
    """1 mm cells over a 20 km odometry jump: the grid names the resolution at which that map would fit instead
    of allocating terabytes; below the limit it grows as before."""
    import numpy as np

    from kosmap.frontend.records import Scan
    from kosmap.mapping.grid import MAX_CELLS, GridBuilder, GridConfig, GridTooLarge

    scan = Scan(0, np.full(90, 2.0, np.float32), -0.8, 0.02, 0.1, 10.0, "laser", "/scan")
    for engine in ("numba", "numpy"):
        g = GridBuilder(GridConfig(resolution=0.001), engine=engine)
        g.add((0.0, 0.0, 0.0), scan)
        assert g.log_odds.size < MAX_CELLS
        with pytest.raises(GridTooLarge, match=r"span 20002 m × 3 m: .* give --set grid.resolution=0.018 or more"):
            g.add((20000.0, 0.0, 0.0), scan)
        grid = g.to_occupancy()  # the grid is as it was before the refused scan
        assert grid.width * grid.resolution == pytest.approx(2.0, abs=0.01)
        assert (grid.data >= 65).sum() >= 85  # its 90 returns


@pytest.mark.slow
def test_truncation_is_warned_under_quiet_in_slam_and_build(laser_log, tmp_path, capsys):
    cut = tmp_path / "cut.mcap"
    data = laser_log.with_name("room.mcap").read_bytes()  # (with its depth frames: many chunks)
    cut.write_bytes(data[: len(data) * 2 // 3])
    for argv in (["slam", str(cut), "--out", str(tmp_path / "s"), "-q"],
                 ["build", str(cut), "--out", str(tmp_path / "b"), "-q", "-j", "0", "--set", "build.depth_rate=2"]):
        assert main(argv) == 0, argv
        cap = capsys.readouterr()
        assert cap.out == "" and "warning: cut.mcap is truncated: read" in cap.err, cap.err
