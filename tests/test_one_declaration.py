"""A setting is declared once (issue 40): one more ``setting(...)`` field, and nothing else edited, is read and
written by the file's reader and writer, is a ROS parameter with its descriptor's range and a live check in the
parameter's words, and is a command-line flag in the node's parser.

The nodes' command lines (cli.ros_nodes) import rclpy: what needs them runs in a child process with stand-ins for it.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

import pytest

from monodock.cli.options import add_flags
from monodock.core.config import yaml_text
from monodock.core.settings import flat, from_mapping, setting, settings_of, to_argv, to_mapping
from monodock.dock.config import DockingConfig
from monodock.errors import ConfigError, InputError
from monodock.ros.parameters import checked, config_from_parameters, parameters_of
from monodock.ros.sim_settings import SimSettings
from shared import json_with_stand_ins


@dataclass(frozen=True)
class WiderConfig(DockingConfig):
    """The docking config with one setting more, as a new docking setting is added: one declaration."""

    max_turn_correction_rate: float = setting(
        0.4, unit="rad/s", positive=True, help="Moving₃: the P-controller never turns faster than this"
    )


class _Node:
    """What config_from_parameters asks of a node: its parameters' values."""

    def __init__(self, values: dict[str, Any]) -> None:
        self.values = values

    def get_parameter(self, name: str) -> Any:
        return argparse.Namespace(value=self.values[name])


def test_a_new_docking_setting_is_read_written_checked_and_a_ros_parameter() -> None:
    config = from_mapping(WiderConfig, {"max_turn_correction_rate": 0.3, "cruise_speed": 0.25}, "docking.yaml")
    assert config.max_turn_correction_rate == 0.3
    assert config.limits.cruise_speed == 0.25
    text = yaml_text(to_mapping(config))
    assert text.endswith("max_turn_correction_rate: 0.3\n")
    assert from_mapping(WiderConfig, to_mapping(config), "again") == config
    with pytest.raises(ConfigError) as caught:
        from_mapping(WiderConfig, {"max_turn_correction_rate": 0}, "docking.yaml")
    assert str(caught.value) == ("docking.yaml: max_turn_correction_rate: must be positive, got 0.0")
    with pytest.raises(ConfigError, match=r"^docking.yaml: max_turn_corection_rate: unknown key \(known: .*"):
        from_mapping(WiderConfig, {"max_turn_corection_rate": 1.0}, "docking.yaml")

    # A ROS parameter of the docking node: its flat name, live, and a live change checked as the file is.
    (declared,) = [s for s in settings_of(WiderConfig) if s.key == "max_turn_correction_rate"]
    assert declared.live
    assert declared.meta.unit == "rad/s"
    values = flat(WiderConfig())
    assert list(values)[-1] == "max_turn_correction_rate"
    node = _Node(values)
    changed = config_from_parameters(node, WiderConfig, list(values), {"max_turn_correction_rate": 0.5})
    assert changed.max_turn_correction_rate == 0.5
    with pytest.raises(ConfigError, match=r"^ROS parameters: max_turn_correction_rate: must be positive, got 0.0$"):
        config_from_parameters(node, WiderConfig, list(values), {"max_turn_correction_rate": 0.0})


@dataclass(frozen=True)
class BusierSim(SimSettings):
    """The simulated robot's settings with one more, as a new node setting is added: one declaration."""

    odom_rate: float = setting(50.0, range=(1.0, 200.0), help="odometry messages per second")


def test_a_new_node_setting_is_a_ros_parameter_with_its_range_and_a_flag() -> None:
    spec = parameters_of(BusierSim)["odom_rate"]
    assert spec.description == "odometry messages per second"
    assert spec.bounds == (1.0, 200.0)
    assert not spec.read_only  # the sim's Policy: its parameters are writable
    assert checked("odom_rate", spec, 20, 50.0) == 20.0
    with pytest.raises(InputError, match=r"^parameter odom_rate must be from 1 to 200, got 500$"):
        checked("odom_rate", spec, 500, 50.0)

    parser = argparse.ArgumentParser(prog="sim")
    add_flags(parser, BusierSim)
    assert "--odom-rate ODOM_RATE" in parser.format_help()
    args = parser.parse_args(["--odom-rate", "20", "--seed", "3"])
    assert BusierSim(**vars(args)) == BusierSim(odom_rate=20.0, seed=3)
    assert to_argv(BusierSim(odom_rate=20.0)) == ["--odom-rate", "20.0"]


def test_a_new_setting_of_the_docking_node_is_a_parameter_and_a_flag() -> None:
    """The docking node's own options (DockOptions, and its flags in cli.ros_nodes): one declaration gives the
    read-only parameter with its descriptor's range and a flag after the node's others in --help."""
    got = json_with_stand_ins(
        """
        import dataclasses, json
        from monodock.cli import ros_nodes
        from monodock.core.settings import setting
        from monodock.ros.dock_options import DockOptions
        from monodock.ros.parameters import parameters_of

        @dataclasses.dataclass(frozen=True)
        class Extended(DockOptions):
            cmd_vel_rate: float = setting(
                50.0, range=(1.0, 200.0), help="cmd_vel messages per second while a mission runs, Hz"
            )

        parser = ros_nodes._Parser(prog="monodock-dock-ros")
        ros_nodes.add_flags(
            parser, Extended, first=ros_nodes._DOCK_ORDER, skip=ros_nodes._ESTIMATOR_FLAGS, helps=ros_nodes._DOCK_HELPS
        )
        spec = parameters_of(Extended)["cmd_vel_rate"]
        print(json.dumps({
            "spec": dataclasses.asdict(spec),
            "last_flag": parser._actions[-1].option_strings,
            "parsed": parser.parse_args(["--cmd-vel-rate", "20"]).cmd_vel_rate,
        }))
        """
    )
    assert got["spec"]["bounds"] == [1.0, 200.0]
    assert got["spec"]["read_only"]
    assert got["spec"]["description"] == "cmd_vel messages per second while a mission runs, Hz"
    assert got["last_flag"] == ["--cmd-vel-rate"]
    assert got["parsed"] == 20.0
