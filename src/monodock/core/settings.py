"""Settings declared once: a dataclass field's metadata says everything the readers, writers and interfaces need.

A settings class is a dataclass whose fields are ``setting(...)``s (a value) and ``section(...)``s (a nested
settings dataclass). From that one declaration come:

- the file reader ``from_mapping`` (on ``core.config.Fields``, so every error is its one line naming the file
  and the key) and the writer ``to_mapping`` (declaration order, defaults left out where ``omit_default``);
- the flat names (``settings_of``: ``cruise_speed``, ``planner.standoff``), which are a ROS node's parameter names
  and a file's dotted keys, with ``flat``/``nested`` between the two forms and ``replace`` by flat name;
- what ``ros.parameters`` derives the ROS 2 parameter declarations from and ``cli.options`` the command-line
  flags from (both read ``Setting.meta``; nothing here imports rclpy or argparse).

A class's ``Policy`` (a ``SETTINGS`` class variable, inherited by its sections) says how its file is read: unknown
keys warned about or refused, the broad range of numbers without their own, whether a field's rules (positive, not
negative) run when the file is read or whenever the dataclass is built, and how a dataclass's own error is told.

A field that is a plain dataclass field (no ``setting``) is a setting with no metadata; a field whose type is a
dataclass is a section keyed by its name. A section with ``key=""`` spreads its keys into its parent's mapping:
its fields are named as if they were the parent's (``DockingConfig``'s sections keep its flat keys).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Iterator, Mapping
from dataclasses import MISSING, dataclass
from typing import Any, Literal, Protocol, TypeVar

from monodock.core.config import Fields
from monodock.errors import ConfigError, MonodockError

__all__ = [
    "Codec",
    "Meta",
    "Policy",
    "Setting",
    "check_fields",
    "flag_of",
    "flat",
    "from_fields",
    "from_flat",
    "from_mapping",
    "inherited",
    "nested",
    "policy_of",
    "replace",
    "section",
    "setting",
    "settings_of",
    "to_argv",
    "to_mapping",
]

T = TypeVar("T")

_META = "monodock.setting"


class Codec(Protocol):
    """How a value of a structural kind (markers keyed by role, a list that is two tuples) is read and written;
    its errors are ``fields.error(key, ...)``, one line naming the file and the key."""

    def read(self, fields: Fields, key: str) -> Any:
        """The field's value from ``fields[key]`` (present in the mapping)."""

    def write(self, value: Any) -> Any:
        """The value as the file holds it (plain YAML/JSON values)."""


@dataclass(frozen=True)
class Meta:
    """What one field declares beyond its type and default.

    Attributes:
        key: its key in the file and its ROS name's last part; None: the field's name; "" (a section only): its
            keys spread into the parent's.
        unit: "m", "s", "rad", "deg", "m/s"...: docs, ROS descriptions, and range errors (``Policy.units_in_errors``).
        range: the values allowed, both ends included.
        positive: a number must be above 0.
        non_negative: a number must not be below 0.
        signed: the Policy's broad range for numbers is mirrored below 0 (an offset, not a distance).
        choices: the strings allowed (ROS checks and CLI choices; a file's choices are the dataclass's own rule).
        help: what it is for, in words (the ROS descriptor's description, the flag's help, the docs row).
        live: it may change while a node runs; None: the Policy's.
        required: the file must hold it although the dataclass has a default.
        omit_default: written only when it differs from the default.
        flag: the command-line flag; None: ``--field-name``; "": none; a name without dashes: a positional.
        cli_help: the flag's help when it must differ from ``help`` ("": none).
        parse: a flag's word as the value (its error's text is the usage error), where the type's own will not do.
        show: the value as a flag's word (``to_argv``), where ``str`` (``repr`` for a real) will not do.
        ros: declared as a ROS parameter (False: a flag alone).
        check: a rule of its own, a message for a bad value or None (told as ``source: key: message``).
        codec: reads and writes a value of a structural kind.
        aliases: other keys read as this one.
        section: the field is a nested settings dataclass.
    """

    key: str | None = None
    unit: str = ""
    range: tuple[float, float] | None = None
    positive: bool = False
    non_negative: bool = False
    signed: bool = False
    choices: tuple[str, ...] = ()
    help: str = ""
    live: bool | None = None
    required: bool = False
    omit_default: bool = False
    flag: str | None = None
    cli_help: str | None = None
    parse: Callable[[str], Any] | None = None
    show: Callable[[Any], str] | None = None
    ros: bool = True
    check: Callable[[Any], str | None] | None = None
    codec: Codec | None = None
    aliases: tuple[str, ...] = ()
    section: bool = False


