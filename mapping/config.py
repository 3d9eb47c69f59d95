"""One TOML file, a section per stage: load it into the stages' typed configs, apply overrides, write it back."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from kosmap.backend.graph import GraphConfig
from kosmap.frontend.camera import DepthConfig
from kosmap.frontend.errors import ConfigError
from kosmap.frontend.fspf import FspfConfig
from kosmap.frontend.kos import KosConfig
from kosmap.frontend.logs.topics import TopicsConfig
from kosmap.frontend.odometry import OdometryConfig
from kosmap.frontend.params import StageConfig, param
from kosmap.mapping.compare import CompareConfig
from kosmap.mapping.grid import GridConfig
from kosmap.mapping.limits import check_config, check_value
from kosmap.mapping.localize_config import LocalizeConfig


@dataclass
class BuildConfig(StageConfig):
    """[build]: rates, the KOS scan SLAM runs on, its SLAM settings, the extra maps and the MCAP's contents."""

    section = "build"
    depth_rate: float = param(10.0, lo=0.0, doc="process at most this many depth frames per second and camera (0 = every frame): SLAM needs ~10 Hz, the maps take 5 Hz, and every frame of a 30 Hz camera costs 3× the CPU for no better map (docs/bench/pipeline.md)", unit="Hz")
    laser_rate: float = param(10.0, lo=0.0, doc="laser scans used for SLAM, at most this many per second (0 = every scan; a laser averaging no more than 1.2× this keeps every scan); the laser map takes laser_map_rate of them", unit="Hz")
    kos_map_rate: float = param(5.0, lo=0.0, doc="KOS steps integrated into the grids, at most this many per second (0 = every step): at 30 Hz the misses of grazing beams wear thin walls away", unit="Hz")
    laser_map_rate: float = param(5.0, lo=0.0, doc="laser (and fused) scans integrated into the grids, at most this many per second (0 = every scan SLAM used): each de-skewed with the twist from the scan before it, as at the full rate", unit="Hz")
    slam_scan: str = param("obstacle", doc="the KOS scan SLAM runs on: obstacle, or a level's name such as h0_75")
    kos_odometry: dict = param({}, doc="[odometry] values for the KOS scans (a narrow depth scan) over the KOS profile (backend/kosprofile.py)")
    kos_graph: dict = param({}, doc="[graph] values for the KOS scans over the KOS profile (backend/kosprofile.py)")
    kos_on_laser_poses: bool = param(True, doc="also map the KOS obstacle scan at the laser SLAM's poses (KOS without KOS SLAM's error)")
    fused_map: bool = param(True, doc="also map the obstacle scan fused with the laser, at the laser SLAM's poses")
    compare_levels: bool = param(False, doc="compare every KOS level with the blueprint (else the SLAM scan's map only)")
    mcap_planes_period: float = param(1.0, lo=0.0, doc="MCAP: the plane points of one frame every this many seconds (0 = none)", unit="s")
    mcap_plane_points: int = param(4000, lo=1, doc="MCAP: at most this many plane points per cloud (a seeded subsample)")
    in_flight: int = param(0, lo=0, doc="depth frames in flight to the worker processes (0 = 3 per worker)")


