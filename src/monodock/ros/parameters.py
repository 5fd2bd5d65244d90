"""ROS 2 parameters for the nodes: declared with a description, and nested configs as dotted names.

A params file's nested mapping (``planner: {standoff: 1.2}``) reaches rclpy as the dotted name
``planner.standoff``; ``flatten`` and ``unflatten`` turn monodock's nested config mappings into those names and
back, so a node's parameters and a config file share one schema.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from typing import Any

from monodock.core.config import load_yaml
from monodock.errors import ConfigError

__all__ = ["check_params_files", "declare", "flatten", "unflatten"]


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


def declare(node: Any, name: str, default: Any, description: str, *, read_only: bool = False) -> Any:
    """Declare ``name`` with its description and return its value (the default unless overridden).

    Numbers take ints or floats alike (``-p standoff:=1`` is a float's 1.0): the parameter is dynamically typed
    and the caller checks the value, so a wrong type is one clear line instead of rclpy's exception.
    """
    from rcl_interfaces.msg import ParameterDescriptor  # type: ignore[import-not-found, unused-ignore]

    descriptor = ParameterDescriptor(description=description, read_only=read_only, dynamic_typing=True)
    return node.declare_parameter(name, default, descriptor).value


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested mapping as dotted names: ``{"a": {"b": 1}}`` → ``{"a.b": 1}``."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def unflatten(values: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted names as a nested mapping (``flatten``'s inverse)."""
    out: dict[str, Any] = {}
    for name, value in values.items():
        *parents, leaf = name.split(".")
        node = out
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"parameter {name}: {part} is a value, not a section")
            node = child
        node[leaf] = value
    return out