def setting(default: Any = MISSING, *, default_factory: Any = MISSING, **meta: Any) -> Any:
    """A settings field: ``x: float = setting(0.2, unit="m/s", positive=True, help="...")`` (``Meta``'s keywords)."""
    return dataclasses.field(default=default, default_factory=default_factory, metadata={_META: Meta(**meta)})


def inherited(base: type[Any], name: str, **changes: Any) -> Any:
    """``base``'s setting ``name`` again in a subclass, with ``changes`` to its declaration (``help="..."``): every
    other rule of it (range, flag, choices, ...) stays the base's, so a rule added there reaches the subclass too."""
    field = next((f for f in dataclasses.fields(base) if f.name == name), None)
    if field is None or not isinstance(field.metadata.get(_META), Meta):
        raise TypeError(f"{base.__name__} has no setting {name!r}")
    meta = dataclasses.replace(_meta(field), **changes)
    return dataclasses.field(default=field.default, default_factory=field.default_factory, metadata={_META: meta})


def section(cls: type[Any], *, key: str | None = None, **meta: Any) -> Any:
    """A nested settings dataclass as a field (its defaults); ``key=""`` spreads its keys into the parent's."""
    return dataclasses.field(default_factory=cls, metadata={_META: Meta(key=key, section=True, **meta)})


@dataclass(frozen=True)
class Policy:
    """How a settings class's file is read and written (its ``SETTINGS`` class variable; its sections use it too).

    Attributes:
        what: the settings' name in messages ("docking config", "robot").
        unknown: "warn": an unknown key is logged and ignored; "refuse": it is an error naming the known keys.
        ignore: keys read past without a word.
        checks: "read": ``positive``/``non_negative`` are checked when a file is read; "construct": by
            ``check_fields``, which the dataclass's ``__post_init__`` calls (code is held to them too).
        culprit: an error of the dataclass's own is told with the file key of the one value that causes it
            (``source: key: text``), the text without its "what: " prefix.
        numbers: the range of a real without its own (mirrored below 0 for ``signed``); None: any finite value.
        counts: the range of an integer without its own.
        units_in_errors: a range error names the unit ("must be within 0 to 5 m").
        live: whether a field may change while a node runs, where the field does not say.
        error: the error type of the reader (ConfigError's text, re-raised as this).
    """

    what: str = "settings"
    unknown: Literal["refuse", "warn"] = "warn"
    ignore: tuple[str, ...] = ()
    checks: Literal["read", "construct"] = "read"
    culprit: bool = False
    numbers: tuple[float, float] | None = None
    counts: tuple[int, int] | None = None
    units_in_errors: bool = True
    live: bool = False
    error: type[MonodockError] = ConfigError


@dataclass(frozen=True)
class Setting:
    """One value of a settings class as every derivation sees it.

    Attributes:
        path: the attribute path from the top class (``("approach", "k_lateral")``).
        key: the flat name: the file's keys joined by dots (a ROS parameter's name: ``planner.standoff``).
        type: the value's type hint.
        default: the value the top class's defaults hold.
        meta: what the field declares.
        live: whether it may change while a node runs (the field's, else the Policy's).
    """

    path: tuple[str, ...]
    key: str
    type: Any
    default: Any
    meta: Meta
    live: bool


def policy_of(cls: type[Any]) -> Policy:
    """The class's ``SETTINGS`` Policy (the default Policy when it declares none)."""
    policy = getattr(cls, "SETTINGS", None)
    return policy if isinstance(policy, Policy) else Policy()


def _meta(f: dataclasses.Field[Any]) -> Meta:
    meta = f.metadata.get(_META)
    return meta if isinstance(meta, Meta) else Meta()


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def _hints(cls: type[Any]) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except NameError:  # a class defined where its annotations' names cannot be resolved: the fields' own types
        return {f.name: f.type for f in dataclasses.fields(cls)}


