"""ROS 2 parameters for the nodes: one scheme of typed, checked declarations, and nested configs as dotted names.

Every node describes its parameters as ``Parameter`` specs (what each is for, whether it may change live, a
number's range, a string's choices) and declares them with ``declare`` or ``declare_options``. A value comes back
of its default's type, checked against the spec (``checked``), or the node stops with one InputError line that names
the parameter, the value and what is allowed. The parameter then carries a typed descriptor (type, range,
read-only, choices) that ``ros2 param set`` obeys. An integer serves a real-valued parameter, at start-up
(``-p max_stamp_age:=2``) and in a live change alike.

The specs are derived from a settings class's declarations (``core.settings``): ``parameters_of`` gives one per
setting (its help the description, ``live`` the opposite of read-only, its range, positive, choices, and a tuple's
length), ``declare_settings`` declares them with the options' values as defaults. A params file's nested mapping
(``planner: {standoff: 1.2}``) reaches rclpy as the dotted name ``planner.standoff``, a setting's flat name:
``declare_config`` declares a config's settings so, ``config_from_parameters`` reads them back through the config
file's reader, so a node's parameters and a config file share one schema and one dialect of errors.
"""

from __future__ import annotations

import array
import dataclasses
import functools
import itertools
import math
import typing
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

from monodock.core.config import load_yaml
from monodock.core.settings import Setting, flat, from_flat, settings_of
from monodock.errors import InputError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    _Options = TypeVar("_Options", bound=DataclassInstance)

__all__ = [
    "Parameter",
    "check_params_files",
    "checked",
    "config_from_parameters",
    "declare",
    "declare_config",
    "declare_options",
    "declare_settings",
    "parameter_of",
    "parameters_of",
    "refuse_unknown_overrides",
]
_T = TypeVar("_T")


@dataclass(frozen=True)
class Parameter:
    """How one ROS parameter is declared and checked; its type is its default's (bool, int, float, str, or a
    tuple of floats; a tuple of strings with ``strings``).

    Attributes:
        description: what it is for, in its descriptor.
        read_only: read once, at start-up; False: it may change while the node runs.
        bounds: a number's range, both ends allowed (in the descriptor too).
        positive: a number must be finite and above 0 (a descriptor's range cannot leave out its end: the check
            alone says so).
        choices: the strings allowed ("" among them where empty means not given).
        length: how many numbers a tuple has.
        strings: a list of strings (a tuple default, which may be empty).
    """

    description: str
    read_only: bool = True
    bounds: tuple[float, float] | None = None
    positive: bool = False
    choices: tuple[str, ...] = ()
    length: int | None = None
    strings: bool = False

    @property
    def constraints(self) -> str:
        """What the descriptor says of the values allowed beyond the type and range (``additional_constraints``)."""
        if self.choices:
            return "one of: " + ", ".join(repr(c) for c in self.choices)
        if self.positive:
            return "finite and above 0"
        if self.length is not None:
            return f"{self.length} numbers"
        return ""


def check_params_files(argv: Sequence[str]) -> None:
    """Every ``--params-file FILE`` among the ROS arguments read first with monodock's YAML loader, so that a key
    named twice (which rcl's parser takes the last of without a word), a file that is not YAML or a missing one
    is one ConfigError naming the file and the key.

    Raises:
        ConfigError: as ``core.config.load_yaml``.
    """
    words = list(argv)
    for flag, value in itertools.pairwise(words):
        if flag == "--params-file":
            load_yaml(value, "ROS parameters")


