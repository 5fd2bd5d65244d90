"""The one loader for monodock's YAML files: typed field access with messages that name the field."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import yaml

from monodock.core.atomic import write_text_atomic
from monodock.errors import ConfigError

__all__ = ["Fields", "load_yaml", "write_text_atomic"]


def load_yaml(path: str | os.PathLike[str], what: str) -> dict[str, Any]:
    """Read a YAML mapping, or raise ConfigError naming the file and the problem."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} file not found: {p}")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{p}: not valid YAML ({first})") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a YAML mapping at the top level")
    return data


class Fields:
    """Typed access to one mapping of a config file; errors name ``source: path.to.field``."""

    def __init__(self, data: Any, source: str, prefix: str = "") -> None:
        if not isinstance(data, dict):
            where = prefix.rstrip(".") or "top level"
            raise ConfigError(f"{source}: {where}: expected a mapping, got {type(data).__name__}")
        self.data: dict[str, Any] = data
        self.source = source
        self.prefix = prefix

    def _name(self, key: str) -> str:
        return f"{self.prefix}{key}"

    def error(self, key: str, message: str) -> ConfigError:
        """A ConfigError about one field."""
        return ConfigError(f"{self.source}: {self._name(key)}: {message}")

    def has(self, key: str) -> bool:
        """Whether the mapping holds the key."""
        return key in self.data

    def raw(self, key: str) -> Any:
        """The value of a required key, untyped."""
        if key not in self.data:
            raise ConfigError(f"{self.source}: missing field '{self._name(key)}'")
        return self.data[key]

    def number(self, key: str, default: float | None = None, *, positive: bool = False) -> float:
        """A finite real number (ints accepted); ``default`` makes the key optional."""
        if key not in self.data and default is not None:
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"expected a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise self.error(key, f"expected a finite number, got {value!r}")
        if positive and out <= 0:
            raise self.error(key, f"must be positive, got {value!r}")
        return out

    def integer(self, key: str, default: int | None = None, *, minimum: int | None = None) -> int:
        """An integer; ``default`` makes the key optional."""
        if key not in self.data and default is not None:
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be at least {minimum}, got {value}")
        return value

    def string(self, key: str, default: str | None = None) -> str:
        """A string; ``default`` makes the key optional."""
        if key not in self.data and default is not None:
            return default
        value = self.raw(key)
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {value!r}")
        return value

    def numbers(self, key: str, count: int | tuple[int, ...]) -> list[float]:
        """A list of finite numbers whose length is ``count`` (or one of several counts)."""
        value = self.raw(key)
        counts = (count,) if isinstance(count, int) else count
        if not isinstance(value, list) or len(value) not in counts:
            want = " or ".join(str(c) for c in counts)
            raise self.error(key, f"expected a list of {want} numbers, got {value!r}")
        out = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int | float) or not math.isfinite(item):
                raise self.error(key, f"expected finite numbers, got {item!r}")
            out.append(float(item))
        return out

    def child(self, key: str) -> Fields:
        """The nested mapping under a required key."""
        return Fields(self.raw(key), self.source, f"{self._name(key)}.")