def _optional(hint: Any) -> Any:
    """``X`` of ``X | None`` (else None)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(hint)) == 2:
            return args[0]
    return None


def _is_section(hint: Any, meta: Meta, default: Any) -> bool:
    return (
        meta.section
        or (isinstance(hint, type) and dataclasses.is_dataclass(hint) and meta.codec is None)
        or (meta.codec is None and dataclasses.is_dataclass(default) and not isinstance(default, type))
    )


@dataclass(frozen=True)
class _Field:
    name: str
    key: str  # "" spreads (a section)
    hint: Any
    meta: Meta
    default: Any
    section: type[Any] | None


# Walked once per class (type hints resolved once): a file is read per mission and per live change.
_FIELDS: dict[type[Any], tuple[_Field, ...]] = {}
_SETTINGS: dict[type[Any], tuple[Setting, ...]] = {}


def _fields(cls: type[Any]) -> tuple[_Field, ...]:
    cached = _FIELDS.get(cls)
    if cached is None:
        cached = _FIELDS[cls] = _walk_fields(cls)
    return cached


def _walk_fields(cls: type[Any]) -> tuple[_Field, ...]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = _hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        meta = _meta(f)
        hint = hints.get(f.name, f.type)
        default = _default(f)
        sub = None
        if _is_section(hint, meta, default):
            sub = hint if isinstance(hint, type) else type(default)
        key = f.name if meta.key is None else meta.key
        if key == "" and sub is None:
            raise TypeError(f"{cls.__name__}.{f.name}: only a section may spread its keys (key='')")
        if "." in key:
            raise TypeError(f"{cls.__name__}.{f.name}: a key cannot hold a dot ({key!r})")
        out.append(_Field(f.name, key, hint, meta, default, sub))
    return tuple(out)


def _settings(cls: type[Any]) -> tuple[Setting, ...]:
    policy = policy_of(cls)
    out: list[Setting] = []

    def walk(c: type[Any], defaults: Any, path: tuple[str, ...], prefix: str) -> None:
        for f in _fields(c):
            value = getattr(defaults, f.name) if defaults is not None else f.default
            if f.section is not None:  # a section with no default: its fields' own defaults
                below = None if value is MISSING else value
                walk(f.section, below, (*path, f.name), f"{prefix}{f.key}." if f.key else prefix)
                continue
            live = policy.live if f.meta.live is None else f.meta.live
            out.append(Setting((*path, f.name), f"{prefix}{f.key}", f.hint, value, f.meta, live))

    try:
        defaults: Any = cls()
    except TypeError:  # a field without a default: the fields' own defaults (MISSING where none)
        defaults = None
    walk(cls, defaults, (), "")
    keys = [s.key for s in out]
    doubled = sorted({k for k in keys if keys.count(k) > 1})
    if doubled:
        raise TypeError(f"{cls.__name__}: the flat name {doubled[0]!r} is declared twice")
    return tuple(out)


def settings_of(cls: type[Any]) -> tuple[Setting, ...]:
    """Every value of the settings class, sections walked, in declaration order (a file's and a node's order)."""
    cached = _SETTINGS.get(cls)
    if cached is None:
        cached = _SETTINGS[cls] = _settings(cls)
    return cached


# --- reading ---------------------------------------------------------------------------------------------------


def _kind(hint: Any) -> tuple[str, Any]:
    """("bool" | "int" | "float" | "str" | "floats" | "strings" | "other", count or None) of a type hint."""
    inner = _optional(hint)
    if inner is not None:
        hint = inner
    if hint is bool:
        return "bool", None
    if hint is int:
        return "int", None
    if hint is float:
        return "float", None
    if hint is str:
        return "str", None
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        variadic = len(args) == 2 and args[1] is Ellipsis
        items = set(args[:1] if variadic else args)
        if items == {float}:
            return "floats", None if variadic else len(args)
        if items == {str} and variadic:
            return "strings", None
    return "other", None


def _strings(f: Fields, key: str) -> tuple[str, ...]:
    value = f.raw(key)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise f.error(key, f"expected a list of strings, got {value!r}"[:200])
    return tuple(value)


def _read_value(f: Fields, key: str, fld: _Field, policy: Policy) -> Any:
    meta = fld.meta
    if meta.codec is not None:
        value = meta.codec.read(f, key)
    else:
        kind, count = _kind(fld.hint)
        if kind == "bool":
            value = f.raw(key)
            if not isinstance(value, bool):
                raise f.error(key, f"expected true or false, got {value!r}")
        elif kind == "int":
            low, high = meta.range if meta.range is not None else (policy.counts or (None, None))
            value = f.integer(
                key, minimum=None if low is None else int(low), maximum=None if high is None else int(high)
            )
        elif kind == "float":
            within = meta.range
            if within is None and policy.numbers is not None:
                low, high = policy.numbers
                within = (-high if meta.signed else low, high)
            unit = meta.unit if policy.units_in_errors else ""
            value = f.number(key, within=within, unit=unit, positive=meta.positive and policy.checks == "read")
        elif kind == "str":
            value = f.string(key)
        elif kind == "floats":
            value = tuple(f.numbers(key, count) if count is not None else _any_numbers(f, key))
        elif kind == "strings":
            value = _strings(f, key)
        else:
            raise TypeError(f"{fld.name}: a {fld.hint!r} setting needs a codec")
        if policy.checks == "read" and kind == "int" and meta.positive and value <= 0:
            raise f.error(key, f"must be positive, got {value!r}")
        if policy.checks == "read" and meta.non_negative and kind in ("int", "float") and value < 0:
            raise f.error(key, f"must not be negative, got {value!r}")
    if meta.check is not None:
        problem = meta.check(value)
        if problem:
            raise f.error(key, problem)
    return value


def _any_numbers(f: Fields, key: str) -> list[float]:
    value = f.raw(key)
    return f.numbers(key, len(value)) if isinstance(value, list) and value else f.numbers(key, 1)


def _mapping_fields(cls: type[Any]) -> Iterator[_Field]:
    """The fields that have a key in one mapping of ``cls``: a spread section's fields in its place."""
    for fld in _fields(cls):
        if fld.section is not None and fld.key == "":
            yield from _mapping_fields(fld.section)
        else:
            yield fld


