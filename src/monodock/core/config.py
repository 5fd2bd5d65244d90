"""The one validation layer for the files a user hands in: YAML and JSON read with size, depth and count limits,
then typed field access with plausible ranges, and every error one line naming the file, the key and the range.

Every loader of a user file goes through here: the camera (``core.camera``), the layout, the robot, the docking
config, a bundle's manifest and a dataset's metadata. docs/user-guide.md ("What every file may hold") lists the ranges.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import yaml

from monodock.core.atomic import write_text_atomic
from monodock.errors import ConfigError

__all__ = [
    "MAX_DEPTH",
    "MAX_FILE_BYTES",
    "MAX_VALUES",
    "Fields",
    "check_structure",
    "json_text",
    "load_json",
    "load_yaml",
    "parse_json",
    "parse_yaml",
    "write_text_atomic",
    "yaml_text",
]

# Warnings about the files read (an unknown key): the CLI shows them once the command has not refused its input.
_log = logging.getLogger("monodock.config")

# A calibration or config file is a few kB and a bundle manifest a few hundred; these limits are far above
# anything real and far below what would exhaust memory (a YAML alias bomb, 100,000 nested lists).
MAX_FILE_BYTES = 16 * 1024 * 1024
MAX_VALUES = 1_000_000
MAX_DEPTH = 32


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _read_text(path: str | os.PathLike[str], what: str, max_bytes: int) -> tuple[Path, str]:
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} file not found: {p}")
    size = p.stat().st_size
    if size > max_bytes:
        raise ConfigError(f"{p}: {size} bytes is too large for a {what} file (at most {max_bytes})")
    try:
        return p, p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text ({_first_line(exc)})") from None


def check_structure(data: Any, source: str, *, max_values: int = MAX_VALUES, max_depth: int = MAX_DEPTH) -> None:
    """ConfigError when ``data`` nests deeper than ``max_depth`` or holds more than ``max_values`` values.

    Counts a value every time it is reached, so a YAML alias bomb (anchors that refer to each other, a few
    lines that expand to billions of values when copied or written out) is refused here, not when it is used.
    """
    budget = max_values
    stack: list[tuple[Any, int]] = [(data, 0)]
    while stack:
        value, depth = stack.pop()
        budget -= 1
        if budget < 0:
            raise ConfigError(f"{source}: holds more than {max_values} values (YAML aliases expanding?)")
        if isinstance(value, dict | list):
            if depth >= max_depth:
                raise ConfigError(f"{source}: nested more than {max_depth} levels deep")
            items = value.values() if isinstance(value, dict) else value
            stack.extend((v, depth + 1) for v in items)
            if isinstance(value, dict):
                bad = next((k for k in value if not isinstance(k, str | int | float | bool) and k is not None), None)
                if bad is not None:
                    raise ConfigError(f"{source}: a key is a {type(bad).__name__}, not a name")


# --- YAML: the core schema of YAML 1.2, duplicate keys refused ------------------------------------------------
#
# PyYAML resolves plain scalars by YAML 1.1's rules: a float needs a dot (``6e-4`` and ``1e308`` are strings, and a
# distortion coefficient written so was refused), ``yes``/``no``/``on``/``off`` are booleans, ``012`` is octal and
# ``1:30`` sexagesimal. Every other reader of these files (yaml-cpp in ROS, OpenCV 5, ruamel) follows YAML 1.2,
# whose core schema is below. A mapping that names a key twice keeps PyYAML's last value without a word (a
# doubled marker_size moved yaw by 16 degrees): refused, naming the key and its line.

_CORE_TAGS = {f"tag:yaml.org,2002:{t}" for t in ("bool", "int", "float", "null", "timestamp", "value")}
_CORE_RESOLVERS = (
    ("tag:yaml.org,2002:null", r"^(?:~|null|Null|NULL|)$", ["~", "n", "N", ""]),
    ("tag:yaml.org,2002:bool", r"^(?:true|True|TRUE|false|False|FALSE)$", list("tTfF")),
    ("tag:yaml.org,2002:int", r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$", list("-+0123456789")),
    (
        "tag:yaml.org,2002:float",
        r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$",
        list("-+.0123456789"),
    ),
)


class _DuplicateKey(yaml.MarkedYAMLError):
    """A mapping names a key twice (raised while the YAML is built, told as one line by ``parse_yaml``)."""


def _core_resolvers(base: dict[Any, list[tuple[str, re.Pattern[str]]]]) -> dict[Any, list[tuple[str, Any]]]:
    """PyYAML's implicit resolvers without YAML 1.1's bool/int/float/null/timestamp (merge ``<<`` stays)."""
    return {first: [(tag, rx) for tag, rx in rules if tag not in _CORE_TAGS] for first, rules in base.items()}


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2's core schema for plain scalars and duplicate keys refused."""

    yaml_implicit_resolvers = _core_resolvers(yaml.SafeLoader.yaml_implicit_resolvers)

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, yaml.Node] = {}
        for key_node, _ in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                continue  # a merge (<<) may override; a non-scalar key is refused by check_structure
            key = self.construct_object(key_node)
            try:
                first = seen.setdefault(key, key_node)
            except TypeError:
                continue
            if first is not key_node:
                line, again = first.start_mark.line + 1, key_node.start_mark.line + 1
                problem = f"key '{str(key)[:80]}' appears twice (lines {line} and {again}); each key may appear once"
                raise _DuplicateKey(None, None, problem, key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def _yaml_int(loader: _Loader, node: yaml.ScalarNode) -> int:
    text = str(loader.construct_scalar(node))
    return int(text, 0) if text.startswith(("0o", "0x")) else int(text, 10)  # YAML 1.2: 012 is twelve


def _yaml_float(loader: _Loader, node: yaml.ScalarNode) -> float:
    text = str(loader.construct_scalar(node)).lower()
    if text.endswith(".inf"):
        return -math.inf if text.startswith("-") else math.inf
    return math.nan if text == ".nan" else float(text)


for _tag, _pattern, _first in _CORE_RESOLVERS:
    _Loader.add_implicit_resolver(_tag, re.compile(_pattern), _first)
_Loader.add_constructor("tag:yaml.org,2002:int", _yaml_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _yaml_float)


class _Dumper(yaml.SafeDumper):
    """SafeDumper that quotes a string either YAML 1.1 or 1.2 would read as something else (``6e-4``, ``yes``,
    ``0o17``), so that what monodock writes reads back the same here and in every other reader."""


_Dumper.yaml_implicit_resolvers = {
    first: [*yaml.SafeDumper.yaml_implicit_resolvers.get(first, []), *_Loader.yaml_implicit_resolvers.get(first, [])]
    for first in {*yaml.SafeDumper.yaml_implicit_resolvers, *_Loader.yaml_implicit_resolvers}
}


def yaml_text(data: Any, *, flow: bool | None = False, sort_keys: bool = False, width: int = 80) -> str:
    """YAML text of ``data`` that ``load_yaml`` (YAML 1.2) and YAML 1.1 readers both read back as it was."""
    return yaml.dump(data, Dumper=_Dumper, sort_keys=sort_keys, default_flow_style=flow, width=width)


def parse_yaml(text: str, source: str) -> Any:
    """YAML text as Python values (YAML 1.2 numbers, duplicate keys refused), with the limits of
    ``check_structure``; ConfigError naming ``source``."""
    try:
        data = yaml.load(text, Loader=_Loader)  # a SafeLoader
    except _DuplicateKey as exc:
        raise ConfigError(f"{source}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML ({_first_line(exc)})") from None
    except (ValueError, OverflowError) as exc:  # an integer of more digits than Python converts
        raise ConfigError(f"{source}: a value cannot be read ({_first_line(exc)})") from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deep to read") from None
    check_structure(data, source)
    return data


def load_yaml(path: str | os.PathLike[str], what: str, *, max_bytes: int = MAX_FILE_BYTES) -> dict[str, Any]:
    """Read a YAML mapping, or raise ConfigError naming the file and the problem."""
    return _load_mapping(path, what, max_bytes, parse_yaml, "a YAML mapping")


def _load_mapping(
    path: str | os.PathLike[str], what: str, max_bytes: int, parse: Callable[[str, str], Any], expected: str
) -> dict[str, Any]:
    """``load_yaml`` and ``load_json``: the file's text read with ``parse``, which must give ``expected`` (a
    mapping) at the top level."""
    p, text = _read_text(path, what, max_bytes)
    data = parse(text, str(p))
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected {expected} at the top level")
    return data


def parse_json(text: str | bytes, source: str) -> Any:
    """JSON text as Python values, with the limits of ``check_structure``; ConfigError naming ``source``."""
    try:
        data = json.loads(text, parse_constant=_refuse_constant, object_pairs_hook=_json_object)
    except _DuplicateJsonKeyError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{source}: not valid JSON ({_first_line(exc)})") from None
    except (ValueError, OverflowError) as exc:  # NaN/Infinity, or an integer of more digits than Python converts
        raise ConfigError(f"{source}: a value cannot be read ({_first_line(exc)})") from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deep to read") from None
    check_structure(data, source)
    return data


def json_text(data: Any, *, indent: int | None = 2) -> str:
    """Strict JSON text of ``data``: NaN and ±inf become null (JSON has no token for them, and Python's NaN makes a
    file that other readers refuse); anything else JSON cannot hold becomes its text."""

    def finite(value: Any) -> Any:
        if isinstance(value, float):
            return value if math.isfinite(value) else None
        if isinstance(value, dict):
            return {k: finite(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [finite(v) for v in value]
        return value

    return json.dumps(finite(data), indent=indent, default=str, allow_nan=False)


class _DuplicateJsonKeyError(ValueError):
    """A JSON object names a key twice (json keeps the last without a word)."""


def _json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateJsonKeyError(f"key '{key[:80]}' appears twice in one object; each key may appear once")
        out[key] = value
    return out


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


def load_json(path: str | os.PathLike[str], what: str, *, max_bytes: int = MAX_FILE_BYTES) -> dict[str, Any]:
    """Read a JSON object, or raise ConfigError naming the file and the problem."""
    return _load_mapping(path, what, max_bytes, parse_json, "a JSON object")


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

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        positive: bool = False,
        within: tuple[float, float] | None = None,
        unit: str = "",
    ) -> float:
        """A finite real number (ints accepted), inside ``within`` (inclusive) when given; ``default`` makes the
        key optional."""
        if key not in self.data and default is not None:
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"expected a number, got {_show(value)}")
        try:
            out = float(value)
        except OverflowError:
            out = math.inf
        if not math.isfinite(out):
            raise self.error(key, f"expected a finite number, got {_show(value)}")
        if positive and out <= 0:
            raise self.error(key, f"must be positive, got {_show(value)}")
        if within is not None and not within[0] <= out <= within[1]:
            raise self.error(key, f"must be within {_span(within, unit)}, got {_show(value)}")
        return out

    def integer(
        self, key: str, default: int | None = None, *, minimum: int | None = None, maximum: int | None = None
    ) -> int:
        """An integer from ``minimum`` to ``maximum``; ``default`` makes the key optional."""
        if key not in self.data and default is not None:
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"expected an integer, got {_show(value)}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be at least {minimum}, got {_show(value)}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be at most {maximum}, got {_show(value)}")
        return value

    def warn_unknown(self, known: Iterable[str]) -> None:
        """Log a warning for every key of this mapping that is not in ``known``: ignored, never copied on."""
        names = tuple(known)
        for key in self.data:
            if key not in names:
                _log.warning(
                    "%s: unknown key '%s' is ignored (known: %s)",
                    self.source,
                    self._name(str(key))[:80],
                    ", ".join(names),
                )

    def string(self, key: str, default: str | None = None) -> str:
        """A string; ``default`` makes the key optional."""
        if key not in self.data and default is not None:
            return default
        value = self.raw(key)
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {_show(value)}")
        return value

    def numbers(self, key: str, count: int | tuple[int, ...]) -> list[float]:
        """A list of finite numbers whose length is ``count`` (or one of several counts)."""
        value = self.raw(key)
        counts = (count,) if isinstance(count, int) else count
        if not isinstance(value, list) or len(value) not in counts:
            want = " or ".join(str(c) for c in counts)
            raise self.error(key, f"expected a list of {want} numbers, got {_show(value)}")
        out = []
        for item in value:
            number = float(item) if isinstance(item, float) else math.inf
            if isinstance(item, int) and not isinstance(item, bool) and abs(item) < 10**300:
                number = float(item)
            if not math.isfinite(number):
                raise self.error(key, f"expected finite numbers, got {_show(item)}")
            out.append(number)
        return out

    def child(self, key: str) -> Fields:
        """The nested mapping under a required key."""
        return Fields(self.raw(key), self.source, f"{self._name(key)}.")


def _show(value: Any, limit: int = 40) -> str:
    """A value as an error message quotes it: its repr, cut short (a 5,000-digit number, a long list)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        return f"an integer of about {int(value.bit_length() * 0.30103) + 1} digits"
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _span(within: tuple[float, float], unit: str) -> str:
    lo, hi = within
    unit = f" {unit}" if unit else ""
    return f"{lo:g} to {hi:g}{unit}"
