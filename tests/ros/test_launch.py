"""launch/monodock_docking.launch.py and its parameters file, checked where ``ros2 launch`` cannot be installed
(launch and launch_ros are not among the ROS 2 wheels on PyPI): the launch description is imported against small
stand-ins that record what it builds, and its nodes and parameters are checked against monodock's executables and
against what the docking node itself declares (the node, started on the params file in a private network namespace,
refuses any key it does not know).
"""

from __future__ import annotations

import importlib.util
import json
import sys
import tomllib
import types
from pathlib import Path
from typing import Any

import pytest
import yaml

from private_graph import needs_graph, run_private_graph

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / "launch" / "monodock_docking.launch.py"
PARAMS = ROOT / "config" / "monodock_docking.yaml"
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]


class _Recorded:
    """A stand-in for a launch class: what it was built with."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


class LaunchConfiguration(_Recorded):
    def __eq__(self, other: object) -> bool:
        return isinstance(other, LaunchConfiguration) and self.args == other.args

    __hash__ = None  # type: ignore[assignment]


def _stand_ins(monkeypatch: pytest.MonkeyPatch) -> None:
    """launch, launch.actions, launch.conditions, launch.substitutions, launch_ros.actions and ament_index_python's
    share lookup (the repository is laid out as the installed share/monodock: config/ and launch/)."""
    kinds = {
        "launch": {"LaunchDescription": type("LaunchDescription", (_Recorded,), {})},
        "launch.actions": {"DeclareLaunchArgument": type("DeclareLaunchArgument", (_Recorded,), {})},
        "launch.conditions": {"IfCondition": type("IfCondition", (_Recorded,), {})},
        "launch.substitutions": {"LaunchConfiguration": LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": type("Node", (_Recorded,), {})},
        "ament_index_python": {},
        "ament_index_python.packages": {"get_package_share_directory": lambda _name: str(ROOT)},
    }
    for name, members in kinds.items():
        module = types.ModuleType(name)
        for key, value in members.items():
            setattr(module, key, value)
        monkeypatch.setitem(sys.modules, name, module)


def _description(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    _stand_ins(monkeypatch)
    spec = importlib.util.spec_from_file_location("monodock_docking_launch", LAUNCH)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return list(module.generate_launch_description().args[0])


def test_the_launch_description_starts_the_docking_node_as_docking_server(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    entities = _description(monkeypatch)
    arguments = {a.args[0]: a.kwargs["default_value"] for a in entities if type(a).__name__ == "DeclareLaunchArgument"}
    # Nav2's launch conventions, and files that exist.
    assert {"namespace", "use_sim_time", "params_file", "autostart"} <= set(arguments)
    assert arguments["namespace"] == ""
    assert arguments["use_sim_time"] == "false"
    assert arguments["autostart"] == "true"
    for name in ("params_file", "layout", "robot"):
        assert Path(arguments[name]).is_file(), name
    assert Path(arguments["params_file"]) == PARAMS
    nodes = {n.kwargs["name"]: n.kwargs for n in entities if type(n).__name__ == "Node"}
    assert set(nodes) == {"docking_server", "lifecycle_manager_docking"}

    docking = nodes["docking_server"]
    assert docking["package"] == "monodock"
    assert docking["executable"] in SCRIPTS
    assert SCRIPTS[docking["executable"]] == "monodock.cli.ros_nodes:dock_main"
    assert docking["namespace"] == LaunchConfiguration("namespace")
    first, params_file, last = docking["parameters"]
    assert set(first) == {"layout", "robot"}
    assert params_file == LaunchConfiguration("params_file")
    # The lifecycle manager starts it: it must not start itself.
    assert last["autostart_node"] is False
    assert last["use_sim_time"] == LaunchConfiguration("use_sim_time")

    manager = nodes["lifecycle_manager_docking"]
    assert (manager["package"], manager["executable"]) == ("nav2_lifecycle_manager", "lifecycle_manager")
    (settings,) = manager["parameters"]
    assert settings["node_names"] == ["docking_server"]
    assert settings["autostart"] == LaunchConfiguration("autostart")


def test_the_params_file_is_for_the_docking_server_and_holds_nav2_s_default_dock() -> None:
    (key, section), *_ = yaml.safe_load(PARAMS.read_text(encoding="utf-8")).items()
    assert key.endswith("docking_server")
    values = section["ros__parameters"]
    assert values["autostart_node"] is False
    assert values["enable_stamped_cmd_vel"] is True
    assert values["docks"] == ["home_dock"]
    assert values["home_dock"]["type"] in values["dock_plugins"]


@pytest.mark.slow
@pytest.mark.timeout(120)
@needs_graph()
def test_the_docking_node_takes_the_params_file_as_the_launch_passes_it() -> None:
    """The node started as the launch starts it (its name, the layout and robot, the params file, then what the launch
    fixes): it declares every key of the file and holds the values, unconfigured until a manager brings it up."""
    run = run_private_graph(
        Path(__file__).with_name("graph_launch_params.py"),
        str(PARAMS),
        str(ROOT / "config" / "layout.yaml"),
        str(ROOT / "config" / "robot.yaml"),
        timeout=100,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    got = run.first("params")
    values = yaml.safe_load(PARAMS.read_text(encoding="utf-8"))["/**/docking_server"]["ros__parameters"]
    flat = {}
    for key, value in values.items():
        if isinstance(value, dict):
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    for key, value in flat.items():
        assert got["values"][key] == value, (key, json.dumps(got["values"].get(key)))
    assert got["name"] == "docking_server"
    assert got["docks"] == {"home_dock": ["monodock", "map", [0.0, 0.0, 0.0]]}
    assert got["state"] == "unconfigured"