def _known(cls: type[Any]) -> list[str]:
    """The keys of one mapping of ``cls`` (spread sections' keys in their place); ``_aliases`` has the others."""
    return [fld.key for fld in _mapping_fields(cls)]


def _spread_sections(cls: type[Any]) -> dict[str, type[Any]]:
    """The sections whose keys stand in ``cls``'s own mapping, by attribute name (``limits``), nested ones too."""
    out: dict[str, type[Any]] = {}
    for fld in _fields(cls):
        if fld.section is not None and fld.key == "":
            out[fld.name] = fld.section
            out.update(_spread_sections(fld.section))
    return out


def _aliases(cls: type[Any]) -> list[str]:
    return [alias for fld in _mapping_fields(cls) for alias in fld.meta.aliases]


def _read_level(cls: type[Any], f: Fields, policy: Policy) -> tuple[dict[str, Any], list[tuple[str, Any]]]:
    """The values one mapping gives for ``cls``'s fields by attribute name (spread sections built), and each value
    read as (its key in this mapping, a tree of attribute names down to it) for ``_culprit``."""
    values: dict[str, Any] = {}
    leaves: list[tuple[str, Any]] = []
    for fld in _fields(cls):
        if fld.section is not None:
            if fld.key == "":
                sub, sub_leaves = _read_level(fld.section, f, policy)
                if sub:
                    values[fld.name] = _build(fld.section, sub, sub_leaves, f, policy)
                    leaves.extend((key, {fld.name: tree}) for key, tree in sub_leaves)
            elif f.has(fld.key):
                values[fld.name] = _read(fld.section, f.child(fld.key), policy)
                leaves.append((fld.key, {fld.name: values[fld.name]}))
            elif fld.meta.required:
                f.raw(fld.key)  # "missing field"
            continue
        value = _read_leaf(f, fld, policy)
        if value is not MISSING:
            values[fld.name] = value
            leaves.append((fld.key, {fld.name: value}))
    return values, leaves