def declare(node: Any, name: str, spec: Parameter, default: Any) -> Any:
    """Declare ``name`` with ``spec`` and return its value (``default`` unless ``-p`` or a params file overrides it),
    checked.

    It is declared dynamically typed first, so that a value of the wrong type is ``checked``'s one line rather than
    rclpy's exception and an integer serves a real; then it gets its typed descriptor, which changes obey.

    Raises:
        InputError: as ``checked``.
    """
    from rcl_interfaces.msg import (  # type: ignore[import-not-found, unused-ignore]
        FloatingPointRange,
        ParameterDescriptor,
    )
    from rclpy.parameter import Parameter as RosParameter  # type: ignore[import-not-found, unused-ignore]

    _accept_integers_for_reals(node)
    loose = ParameterDescriptor(description=spec.description, dynamic_typing=True)
    value = checked(name, spec, node.declare_parameter(name, _ros_value(default), loose).value, default)
    if spec.strings:  # typed by the spec: an empty list has no element to tell rclpy its type
        typed = RosParameter(name, RosParameter.Type.STRING_ARRAY, list(value))
    else:
        typed = RosParameter(name, value=_ros_value(value))
    descriptor = ParameterDescriptor(
        description=spec.description,
        read_only=spec.read_only,
        type=typed.type_.value,
        additional_constraints=spec.constraints,
    )
    if spec.bounds is not None:
        descriptor.floating_point_range = [FloatingPointRange(from_value=spec.bounds[0], to_value=spec.bounds[1])]
    node.set_descriptor(name, descriptor, typed.get_parameter_value())
    return value


def declare_options(node: Any, options: _Options, specs: Mapping[str, Parameter]) -> _Options:
    """Declare a parameter for each of ``specs``, a field of ``options`` whose value is its default, and return the
    options they hold.

    A field whose dataclass default is None is a string parameter, empty when not given (and None again here).

    Raises:
        InputError: as ``checked``.
    """
    optional = {f.name for f in dataclasses.fields(options) if f.default is None}
    values: dict[str, Any] = {}
    for name, spec in specs.items():
        default = getattr(options, name)
        value = declare(node, name, spec, "" if default is None else default)
        values[name] = (value or None) if name in optional else value
    return dataclasses.replace(options, **values)


def checked(name: str, spec: Parameter, value: Any, default: Any) -> Any:
    """``value`` as the type of ``default`` (an integer serves a real; a tuple's numbers come back a tuple), within
    the spec's range, choices and length.

    Raises:
        InputError: one line naming the parameter, the value and what is allowed.
    """
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"parameter {name} is true or false, got {value!r}")
        return value
    if isinstance(default, float):
        return _number(name, spec, value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"parameter {name} is an integer, got {value!r}")
        _number(name, spec, value)  # its range and sign, as a real's
        return value
    if spec.strings:
        items = list(value) if isinstance(value, list | tuple) else None
        if items is None or not all(isinstance(v, str) for v in items):
            raise InputError(f"parameter {name} is a list of strings, got {value!r}")
        return tuple(items)
    if isinstance(default, tuple | list):
        return _numbers(name, spec, value)
    if not isinstance(value, str):
        raise InputError(f"parameter {name} is a string, got {value!r} (quote a number: {name}:=\"'{value}'\")")
    if spec.choices and value not in spec.choices:
        named = ", ".join(c for c in spec.choices if c)
        raise InputError(f"parameter {name}: '{value}' is not one of {named}")
    return value


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _number(name: str, spec: Parameter, value: Any) -> float:
    if not _is_number(value):
        raise InputError(f"parameter {name} is a number, got {value!r}")
    number = float(value)
    if spec.bounds is not None:
        low, high = spec.bounds
        if not low <= number <= high:
            raise InputError(f"parameter {name} must be from {low:g} to {high:g}, got {number:g}")
    if spec.positive and not (math.isfinite(number) and number > 0):
        raise InputError(f"parameter {name} must be a finite number above 0, got {number:g}")
    return number


def _numbers(name: str, spec: Parameter, value: Any) -> tuple[float, ...]:
    items = list(value) if isinstance(value, list | tuple | array.array) else None
    if (
        items is None
        or not all(_is_number(v) and math.isfinite(v) for v in items)
        or (spec.length is not None and len(items) != spec.length)
    ):
        count = "" if spec.length is None else f"{spec.length} "
        raise InputError(
            f"parameter {name} is a list of {count}finite numbers, got {value if items is None else items!r}"
        )
    return tuple(float(v) for v in items)


def _ros_value(value: Any) -> Any:
    """A value as rclpy takes it: a tuple as a list (an empty list of strings is typed by ``declare`` after)."""
    return list(value) if isinstance(value, tuple) else value


# The nodes whose live changes take an integer for a real (each gets the callback once: rclpy would run a second
# one too and set every parameter twice).
_WIDENING: weakref.WeakSet[Any] = weakref.WeakSet()


