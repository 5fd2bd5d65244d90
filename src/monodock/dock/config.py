"""The docking config file: the mission's gains, speeds, tolerances, time-outs and retries as one YAML mapping.

The file mirrors ``DockingConfig`` field by field, its nested sections (``planner``, ``track`` with its
``odometry``, ``measurement``) as nested mappings. Every key is optional (a missing one keeps its default) and
every key must be known: a misspelt gain is refused, not ignored. Values are checked for type, finiteness and
a broad range (0 to MAX_NUMBER, counts to MAX_COUNT) here and for their own rules by the dataclasses; any error
is one line naming the file and the key.
``monodock dock-sim --config`` and the docking node's parameters read the same schema.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any, TypeVar

from monodock.core.config import Fields, load_yaml, write_text_atomic, yaml_text
from monodock.dock.controller import DockingConfig
from monodock.errors import ConfigError

__all__ = ["docking_config_from_dict", "docking_config_to_dict", "load_docking_config", "save_docking_config"]

D = TypeVar("D")

# Every number of the config is a non-negative distance (m), speed, rate, time (s), gain, angle (°) or noise:
# none is plausibly beyond these. The dataclasses check the finer rules.
MAX_NUMBER = 10_000.0
MAX_COUNT = 1_000


def _from_fields(cls: type[D], f: Fields) -> D:
    """An instance of the dataclass ``cls`` from a mapping: known keys typed like their defaults, others refused."""
    defaults = cls()
    known = {x.name: x for x in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in f.data if k not in known)
    if unknown:
        raise f.error(unknown[0], f"unknown key (known: {', '.join(known)})")
    values: dict[str, Any] = {}
    for name in known:
        if not f.has(name):
            continue
        default = getattr(defaults, name)
        if dataclasses.is_dataclass(default):
            values[name] = _from_fields(type(default), f.child(name))
        elif isinstance(default, bool):
            value = f.raw(name)
            if not isinstance(value, bool):
                raise f.error(name, f"expected true or false, got {value!r}")
            values[name] = value
        elif isinstance(default, int):
            values[name] = f.integer(name, minimum=0, maximum=MAX_COUNT)
        elif isinstance(default, float):
            values[name] = f.number(name, within=(0.0, MAX_NUMBER))
        elif isinstance(default, str):
            values[name] = f.string(name)
        else:  # pragma: no cover - every DockingConfig field is one of the above
            raise f.error(name, f"cannot be set from a file ({type(default).__name__})")
    try:
        return dataclasses.replace(defaults, **values)  # type: ignore[type-var]
    except ConfigError as exc:
        raise ConfigError(
            f"{f.source}: {_culprit(defaults, values, f)}{str(exc).removeprefix('docking config: ')}"
        ) from None


def _culprit(defaults: Any, values: dict[str, Any], f: Fields) -> str:
    """``key: `` of the one value that the dataclass's own check refuses on its own, else nothing: the checks
    in ``__post_init__`` know the rule but not the file's key."""
    for name, value in values.items():
        try:
            dataclasses.replace(defaults, **{name: value})
        except ConfigError:
            return f"{f.prefix}{name}: "
    return ""


def docking_config_from_dict(data: dict[str, Any], source: str = "docking config") -> DockingConfig:
    """A DockingConfig from a mapping (defaults for the keys it leaves out)."""
    return _from_fields(DockingConfig, Fields(data, source))


def load_docking_config(path: str | os.PathLike[str]) -> DockingConfig:
    """Read a docking config YAML file."""
    return docking_config_from_dict(load_yaml(path, "docking config"), str(path))


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"docking config: cannot write a non-finite value ({value})")
    return value


def docking_config_to_dict(config: DockingConfig) -> dict[str, Any]:
    """Every field of the config as a nested mapping (what a config file may hold)."""
    out = _plain(config)
    assert isinstance(out, dict)
    return out


def save_docking_config(config: DockingConfig, path: str | os.PathLike[str], *, force: bool = False) -> None:
    """Write the config as YAML, atomically (refused over an existing file without ``force``)."""
    text = yaml_text(docking_config_to_dict(config))
    write_text_atomic(Path(path), text, force=force)