def _read_leaf(f: Fields, fld: _Field, policy: Policy) -> Any:
    """A field's value under its key or the first alias the mapping has; MISSING when it has none (and the field
    has a default and is not required: otherwise the "missing field" error)."""
    key = next((k for k in (fld.key, *fld.meta.aliases) if f.has(k)), None)
    if key is None:
        if fld.meta.required or fld.default is MISSING:
            f.raw(fld.key)  # "missing field"
        return MISSING
    return _read_value(f, key, fld, policy)


def _check_unknown(cls: type[Any], f: Fields, policy: Policy) -> None:
    known = _known(cls)
    allowed = list(dict.fromkeys([*known, *_aliases(cls), *policy.ignore]))  # the keys, then the others read past
    if policy.unknown == "refuse":
        unknown = sorted(str(k) for k in f.data if k not in allowed)
        spread = _spread_sections(cls)
        if unknown and unknown[0] in spread:  # e.g. ``limits:``: its keys belong in this mapping itself
            keys = _known(spread[unknown[0]])
            where = f"under {f.prefix.rstrip('.')}" if f.prefix else "at the top level"
            some = ", ".join(keys[:3]) + (", ..." if len(keys) > 3 else "")
            raise f.error(unknown[0], f"not a key of this file: write its keys ({some}) {where}")
        if unknown:
            raise f.error(unknown[0], f"unknown key (known: {', '.join(known)})")
    else:
        f.warn_unknown(allowed)


def _read(cls: type[Any], f: Fields, policy: Policy) -> Any:
    _check_unknown(cls, f, policy)
    values, leaves = _read_level(cls, f, policy)
    return _build(cls, values, leaves, f, policy)


def _build(cls: type[Any], values: dict[str, Any], leaves: list[tuple[str, Any]], f: Fields, policy: Policy) -> Any:
    try:
        return cls(**values)
    except RuleError as exc:  # the rule's own key, below this mapping's
        raise ConfigError(f"{f.source}: {f.prefix}{exc.key}: {exc.problem}") from None
    except ConfigError as exc:
        text = str(exc)
        if policy.culprit:
            text = text.removeprefix(f"{policy.what}: ")
            if f.prefix:  # a nested section's own name (``planner: ``): the culprit's key says it
                text = text.removeprefix(f"{f.prefix.rstrip('.')}: ")
            raise ConfigError(f"{f.source}: {_culprit(cls, leaves, f.prefix)}{text}") from None
        if text.startswith(f"{f.source}:"):
            raise
        raise ConfigError(f"{f.source}: {text}") from None


def _culprit(cls: type[Any], leaves: list[tuple[str, Any]], prefix: str) -> str:
    """``key: `` of the first value read that the dataclass refuses on its own among its defaults, else nothing:
    its own checks know the rule but not the file's key."""
    defaults = cls()
    for key, tree in leaves:
        try:
            _apply(defaults, tree)
        except ConfigError:
            return f"{prefix}{key}: "
    return ""


def from_mapping(cls: type[T], data: Any, source: str) -> T:
    """An instance of the settings class ``cls`` from a file's mapping: each key read and checked as its field
    declares (a missing optional key keeps its default), unknown keys as the Policy says, then built.

    Raises:
        ConfigError: (or the Policy's error type) one line naming ``source``, the key and the problem.
    """
    policy = policy_of(cls)
    try:
        out = _read(cls, Fields(data, source), policy)
    except ConfigError as exc:
        if policy.error is ConfigError:
            raise
        raise policy.error(str(exc)) from None
    return typing.cast(T, out)


def from_flat(cls: type[T], values: Mapping[str, Any], source: str) -> T:
    """``from_mapping`` of flat names (ROS parameters: ``{"planner.standoff": 1.2}``)."""
    return from_mapping(cls, nested(values), source)


