"""The docking node's dock database from its ROS parameters, named as Nav2's docking server names them.

```yaml
docking_server:            # or monodock_dock
  ros__parameters:
    dock_plugins: ["monodock"]                 # the dock types
    monodock:
      plugin: "monodock::ArucoChargingDock"
      layout: "/path/to/layout.yaml"           # monodock's: the markers of docks of this type ("": the node's layout)
      staging_x_offset: -0.7                   # as SimpleChargingDock's, with its defaults
      staging_yaw_offset: 0.0
      docking_threshold: 0.05
      charging_threshold: 0.5
      use_battery_status: true
    docks: ["home_dock"]                       # the instances, or dock_database: FILE (upstream's format)
    home_dock:
      type: "monodock"
      frame: "map"
      pose: [0.0, 0.0, 0.0]
      id: ""
      layout: ""                               # monodock's: this dock's own layout ("": its type's)
```

With neither ``docks`` nor ``dock_database`` the database holds one dock, ``dock_id`` (``home_dock``, the name Nav2's
example behaviour trees dock at), of the first type and with no pose: monodock finds it with its camera. Every name
is declared when the node starts (a misspelt one is refused there, in one line); the values are read again when the
node is configured. ``~/reload_database`` (nav2_msgs/srv/ReloadDockDatabase) replaces the instances from a file, as
upstream's does, and is refused while a goal runs.
"""

from __future__ import annotations

from typing import Any

from monodock.core.pose2d import Pose2D
from monodock.dock.database import PLUGIN, DockDatabase, DockInstance, DockType, load_dock_file
from monodock.errors import InputError
from monodock.ros.parameters import Parameter, declare

__all__ = ["DATABASE_PARAMETERS", "declare_database", "read_database"]

DATABASE_PARAMETERS: dict[str, Parameter] = {
    "dock_plugins": Parameter(
        "the dock types (Nav2's dock plugins), each with TYPE.plugin and its settings", strings=True
    ),
    "docks": Parameter(
        "the docks (each with NAME.type, NAME.frame, NAME.pose, NAME.id, NAME.layout); empty: dock_database's",
        strings=True,
    ),
    "dock_database": Parameter(
        "dock database YAML in Nav2's format (docks: {NAME: {type, frame, pose, id}}); empty: docks"
    ),
}

_D = DockType(name="")  # SimpleChargingDock's defaults
_TYPE_PARAMETERS: dict[str, tuple[Parameter, Any]] = {
    "plugin": (Parameter(f"the dock plugin: {PLUGIN}", choices=(PLUGIN,)), PLUGIN),
    "layout": (Parameter("dock layout YAML of this type's docks; empty: the node's layout"), ""),
    "staging_x_offset": (
        Parameter("staging pose: m along the dock's heading from its pose", bounds=(-20.0, 20.0)),
        _D.staging_x_offset,
    ),
    "staging_yaw_offset": (
        Parameter("staging pose: rad added to the dock's heading", bounds=(-7.0, 7.0)),
        _D.staging_yaw_offset,
    ),
    "docking_threshold": (Parameter("m from where it docked: still docked", positive=True), _D.docking_threshold),
    "charging_threshold": (
        Parameter("A of battery current above which it charges", bounds=(-1000.0, 1000.0)),
        _D.charging_threshold,
    ),
    "use_battery_status": (Parameter("charging from battery_state (false: it cannot tell)"), _D.use_battery_status),
}
_DOCK_PARAMETERS: dict[str, tuple[Parameter, Any]] = {
    "type": (Parameter("the dock's type (one of dock_plugins)"), ""),
    "frame": (Parameter("the frame of its pose"), "map"),
    "pose": (Parameter("x, y (m), theta (rad) of the docked robot's base_link in frame", length=3), (0.0, 0.0, 0.0)),
    "id": (Parameter("its detector id (unused by monodock)"), ""),
    "layout": (Parameter("its own dock layout YAML; empty: its type's"), ""),
}


def declare_database(node: Any, default_type: str) -> None:
    """Declare every database parameter the node was started with (types and docks by name).

    Raises:
        InputError: a dock without its type or pose, or a value of the wrong kind.
    """
    overrides = getattr(node, "_parameter_overrides", {})
    plugins = declare(node, "dock_plugins", DATABASE_PARAMETERS["dock_plugins"], (default_type,))
    for name in plugins:
        for key, (spec, default) in _TYPE_PARAMETERS.items():
            declare(node, f"{name}.{key}", spec, default)
    docks = declare(node, "docks", DATABASE_PARAMETERS["docks"], ())
    for name in docks:
        for required in ("type", "pose"):
            if f"{name}.{required}" not in overrides:
                raise InputError(f"dock {name} has no '{required}' (give {name}.{required} with docks: [{name}])")
        for key, (spec, default) in _DOCK_PARAMETERS.items():
            declare(node, f"{name}.{key}", spec, default)
    declare(node, "dock_database", DATABASE_PARAMETERS["dock_database"], "")


def read_database(node: Any, default_dock: str) -> DockDatabase:
    """The database the parameters hold now (``DockDatabase::initialize``); ``default_dock`` names the one dock of a
    node given no docks.

    Raises:
        ConfigError: as ``DockDatabase`` and ``load_dock_file``.
    """

    def value(name: str) -> Any:
        return node.get_parameter(name).value

    types = {}
    for name in value("dock_plugins"):
        settings = {key: value(f"{name}.{key}") for key in _TYPE_PARAMETERS}
        types[name] = DockType(name=name, **settings)
    path = value("dock_database")
    docks: dict[str, DockInstance]
    if path:
        docks = load_dock_file(path)
    elif value("docks"):
        docks = {}
        for name in value("docks"):
            x, y, theta = (float(v) for v in value(f"{name}.pose"))
            docks[name] = DockInstance(
                name=name,
                type=value(f"{name}.type"),
                frame=value(f"{name}.frame"),
                pose=Pose2D(x, y, theta),
                id=value(f"{name}.id"),
                layout=value(f"{name}.layout"),
            )
    else:
        first = next(iter(types))
        docks = {default_dock: DockInstance(name=default_dock, type=first, frame="", pose=None)}
    return DockDatabase(types, docks)
