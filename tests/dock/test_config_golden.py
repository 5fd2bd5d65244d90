"""The docking config file pinned as it was before the settings schema took it over: the text written for the
defaults and for a config with every value changed, the flat names in order, and the one line of each refusal.

The goldens in tests/data/settings were written by the hand-written reader and writer (issue 40, step 0); the
settings schema must reproduce them byte for byte.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from monodock.core.config import yaml_text
from monodock.dock.config import DockingConfig, docking_config_from_dict, docking_config_to_dict
from monodock.errors import ConfigError

GOLDEN = Path(__file__).parents[1] / "data" / "settings"


def _leaves(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_leaves(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def _nest(name: str, value: Any) -> dict[str, Any]:
    *parents, leaf = name.split(".")
    out: dict[str, Any] = {leaf: value}
    for part in reversed(parents):
        out = {part: out}
    return out


def _bad_values(default: Any) -> list[Any]:
    """Values of the wrong type, out of the broad range, non-finite and at the rules' edges."""
    if isinstance(default, bool):
        return ["yes", 1]
    if isinstance(default, int):
        return [1.5, -1, 0, 10**40, True, "3"]
    if isinstance(default, float):
        return ["fast", math.inf, -0.1, 0.0, 1e300, -1e4, 1e4 + 1, None, [1.0]]
    return [3, None]


def error_cases() -> list[tuple[str, Any]]:
    """(flat key, bad value) for every key of the docking config."""
    names = _leaves(docking_config_to_dict(DockingConfig()))
    return [(name, value) for name, default in names.items() for value in _bad_values(default)]


def _refusal(data: Any) -> str:
    try:
        docking_config_from_dict(data, "docking.yaml")
    except ConfigError as exc:
        return str(exc)
    return "accepted"


def rich_config() -> dict[str, Any]:
    """Every value moved from its default within its rules (booleans flipped)."""

    def move(name: str, value: Any) -> Any:
        if isinstance(value, bool):
            return not value
        if isinstance(value, int):
            return value + 1
        if isinstance(value, float):
            return round(value * 1.1 + (0.001 if "offset" not in name else 0.01), 6)
        return value

    flat = {k: move(k, v) for k, v in _leaves(docking_config_to_dict(DockingConfig())).items()}
    out: dict[str, Any] = {}
    for name, value in flat.items():
        node = out
        *parents, leaf = name.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def golden_refusals() -> dict[str, str]:
    return {f"{name}={value!r}": _refusal(_nest(name, value)) for name, value in error_cases()}


def test_the_defaults_are_written_as_before() -> None:
    text = yaml_text(docking_config_to_dict(DockingConfig()))
    assert text == (GOLDEN / "docking_defaults.yaml").read_text(encoding="utf-8")


def test_a_config_with_every_value_changed_reads_and_writes_as_before() -> None:
    config = docking_config_from_dict(rich_config(), "rich")
    text = yaml_text(docking_config_to_dict(config))
    assert text == (GOLDEN / "docking_rich.yaml").read_text(encoding="utf-8")


def test_the_flat_names_are_as_before_in_order() -> None:
    names = list(_leaves(docking_config_to_dict(DockingConfig())))
    assert names == (GOLDEN / "docking_names.txt").read_text(encoding="utf-8").split()


@pytest.mark.parametrize(
    "data",
    [
        {"k_laterl": 1.0},
        {"planner": {"standof": 1.0}},
        {"track": {"odometry": {"x": 1}}},
        {"charging_offset": {"x": 0.5}},
        {"staging_distance": 3.0},
        {"far_bearing_deg": 91.0},
        {"far_max_legs": 0},
        {"min_speed": 0.5},
        {"min_speed": 0.11, "approach_speed": 0.2},
        {"recover_distance": 2.0},
        {"cruise_speed": 0.0, "turn_rate": 0.0},
        {"planner": 3},
        {"track": []},
    ],
)
def test_refusals_of_keys_and_rules_are_as_before(data: dict[str, Any]) -> None:
    golden = json.loads((GOLDEN / "docking_rules.json").read_text(encoding="utf-8"))
    assert _refusal(data) == golden[json.dumps(data, sort_keys=True)]


def test_every_bad_value_of_every_key_is_refused_as_before() -> None:
    golden = json.loads((GOLDEN / "docking_refusals.json").read_text(encoding="utf-8"))
    assert golden_refusals() == golden