def from_fields(cls: type[T], fields: Fields, **given: Any) -> T:
    """An instance of ``cls`` read from one mapping of a larger file, some of its fields given by the file's
    structure rather than keys in the mapping: a marker's role (``markers: {left: {...}}``), a dock's name
    (``docks: {home: {...}}``). The ``given`` fields are taken as they are; every other field is read as
    ``from_mapping`` reads it, from ``fields``, whose prefix names the whole key path in errors; unknown keys are
    warned about.

    Raises:
        ConfigError: one line naming the file and the key (``layout.yaml: markers.left.y: ...``).
    """
    policy = policy_of(cls)
    declared = [f for f in _fields(cls) if f.name not in given]
    values = dict(given)
    for f in declared:
        value = _read_leaf(fields, f, policy)
        if value is not MISSING:
            values[f.name] = value
    fields.warn_unknown([*(f.key for f in declared), *(a for f in declared for a in f.meta.aliases), *policy.ignore])
    return cls(**values)


# --- writing and flat names ------------------------------------------------------------------------------------


def _plain(value: Any, hint: Any, what: str) -> Any:
    kind, _ = _kind(hint)
    if value is None:
        return None
    if kind == "float" or (kind == "int" and isinstance(value, float)):
        value = float(value) if kind == "float" else value
        if not math.isfinite(value):
            raise ConfigError(f"{what}: cannot write a non-finite value ({value})")
        return value
    if kind == "int":
        return int(value)
    if kind == "floats":
        out = [float(v) for v in value]
        bad = next((v for v in out if not math.isfinite(v)), None)
        if bad is not None:
            raise ConfigError(f"{what}: cannot write a non-finite value ({bad})")
        return out
    if kind == "strings" or isinstance(value, tuple):
        return list(value)
    return value


def _write(obj: Any, policy: Policy) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for fld in _fields(type(obj)):
        value = getattr(obj, fld.name)
        if fld.section is not None:
            sub = _write(value, policy)
            if fld.key == "":
                out.update(sub)
            elif not (fld.meta.omit_default and value == fld.default):
                out[fld.key] = sub
            continue
        if fld.meta.omit_default and value == fld.default:
            continue
        if fld.meta.codec is not None:
            out[fld.key] = fld.meta.codec.write(value)
        else:
            out[fld.key] = _plain(value, fld.hint, policy.what)
    return out


def to_mapping(obj: Any) -> dict[str, Any]:
    """The settings as their file holds them: nested mappings in declaration order, plain values (a real a float,
    a tuple a list), defaults left out where the field says so.

    Raises:
        ConfigError: a non-finite number, which a file cannot hold.
    """
    return _write(obj, policy_of(type(obj)))


def flat(obj: Any) -> dict[str, Any]:
    """Every value of the settings by flat name (``{"cruise_speed": 0.2, "planner.standoff": 1.0, ...}``)."""
    out: dict[str, Any] = {}
    for s in settings_of(type(obj)):
        value = obj
        for name in s.path:
            value = getattr(value, name)
        out[s.key] = value
    return out


def flag_of(setting: Setting) -> str | None:
    """A setting's command-line flag: the one it declares (a word without dashes is a positional), else
    ``--kebab-name``; None when it has none (``flag=""``)."""
    if setting.meta.flag == "":
        return None
    return setting.meta.flag or "--" + setting.key.replace("_", "-").replace(".", "-")


def to_argv(obj: Any) -> list[str]:
    """The command line that gives these options (what ``cli.options.add_flags``' parser reads back as them):
    the positionals in order, then a flag per value that is not its default.

    Raises:
        ValueError: a value that differs from its default but has no flag to say so.
    """
    values = flat(obj)
    positionals: list[str] = []
    words: list[str] = []
    for s in settings_of(type(obj)):
        value, flag = values[s.key], flag_of(s)
        if flag is not None and not flag.startswith("-"):
            positionals.append(_word(s, value))
            continue
        if s.default is not MISSING and value == s.default:
            continue
        if flag is None:
            raise ValueError(f"{type(obj).__name__}.{s.key} has no flag to give it {value!r}")
        if s.type is bool:
            words.append(flag if value else "--no-" + flag.removeprefix("--"))
        else:
            words += [flag, _word(s, value)]
    return [*positionals, *words]


def _word(setting: Setting, value: Any) -> str:
    if setting.meta.show is not None:
        return setting.meta.show(value)
    return repr(value) if isinstance(value, float) else str(value)