def _accept_integers_for_reals(node: Any) -> None:
    if node not in _WIDENING:
        _WIDENING.add(node)
        node.add_pre_set_parameters_callback(functools.partial(_integers_as_reals, node))


def _integers_as_reals(node: Any, parameters: list[Any]) -> list[Any]:
    """A live change's integers as reals where the parameter is real (``ros2 param set`` sends ``2`` as an
    integer), as at start-up; rclpy's type check, which comes after this, would refuse them."""
    from rclpy.parameter import Parameter as RosParameter  # type: ignore[import-not-found, unused-ignore]

    kinds = RosParameter.Type
    out: list[Any] = []
    for given in parameters:
        kind = node.describe_parameter(given.name).type if node.has_parameter(given.name) else None
        if given.type_ == kinds.INTEGER and kind == kinds.DOUBLE.value:
            out.append(RosParameter(given.name, value=float(given.value)))
        elif given.type_ == kinds.INTEGER_ARRAY and kind == kinds.DOUBLE_ARRAY.value:
            out.append(RosParameter(given.name, value=[float(v) for v in given.value]))
        else:
            out.append(given)
    return out


def refuse_unknown_overrides(node: Any) -> None:
    """A misspelt parameter (``-p planner.standof:=1.2``, a params file's key) is an error, not silently ignored.

    Raises:
        InputError: naming the first unknown name.
    """
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps -p and params-file values here
    unknown = sorted(name for name in overrides if not node.has_parameter(name))
    if unknown:
        raise InputError(f"unknown parameter {unknown[0]} (docs/ros2.md lists the node's parameters)")


def parameter_of(setting: Setting) -> Parameter:
    """The ROS parameter spec a setting declares: its help, read-only unless live, its range, positive, choices
    ("" among them where the default is None: empty means not given), and a tuple's length or a list of strings."""
    hint = setting.type
    args = typing.get_args(hint)
    fixed = typing.get_origin(hint) is tuple and bool(args) and Ellipsis not in args
    strings = typing.get_origin(hint) is tuple and args == (str, Ellipsis)
    choices = setting.meta.choices
    if choices and setting.default is None and "" not in choices:
        choices = ("", *choices)
    return Parameter(
        setting.meta.help,
        read_only=not setting.live,
        bounds=setting.meta.range,
        positive=setting.meta.positive,
        choices=choices,
        length=len(args) if fixed else None,
        strings=strings,
    )


def parameters_of(cls: type[Any]) -> dict[str, Parameter]:
    """A spec per setting of the options class (those declared ``ros=False`` left out), in declaration order."""
    return {s.key: parameter_of(s) for s in settings_of(cls) if s.meta.ros}


def declare_settings(node: Any, options: _Options) -> _Options:
    """Declare a parameter per setting of ``options`` (``parameters_of``), its value the default, and return the
    options they hold.

    Raises:
        InputError: as ``checked``.
    """
    return declare_options(node, options, parameters_of(type(options)))


def _config_description(setting: Setting) -> str:
    unit = f", {setting.meta.unit}" if setting.meta.unit else ""
    return f"{setting.meta.help}{unit} (docs/docking.md)"


def declare_config(node: Any, config: Any) -> list[str]:
    """Declare each setting of a config by its flat name (``cruise_speed``, ``planner.standoff``), the config's value
    its default, without a range: a value out of range is the config file's one line, from
    ``config_from_parameters``. Returns the names.

    Raises:
        InputError: a value of the wrong type, as ``checked``.
    """
    values = flat(config)
    for s in settings_of(type(config)):
        declare(node, s.key, Parameter(_config_description(s), read_only=not s.live), values[s.key])
    return list(values)


def config_from_parameters(
    node: Any, cls: type[_T], names: Sequence[str], changes: Mapping[str, Any] | None = None
) -> _T:
    """The config the parameters ``names`` hold now (with ``changes``, a live change, applied), read as a config file
    named "ROS parameters" is.

    Raises:
        ConfigError: as the config file's reader.
    """
    values = {name: node.get_parameter(name).value for name in names}
    values.update({k: v for k, v in (changes or {}).items() if k in values})
    return from_flat(cls, values, "ROS parameters")
