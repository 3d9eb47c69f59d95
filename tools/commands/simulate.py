"""`kosmap simulate WORLD --out LOG.mcap`: a simulated robot log with exact ground truth (tools/simulate)."""

from __future__ import annotations

import dataclasses
import sys
import tomllib
from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.frontend.errors import ConfigError
from kosmap.tools.progress import seconds_bar


def _sim_config(config: Path | None, sets: list[str] | None, **flags):
    """[simulate] of a TOML file ← --set key=value ← the dedicated flags (the most specific wins)."""
    from kosmap.mapping.config import parse_value
    from kosmap.mapping.limits import check_value
    from kosmap.tools.simulate.config import SimConfig

    values: dict = {}
    if config is not None:
        if config.is_dir():
            raise ConfigError(f"config file {config} is a folder; give a TOML file with [simulate] or drop --config")
        if not config.is_file():
            raise ConfigError(f"config file {config} does not exist; drop --config or give a TOML file with [simulate]")
        try:
            data = tomllib.loads(config.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise ConfigError(f"config file {config} is not valid TOML ({e}); fix that line") from e
        values.update(data.get("simulate", {}))
    for s in sets or []:
        if "=" not in s:
            raise ConfigError(f"--set {s!r} must look like key=value, e.g. depth_rate=15")
        k, v = s.split("=", 1)
        k = k.strip().removeprefix("simulate.")
        values[k] = parse_value(v.strip())
    values.update({k: v for k, v in flags.items() if v is not None})
    known = set(SimConfig.keys())
    for k in values:
        if k not in known:
            raise ConfigError(f"unknown simulator setting '{k}'; known: {', '.join(sorted(known))}")
    fields = {f.name: f for f in dataclasses.fields(SimConfig)}
    for k, v in values.items():  # finite, and within what sensors and robots allow (mapping/limits.py)
        d = fields[k].default
        check_value("simulate", k, fields[k].metadata.get("unit", ""), v, count=isinstance(d, int) and not isinstance(d, bool))
    try:
        return SimConfig(**values)
    except TypeError as e:
        raise ConfigError(f"simulator settings: {e}") from e


def _parse_camera(text: str) -> dict:
    """--camera NS:x,y,z[:roll,pitch,yaw[:FRAME]] → an extra_cameras entry (checked later by SimConfig)."""
    parts = text.split(":")
    usage = (f"--camera {text!r} must look like NS:x,y,z[:roll,pitch,yaw[:FRAME]] (m, deg), e.g. "
             f"/kinect2_left/sd:0,0.1,1.0:0,0,90")
    if not 2 <= len(parts) <= 4 or not parts[0]:
        raise ConfigError(usage)
    entry: dict = {"ns": parts[0]}
    for key, field in zip(("xyz", "rpy_deg"), parts[1:3]):
        try:
            entry[key] = [float(v) for v in field.split(",")]
        except ValueError:
            raise ConfigError(usage) from None
        if len(entry[key]) != 3:
            raise ConfigError(usage)
    if len(parts) == 4:
        entry["frame"] = parts[3]
    return entry


def _write_sidecar(out: Path, world_arg: str, cfg, summary: dict) -> Path:
    """The effective settings and the summary beside the log (`LOG.sim.yaml`), so a run can be repeated."""
    import yaml

    side = out.with_suffix(".sim.yaml")
    doc = {"world": world_arg, "config": dataclasses.asdict(cfg), "summary": summary}
    tmp = side.with_name(side.name + ".partial")
    tmp.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    tmp.replace(side)
    return side


def register(app: typer.Typer) -> None:
    @app.command()
    def simulate(
        world: Annotated[str, typer.Argument(help="A bundled world (office, room) or a world YAML file.")],
        out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Output log (.mcap).")] = None,
        seed: Annotated[Optional[int], typer.Option("--seed", help="Random seed (same seed → identical file).")] = None,
        duration: Annotated[Optional[float], typer.Option("--duration", help="Seconds to simulate (default or 0: the whole path; past its end the robot stands still).")] = None,
        path: Annotated[Optional[Path], typer.Option("--path", help="Waypoints file (YAML or 'x y' lines), or the name of one of the world's paths (office: survey), instead of its default path.")] = None,
        rear_camera: Annotated[bool, typer.Option("--rear-camera", help="Add a rear-facing Kinect.")] = False,
        no_laser: Annotated[bool, typer.Option("--no-laser", help="Leave the laser scanner out.")] = False,
        no_imu: Annotated[bool, typer.Option("--no-imu", help="Leave the IMU (/imu, 200 Hz gyro + accelerometer) out.")] = False,
        surface_ids: Annotated[bool, typer.Option("--surface-ids", help="Also write each depth frame's surface ids.")] = False,
        camera_height: Annotated[Optional[float], typer.Option("--camera-height", help="Front camera height (m).")] = None,
        camera_pitch: Annotated[Optional[float], typer.Option("--camera-pitch", help="Front camera pitch (deg, > 0 looks down).")] = None,
        camera: Annotated[Optional[list[str]], typer.Option("--camera", help="Add a depth camera: NS:x,y,z[:roll,pitch,yaw[:FRAME]] (m, deg; repeatable; frame default from NS).")] = None,
        blueprint: Annotated[Optional[Path], typer.Option("--blueprint", help="Also export the floor plan as map_server PNG + YAML (give the .yaml).")] = None,
        resolution: Annotated[float, typer.Option("--resolution", help="Blueprint cell size (m).")] = 0.05,
        config: Annotated[Optional[Path], typer.Option("--config", "-c", help="TOML file with a 'simulate' section (its keys as for --set).")] = None,
        set_: Annotated[Optional[list[str]], typer.Option("--set", "-s", help="Override a simulator setting: key=value (repeatable).")] = None,
        quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")] = False,
    ) -> None:
        """Simulate a robot (Kinect v2 depth, Hokuyo laser, drifting odometry, a MEMS IMU, true pose) driving through a
        building and write the log as MCAP; optionally export the building's blueprint."""
        from kosmap.tools.simulate import load_path, load_world
        from kosmap.tools.simulate import simulate as run

        if out is None and blueprint is None:
            raise ConfigError("nothing to do: give --out LOG.mcap (the log) and/or --blueprint MAP.yaml (the floor plan)")
        cfg_flags: dict = {"seed": seed, "duration": duration, "surface_ids": True if surface_ids else None,
                           "rear_camera": True if rear_camera else None, "laser": False if no_laser else None,
                           "imu": False if no_imu else None}
        cfg = _sim_config(config, set_, **cfg_flags)
        if camera_height is not None or camera_pitch is not None:
            xyz, rpy = list(cfg.camera_xyz), list(cfg.camera_rpy_deg)
            if camera_height is not None:
                xyz[2] = camera_height
            if camera_pitch is not None:
                rpy[1] = camera_pitch
            cfg = dataclasses.replace(cfg, camera_xyz=xyz, camera_rpy_deg=rpy)
        if camera:  # added to the config's extra_cameras
            cfg = dataclasses.replace(cfg, extra_cameras=cfg.extra_cameras + [_parse_camera(c) for c in camera])
        w = load_world(world)
        if path is not None and not path.exists() and str(path) in w.paths:
            way = w.paths[str(path)]  # one of the world's named paths (office: survey)
        elif path is not None and not path.exists():
            named = f" or one of the world's paths: {', '.join(w.paths)}" if w.paths else ""
            raise ConfigError(f"--path {path}: no such file; give a waypoints file{named}")
        else:
            way = load_path(path) if path is not None else None
        if blueprint is not None:
            from kosmap.mapping.mapio import write_map_server

            if blueprint.suffix not in (".yaml", ".yml"):
                raise ConfigError(f"--blueprint {blueprint} must name the map's .yaml (the .png goes beside it)")
            yp = write_map_server(w.blueprint(resolution), blueprint, ".png")
            if not quiet:
                print(f"blueprint: {yp} (+ {yp.with_suffix('.png').name}), {resolution} m cells")
        if out is None:
            return
        if out.exists() and not quiet:  # (replaced only once the new log is whole: it is written to LOG.partial)
            print(f"note: {out} exists; the new log replaces it when it is done", file=sys.stderr)
        with seconds_bar("simulating", "{task.fields[t]:.1f} s", quiet) as tick:
            summary = run(w, cfg, out, way, progress=tick)
        side = _write_sidecar(out, world, cfg, summary)
        if not quiet:
            print(f"log: {out} ({summary['bytes'] / 1e6:.1f} MB), world {summary['world']}, seed {summary['seed']}")
            print(f"  {summary['duration_s']:.1f} s simulated ({summary['distance_m']:.1f} m driven) in "
                  f"{summary['wall_s']:.1f} s ({summary['cpu_s']:.1f} s CPU): {summary['real_time_factor']:.2f}× real time")
            print("  " + ", ".join(f"{t} {n}" for t, n in summary["messages"].items()))
            print(f"  odometry drift at the end: {summary['odom_drift_m']:.3f} m, {summary['odom_drift_deg']:.2f}°")
            od, im = summary["truth"]["odometry"], summary["truth"]["imu"]
            print(f"  truth: odometry distance scale {od['distance_scale']:.5f}, heading drift "
                  f"{od['heading_drift_deg_per_m']:.3f}°/m" + (f", gyro z bias {im['gyro_bias_initial_dps'][2]:+.4f}°/s "
                                                              f"at the start" if im else ""))
            print(f"  settings and summary: {side}")
