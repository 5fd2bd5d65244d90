"""The nodes' ROS parameter specs pinned as they were hand-written before the settings declarations derived them
(issue 40, step 0): every name, description, read-only flag, range, choice and length, and every default.

The nodes' modules import rclpy; the table is made in a child process with stand-ins for it
(``shared.RCLPY_STAND_INS``), so that no real rclpy is loaded here.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from shared import json_with_stand_ins

GOLDEN = Path(__file__).parents[1] / "data" / "settings" / "ros_parameters.json"

_SCRIPT = """
import dataclasses, json

from monodock.ros.detector import PARAMETERS as DETECTOR, DetectorOptions
from monodock.ros.dock_options import PARAMETERS as DOCK, DockOptions
from monodock.ros.sim_node import PARAMETERS as SIM
from monodock.ros.sim_settings import SimSettings

def table(specs, options):
    return {
        name: {**dataclasses.asdict(spec), "default": getattr(options, name)}
        for name, spec in sorted(specs.items())
    }

print(json.dumps({
    "monodock_detector": table(DETECTOR, DetectorOptions()),
    "monodock_dock": table(DOCK, DockOptions()),
    "monodock_sim": table(SIM, SimSettings()),
}))
"""


def tables() -> dict[str, Any]:
    """Each node's specs and defaults as JSON values (tuples as lists)."""
    out: dict[str, Any] = json_with_stand_ins(_SCRIPT)
    return out


def test_every_node_parameter_is_declared_as_before() -> None:
    assert tables() == json.loads(GOLDEN.read_text(encoding="utf-8"))


def test_an_integer_parameter_is_held_to_its_range_and_sign() -> None:
    from monodock.errors import InputError
    from monodock.ros.parameters import Parameter, checked

    spec = Parameter("tries", bounds=(1.0, 10.0))
    assert checked("tries", spec, 3, 1) == 3
    with pytest.raises(InputError, match=r"^parameter tries must be from 1 to 10, got 0$"):
        checked("tries", spec, 0, 1)
    with pytest.raises(InputError, match=r"^parameter gap must be a finite number above 0, got -2$"):
        checked("gap", Parameter("gap", positive=True), -2, 1)