def nested(values: Mapping[str, Any]) -> dict[str, Any]:
    """Flat (dotted) names as a nested mapping: ``{"a.b": 1}`` → ``{"a": {"b": 1}}``.

    Raises:
        ConfigError: a name that uses a value as a section (``a`` and ``a.b`` both given).
    """
    out: dict[str, Any] = {}
    for name, value in values.items():
        *parents, leaf = name.split(".")
        node = out
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"parameter {name}: {part} is a value, not a section")
            node = child
        if isinstance(node.get(leaf), dict):
            raise ConfigError(f"parameter {name}: {leaf} is a section, not a value")
        node[leaf] = value
    return out


def replace(obj: T, changes: Mapping[str, Any] | None = None, /, **by_name: Any) -> T:
    """A copy of the settings with values changed by flat name (``cruise_speed``, ``planner.standoff``), through
    their sections; a keyed section may be given whole (``planner=PlannerConfig(...)``); ``changes`` takes the
    names that are not identifiers.

    Raises:
        KeyError: a name that is not one of the settings'.
    """
    wanted = {**(changes or {}), **by_name}
    paths = {**_section_paths(type(obj), (), ""), **{s.key: s.path for s in settings_of(type(obj))}}
    tree: dict[str, Any] = {}
    for name, value in wanted.items():
        if name not in paths:
            raise KeyError(f"{type(obj).__name__} has no setting {name!r}")
        *parents, leaf = paths[name]
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return typing.cast(T, _apply(obj, tree))


def _section_paths(cls: type[Any], path: tuple[str, ...], prefix: str) -> dict[str, tuple[str, ...]]:
    """The flat names of the sections that have a key of their own (``planner``, ``track.odometry``): a whole
    section may be replaced."""
    out: dict[str, tuple[str, ...]] = {}
    for fld in _fields(cls):
        if fld.section is not None:
            if fld.key:
                out[f"{prefix}{fld.key}"] = (*path, fld.name)
            out.update(_section_paths(fld.section, (*path, fld.name), f"{prefix}{fld.key}." if fld.key else prefix))
    return out


def _apply(obj: Any, tree: dict[str, Any]) -> Any:
    values = {
        name: _apply(getattr(obj, name), sub) if isinstance(sub, dict) and _is_dc(getattr(obj, name)) else sub
        for name, sub in tree.items()
    }
    return dataclasses.replace(obj, **values)


def _is_dc(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def check_fields(obj: Any, what: str | None = None) -> None:
    """The declared rules (``positive``, ``non_negative``, ``range``) of every value of the object, its sections'
    included, for a class whose Policy checks at construction: call it from ``__post_init__``.

    Raises:
        ConfigError: ``"{what}: {key} must be positive, got {value}"`` (the Policy's what unless given), for the
            first value in declaration order that breaks its rule.
    """
    what = policy_of(type(obj)).what if what is None else what
    _check(obj, what, "")


class RuleError(ConfigError):
    """A declared rule broken, from ``check_fields``: ``"{what}: {key} {problem}"``, with the key and the problem
    apart, so that a file's reader can say ``source: key: problem`` as its read-time errors do."""

    def __init__(self, what: str, key: str, problem: str) -> None:
        super().__init__(f"{what}: {key} {problem}")
        self.key = key
        self.problem = problem


def _rule_problem(meta: Meta, value: Any) -> str | None:
    """What a number breaks of its field's ``positive``, ``non_negative`` and ``range``, else None."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return None
    if meta.positive and not value > 0:
        return f"must be positive, got {value}"
    if meta.non_negative and not value >= 0:
        return f"must not be negative, got {value}"
    if meta.range is not None and not meta.range[0] <= value <= meta.range[1]:
        return f"must be within {meta.range[0]:g} to {meta.range[1]:g}, got {value}"
    return None


def _check(obj: Any, what: str, prefix: str) -> None:
    for fld in _fields(type(obj)):
        value = getattr(obj, fld.name)
        if fld.section is not None:
            _check(value, what, f"{prefix}{fld.key}." if fld.key else prefix)
            continue
        problem = _rule_problem(fld.meta, value)
        if problem:
            raise RuleError(what, f"{prefix}{fld.key}", problem)
