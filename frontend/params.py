"""Typed, range-checked configuration fields shared by every stage's config dataclass.

A stage declares `section = "fspf"` and its fields with `param(default, lo=…, hi=…)`; `check()`
rejects out-of-range values with a message naming `[section] key`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from kosmap.frontend.errors import ConfigError


def param(default: Any, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
          choices: tuple | None = None, doc: str = "", unit: str = "") -> Any:
    """A config field with its bounds (lo ≤ v ≤ hi, or lo < v when lo_open) and a one-line doc."""
    meta = {"lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices, "doc": doc, "unit": unit}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


class StageConfig:
    """Mixin for stage configs: validates every field after construction."""

    section: ClassVar[str] = ""

    def __post_init__(self) -> None:
        check(self)


def _bad(section: str, name: str, value: Any, why: str) -> ConfigError:
    return ConfigError(f"config [{section}] {name} = {value!r} {why}")


def _check_number(section: str, f: dataclasses.Field, v: Any) -> None:
    m = f.metadata
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _bad(section, f.name, v, "is not a number")
    if v != v:  # NaN
        raise _bad(section, f.name, v, "is not a number")
    lo, hi = m.get("lo"), m.get("hi")
    if lo is not None and (v <= lo if m.get("lo_open") else v < lo):
        raise _bad(section, f.name, v, f"is out of range: it must be {'>' if m.get('lo_open') else '≥'} {lo}")
    if hi is not None and v > hi:
        raise _bad(section, f.name, v, f"is out of range: it must be ≤ {hi}")


def check(cfg: Any) -> None:
    """Raise ConfigError for the first field whose value has the wrong type or lies out of range."""
    section = getattr(cfg, "section", type(cfg).__name__)
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        choices = f.metadata.get("choices")
        if choices is not None:
            items = v if isinstance(v, (list, tuple)) else [v]
            for item in items:
                if item not in choices:
                    raise _bad(section, f.name, v, f"is not one of {', '.join(map(str, choices))}")
        if isinstance(default, bool):
            if not isinstance(v, bool):
                raise _bad(section, f.name, v, "must be true or false")
        elif isinstance(default, (int, float)):
            if isinstance(default, int) and isinstance(v, float) and not v.is_integer():
                raise _bad(section, f.name, v, "must be a whole number")
            _check_number(section, f, v)
            if isinstance(default, int) and not isinstance(v, bool):
                object.__setattr__(cfg, f.name, int(v))
            elif isinstance(default, float):
                object.__setattr__(cfg, f.name, float(v))
        elif isinstance(default, str):
            if not isinstance(v, str):
                raise _bad(section, f.name, v, "must be a string")
        elif isinstance(default, list):
            if not isinstance(v, (list, tuple)):
                raise _bad(section, f.name, v, "must be a list")
            if default and isinstance(default[0], (int, float)) and not isinstance(default[0], bool):
                for item in v:
                    _check_number(section, f, item)
                object.__setattr__(cfg, f.name, [float(x) if isinstance(default[0], float) else x for x in v])