@dataclass
class Config:
    """Every stage's settings; each field is one TOML section."""

    topics: TopicsConfig = field(default_factory=TopicsConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    fspf: FspfConfig = field(default_factory=FspfConfig)
    kos: KosConfig = field(default_factory=KosConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    compare: CompareConfig = field(default_factory=CompareConfig)
    build: BuildConfig = field(default_factory=BuildConfig)
    localize: LocalizeConfig = field(default_factory=LocalizeConfig)


SECTIONS: dict[str, type] = {f.name: f.default_factory for f in dataclasses.fields(Config)}  # type: ignore[misc]


# Examples for list-valued keys whose default is empty (the others show their default).
LIST_EXAMPLES: dict[str, list] = {"topics.depth": ["/kinect2/sd/image_depth"],
                                  "topics.info": ["/kinect2/sd/camera_info"]}


def _list_default(dotted: str) -> list | None:
    """The default of a list-valued key ("kos.levels" → [0.3, 0.75, 1.5]); None for any other key."""
    name, _, key = dotted.partition(".")
    cls = SECTIONS.get(name)
    f = next((f for f in dataclasses.fields(cls) if f.name == key), None) if cls is not None else None
    if f is None or f.default_factory is dataclasses.MISSING:  # type: ignore[misc]
        return None
    d = f.default_factory()  # type: ignore[misc]
    return d if isinstance(d, list) else None


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _list_example(dotted: str, default: list, from_set: bool) -> str:
    """How to give a list-valued key: its default (or an example) as --set accepts it, or as a TOML line."""
    items = default or LIST_EXAMPLES.get(dotted, ["…"])
    text = [f"{v:g}" if _is_number(v) else f'"{v}"' for v in items]
    if not from_set:
        name, _, key = dotted.partition(".")
        return f"e.g. {key} = [{', '.join(text)}] under [{name}]"
    bare = ",".join(f"{v:g}" if _is_number(v) else str(v) for v in items)
    return f"e.g. --set '{dotted}=[{','.join(text)}]' or --set {dotted}={bare}"


# Keys a config.toml written by an earlier kosmap may hold: (section, key) → (the value that changes nothing, why the
# key went). That value is dropped; any other is refused with the reason.
RETIRED = {("fspf", "backend"): ("numba", "the compiled kernels are FSPF's only backend (the numpy reference is "
                                          "tools/fspf_numpy.py, for benchmarks)")}


def _without_retired(name: str, values: dict[str, Any]) -> dict[str, Any]:
    kept = {}
    for key, value in values.items():
        if (name, key) not in RETIRED:
            kept[key] = value
        elif value != RETIRED[name, key][0]:
            raise ConfigError(f"config [{name}] {key} = {value!r} is no longer a setting: {RETIRED[name, key][1]}; "
                              f"drop the key")
    return kept


def _section(name: str, values: dict[str, Any], where: str, from_set: frozenset[str] | set[str] = frozenset()):
    cls = SECTIONS.get(name)
    if cls is None:
        raise ConfigError(f"{where}: unknown section [{name}]; sections are {', '.join(f'[{s}]' for s in SECTIONS)}")
    if not isinstance(values, dict):
        raise ConfigError(f"{where}: [{name}] must be a table of keys")
    known = {f.name for f in dataclasses.fields(cls)}
    values = _without_retired(name, values)
    for key in values:
        if key not in known:
            raise ConfigError(f"{where}: unknown key [{name}] {key}; known keys are {', '.join(sorted(known))}")
        default = _list_default(f"{name}.{key}")
        if default is not None and not isinstance(values[key], (list, tuple)):  # say how to write one
            raise ConfigError(f"config [{name}] {key} = {values[key]!r} must be a list, "
                              f"{_list_example(f'{name}.{key}', default, f'{name}.{key}' in from_set)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key, value in values.items():  # finite, and within what sensors and buildings allow (mapping/limits.py)
        d = fields[key].default
        check_value(name, key, fields[key].metadata.get("unit", ""), value,
                    count=isinstance(d, int) and not isinstance(d, bool))
    try:
        return cls(**values)
    except TypeError as e:  # a value of a type the dataclass cannot take
        raise ConfigError(f"{where}: [{name}] {e}") from e


def parse_value(text: str) -> Any:
    """A CLI override value as TOML (numbers, booleans, lists); anything else is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _comma_list(text: str, default: list) -> list | None:
    """A list-valued key's --set value written without TOML's brackets and quotes: "0.3,0.75,1.5", "0.5" (a list
    of one), "ground,ceiling", "[ground,ceiling]"; None when a bare item is not a number where numbers are due
    (so that `kos.levels=abc` is told how to write a list)."""
    bracketed = text.startswith("[") and text.endswith("]")
    items = [t.strip() for t in (text[1:-1] if bracketed else text).split(",")]
    if not all(items):
        return None
    values = [parse_value(t) for t in items]
    if default and _is_number(default[0]):
        return values if bracketed or all(_is_number(v) for v in values) else None
    return [v if isinstance(v, str) else t for v, t in zip(values, items)]  # strings: "5" stays "5"


def load_config(path: str | Path | None = None, overrides: list[str] | dict[str, Any] = ()) -> Config:
    """Defaults ← TOML file ← overrides ("section.key=value" strings or {"section.key": value})."""
    data: dict[str, dict[str, Any]] = {}
    where = "--set"
    if path is not None:
        p = Path(path)
        where = str(p)
        if p.is_dir():
            raise ConfigError(f"config file {p} is a folder; give a TOML file (a section per stage) or drop --config")
        if not p.is_file():
            raise ConfigError(f"config file {p} does not exist; give an existing TOML file (a section per stage) or drop --config")
        try:
            data = tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise ConfigError(f"config file {p} is not valid TOML ({e}); fix that line") from e
        for name in data:
            _section(name, data[name], where)  # reject unknown sections and keys early
    items = overrides.items() if isinstance(overrides, dict) else (parse_override(o) for o in overrides)
    from_set = set()
    for dotted, value in items:
        name, _, key = dotted.partition(".")
        if not key:
            raise ConfigError(f"override '{dotted}' must look like section.key=value, e.g. fspf.n_min=50")
        data.setdefault(name, {})[key] = value
        from_set.add(dotted)
    cfg = Config(**{name: _section(name, values, where, from_set) for name, values in data.items()})
    check_config(cfg)
    return cfg


def parse_override(text: str) -> tuple[str, Any]:
    """"section.key=value" → ("section.key", value); a list-valued key also takes comma-separated items
    (`kos.levels=0.3,0.75,1.5`, as `kosmap scan --levels` does)."""
    key, eq, value = text.partition("=")
    if not eq:
        raise ConfigError(f"override '{text}' must look like section.key=value, e.g. fspf.n_min=50")
    key, value = key.strip(), value.strip()
    parsed = parse_value(value)
    default = _list_default(key)
    if default is not None and not isinstance(parsed, list):
        items = _comma_list(value, default)
        return key, parsed if items is None else items
    return key, parsed


def config_dict(cfg: Config) -> dict[str, dict[str, Any]]:
    return {f.name: dataclasses.asdict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


def write_config(cfg: Config, path: str | Path) -> Path:
    """Write the effective config as TOML (every run writes it beside its outputs)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("# kosmap effective configuration\n" + tomli_w.dumps(config_dict(cfg)))
    return p
