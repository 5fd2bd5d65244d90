"""Results as data: one converter between frozen dataclasses and the plain mappings of their JSON files.

The result types (dock-sim's summary, the robustness sweep's) are dataclasses; their files are JSON. Instead of a
hand-written ``to_dict``/``from_dict`` per type, ``to_record`` and ``from_record`` walk the fields by their type
hints: numbers, strings, booleans, None, enums (by value), tuples, lists, mappings (str, int or enum keys; JSON
keys are strings) and nested dataclasses. A ``float`` written as NaN or ±inf is null in the file (``json_text``)
and reads back as NaN; a ``float | None`` reads null as None. A field's file key is its name, or the key it
declares, ``core.settings.setting(0, key="a.b")`` or ``field(metadata=file_key("a.b"))`` (one key model for
settings and records; ``file_key`` is for a field without a default, which mypy cannot tell in a ``setting``): a
dotted key nests it (``retries.total``; a key part cannot hold a dot), an empty key spreads a nested dataclass's
keys into its parent's (a spread mapping, e.g. one entry per method, can be written but not read back: its keys
cannot be told from the parent's). A key absent from a file takes the field's default (files written before the
field existed stay readable); one without a default is an error naming the key.
A type the converter does not know is a TypeError (a programming error), never a user's one-line error.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

from monodock.core.settings import Meta, setting
from monodock.errors import InputError

__all__ = ["file_key", "from_record", "to_record"]

T = TypeVar("T")


def file_key(name: str) -> Mapping[str, Any]:
    """A field's metadata giving its key in the file, as ``setting(key=name)`` declares it:
    ``field(metadata=file_key("retries.total"))``; "" spreads it."""
    field: dataclasses.Field[Any] = setting(key=name)
    return field.metadata


def _key_of(f: dataclasses.Field[Any]) -> str:
    """The field's key in the file: ``setting(key=...)``'s, else its name. Unlike a settings file's, a record's key
    may be dotted (``retries.total``: nested) and "" may spread a mapping (written, never read back)."""
    meta = next((m for m in f.metadata.values() if isinstance(m, Meta)), None)
    return f.name if meta is None or meta.key is None else meta.key


def to_record(value: Any) -> Any:
    """The JSON-able form of a dataclass, enum, mapping, sequence or plain value."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(value):
            item = to_record(getattr(value, f.name))
            name = _key_of(f)
            if name == "":
                out.update(item)
                continue
            *parents, last = name.split(".")
            node = out
            for p in parents:
                node = node.setdefault(p, {})
            node[last] = item
        return out
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, Mapping):
        return {str(k.value if isinstance(k, enum.Enum) else k): to_record(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [to_record(v) for v in value]
    return value


_MISSING = object()


def _lookup(data: Mapping[str, Any], name: str) -> Any:
    node: Any = data
    for part in name.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return _MISSING
        node = node[part]
    return node


_HINTS: dict[type[Any], dict[str, Any]] = {}


def _hints(cls: type[Any]) -> dict[str, Any]:
    """The fields' types, resolved once per class (``from __future__ import annotations`` leaves them text)."""
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def from_record(cls: type[T], data: Any, where: str = "") -> T:
    """An instance of the dataclass ``cls`` from its record (``to_record``'s form).

    Raises:
        InputError: a key missing that has no default, or a value of the wrong type (one line, naming the key).
    """
    return typing.cast(T, _convert(cls, data, where or cls.__name__))


def _dataclass(cls: type[Any], data: Any, where: str) -> Any:
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected a mapping, got {type(data).__name__}")
    hints = _hints(cls)
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        name = _key_of(f)
        if name == "" and typing.get_origin(hints[f.name]) in (dict, Mapping):
            raise TypeError(f"{cls.__name__}.{f.name}: a spread mapping cannot be read back")
        raw = data if name == "" else _lookup(data, name)
        if raw is _MISSING:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise InputError(f"{where}: '{name}' is missing")
            continue
        values[f.name] = _convert(hints[f.name], raw, f"{where}.{name}" if name else where)
    return cls(**values)


def _convert(tp: Any, data: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(tp)
        if data is None and type(None) in options:
            return None
        inner = [o for o in options if o is not type(None)]
        if len(inner) != 1:
            raise TypeError(f"{where}: only X | None unions are supported, not {tp!r}")
        return _convert(inner[0], data, where)
    if dataclasses.is_dataclass(tp):
        return _dataclass(typing.cast(type[Any], tp), data, where)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(data)
        except ValueError:
            raise InputError(f"{where}: unknown value {data!r}") from None
    if origin in (tuple, list, Sequence) or tp in (tuple, list):
        if not isinstance(data, (list, tuple)):
            raise InputError(f"{where}: expected a list, got {type(data).__name__}")
        args = typing.get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(data):
                raise InputError(f"{where}: expected {len(args)} values, got {len(data)}")
            return tuple(_convert(a, d, f"{where}[{i}]") for i, (a, d) in enumerate(zip(args, data, strict=True)))
        item = args[0] if args else Any
        items = [_convert(item, d, f"{where}[{i}]") for i, d in enumerate(data)]
        return items if origin is list else tuple(items)
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        if not isinstance(data, Mapping):
            raise InputError(f"{where}: expected a mapping, got {type(data).__name__}")
        k_tp, v_tp = typing.get_args(tp) or (str, Any)
        return {_mapping_key(k_tp, k, where): _convert(v_tp, v, f"{where}.{k}") for k, v in data.items()}
    return _scalar(tp, data, where)


def _mapping_key(tp: Any, data: Any, where: str) -> Any:
    """A mapping's key from its JSON text: an int key is written as its digits."""
    if tp is int and isinstance(data, str):
        try:
            return int(data)
        except ValueError:
            raise InputError(f"{where}: expected an integer key, got {data!r}") from None
    return _convert(tp, data, where)


def _scalar(tp: Any, data: Any, where: str) -> Any:
    if tp is Any:
        return data
    if tp is bool:
        if not isinstance(data, bool):
            raise InputError(f"{where}: expected true or false, got {data!r}")
        return data
    if tp is int:
        whole = isinstance(data, float) and data.is_integer()  # 2.0: an integer another writer wrote as a float
        if isinstance(data, bool) or not (isinstance(data, int) or whole):
            raise InputError(f"{where}: expected an integer, got {data!r}")
        return int(data)
    if tp is float:
        if data is None:
            return math.nan
        if isinstance(data, bool) or not isinstance(data, (int, float)):
            raise InputError(f"{where}: expected a number, got {data!r}")
        return float(data)
    if tp is str:
        if not isinstance(data, str):
            raise InputError(f"{where}: expected a string, got {data!r}")
        return data
    raise TypeError(f"{where}: the converter cannot read a {tp!r}")
