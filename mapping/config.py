"""One TOML file, a section per stage: load it into the stages' typed configs, apply overrides, write it back."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from backend.graph import GraphConfig
from frontend.camera import DepthConfig
from frontend.errors import ConfigError
from frontend.fspf import FspfConfig
from frontend.kos import KosConfig
from frontend.logs.topics import TopicsConfig
from frontend.odometry import OdometryConfig
from mapping.compare import CompareConfig
from mapping.grid import GridConfig
from mapping.pipeline_config import BuildConfig


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


SECTIONS: dict[str, type] = {f.name: f.default_factory for f in dataclasses.fields(Config)}  # type: ignore[misc]


def _section(name: str, values: dict[str, Any], where: str):
    cls = SECTIONS.get(name)
    if cls is None:
        raise ConfigError(f"{where}: unknown section [{name}]; sections are {', '.join(f'[{s}]' for s in SECTIONS)}")
    if not isinstance(values, dict):
        raise ConfigError(f"{where}: [{name}] must be a table of keys")
    known = {f.name for f in dataclasses.fields(cls)}
    for key in values:
        if key not in known:
            raise ConfigError(f"{where}: unknown key [{name}] {key}; known keys are {', '.join(sorted(known))}")
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


def load_config(path: str | Path | None = None, overrides: list[str] | dict[str, Any] = ()) -> Config:
    """Defaults ← TOML file ← overrides ("section.key=value" strings or {"section.key": value})."""
    data: dict[str, dict[str, Any]] = {}
    where = "--set"
    if path is not None:
        p = Path(path)
        where = str(p)
        if not p.is_file():
            raise ConfigError(f"config file {p} does not exist; give an existing TOML file (a section per stage) or drop --config")
        try:
            data = tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise ConfigError(f"config file {p} is not valid TOML ({e}); fix that line") from e
        for name in data:
            _section(name, data[name], where)  # reject unknown sections and keys early
    items = overrides.items() if isinstance(overrides, dict) else (parse_override(o) for o in overrides)
    for dotted, value in items:
        name, _, key = dotted.partition(".")
        if not key:
            raise ConfigError(f"override '{dotted}' must look like section.key=value, e.g. fspf.n_min=50")
        data.setdefault(name, {})[key] = value
    return Config(**{name: _section(name, values, where) for name, values in data.items()})


def parse_override(text: str) -> tuple[str, Any]:
    """"section.key=value" → ("section.key", value)."""
    key, eq, value = text.partition("=")
    if not eq:
        raise ConfigError(f"override '{text}' must look like section.key=value, e.g. fspf.n_min=50")
    return key.strip(), parse_value(value.strip())


def config_dict(cfg: Config) -> dict[str, dict[str, Any]]:
    return {f.name: dataclasses.asdict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


def write_config(cfg: Config, path: str | Path) -> Path:
    """Write the effective config as TOML (every run writes it beside its outputs)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("# kosmap effective configuration\n" + tomli_w.dumps(config_dict(cfg)))
    return p
