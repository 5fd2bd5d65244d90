"""The dock database, as Nav2's docking server keeps it: dock types (its "dock plugins") and dock instances.

A **dock type** is what Nav2 loads as a plugin (``dock_plugins: [name]``, ``name.plugin: ...``): here always a
monodock charger, three ArUco markers and a camera, with its own layout file and the settings Nav2's
``SimpleChargingDock`` has (staging offsets, docking and charging thresholds). A **dock instance** is one charger
in the world: a name (a DockRobot goal's ``dock_id``), its type, the frame its pose is given in (``map`` unless
said), that pose ``[x, y, theta]`` and an optional ``id``; monodock adds an optional ``layout`` of its own.

The pose means what it means to Nav2's ``SimpleChargingDock``: where the robot's ``base_link`` stands when docked
(``isDocked`` compares the two, ``docking_threshold`` apart). The staging pose is worked out from it as upstream does:
``staging_x_offset`` along its heading (negative: in front of the dock) and ``staging_yaw_offset`` on the heading
(``simple_charging_dock.cpp``, Kilted, ``getStagingPose``). A dock may also have no pose (the default dock of a node
given no database): monodock finds it with its camera, and there is no staging pose to navigate to.

The file format is upstream's (``utils::parseDockFile``): a top-level ``docks`` mapping of name to
``{type, frame, pose, id}``; its ``frame`` defaults to ``map``. Nothing here needs ROS.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from monodock.core.config import Fields, load_yaml
from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.settings import from_fields, setting
from monodock.dock.nav2 import DockNotInDB, DockNotValid
from monodock.errors import ConfigError

__all__ = ["PLUGIN", "DockDatabase", "DockInstance", "DockType", "load_dock_file", "pose_distance", "staging_pose"]

# The plugin name a dock type of monodock's carries (``name.plugin``), in pluginlib's namespace::Class form.
PLUGIN = "monodock::ArucoChargingDock"


@dataclass(frozen=True)
class DockType:
    """One dock type (a Nav2 dock plugin instance), with SimpleChargingDock's defaults."""

    name: str
    plugin: str = PLUGIN
    layout: str = ""  # its dock layout YAML; empty: the docking node's own ``layout``
    staging_x_offset: float = -0.7  # m along the dock's heading from its pose to the staging pose
    staging_yaw_offset: float = 0.0  # rad added to the dock's heading at the staging pose
    docking_threshold: float = 0.05  # m: a robot this close to where it docked is docked
    charging_threshold: float = 0.5  # A: a battery current above this is charging
    use_battery_status: bool = True  # charging from battery_state; False: charging is not known (docked is)


class _PoseList:
    """A dock file's ``pose``: ``[x, y, theta]``, three finite numbers."""

    def read(self, fields: Fields, key: str) -> Pose2D:
        x, y, theta = fields.numbers(key, 3)
        return Pose2D(x, y, theta)

    def write(self, value: Pose2D | None) -> list[float] | None:
        return None if value is None else [value.x, value.y, value.theta]


class _Text:
    """A dock file's ``id`` as upstream reads it (``as<std::string>()``): a string, or a number written as one."""

    def read(self, fields: Fields, key: str) -> str:
        value = fields.raw(key)
        if isinstance(value, bool) or not isinstance(value, str | int):
            raise fields.error(key, f"expected a string, got {value!r}"[:80])
        return str(value)

    def write(self, value: str) -> str:
        return value


@dataclass(frozen=True)
class DockInstance:
    """One charger in the world; in a dock file, the mapping under its name (``docks: {name: {type, pose, ...}}``),
    where ``pose`` must be given."""

    name: str
    type: str = setting()
    frame: str = setting("map")
    # the docked robot's base_link in ``frame``; None: found by the camera alone
    pose: Pose2D | None = setting(None, required=True, codec=_PoseList())
    id: str = setting("", codec=_Text())
    layout: str = setting("")  # its own dock layout YAML; empty: its type's


def staging_pose(pose: Pose2D, dock_type: DockType) -> Pose2D:
    """The staging pose of a dock at ``pose``, as ``SimpleChargingDock::getStagingPose`` works it out."""
    return Pose2D(
        pose.x + math.cos(pose.theta) * dock_type.staging_x_offset,
        pose.y + math.sin(pose.theta) * dock_type.staging_x_offset,
        wrap_angle(pose.theta + dock_type.staging_yaw_offset),
    )


def pose_distance(a: Pose2D, b: Pose2D) -> float:
    """Nav2's ``utils::l2Norm``: the distance between two poses with their heading difference (rad) as a third axis,
    which ``dock_prestaging_tolerance`` bounds."""
    return math.sqrt((a.x - b.x) ** 2 + (a.y - b.y) ** 2 + wrap_angle(b.theta - a.theta) ** 2)


def load_dock_file(path: str | os.PathLike[str]) -> dict[str, DockInstance]:
    """The dock instances of a dock database file (upstream's format).

    Raises:
        ConfigError: the file cannot be read, has no ``docks``, or an entry lacks ``type`` or a 3-number ``pose``.
    """
    source = f"dock database {Path(path).name}"
    top = Fields(load_yaml(path, "dock database"), source)
    if not top.has("docks"):
        raise ConfigError(f"{source}: does not contain 'docks'")
    docks = top.child("docks")
    return {str(name): from_fields(DockInstance, docks.child(str(name)), name=str(name)) for name in docks.data}


@dataclass
class DockDatabase:
    """Dock types and instances; looks a goal's dock up as ``DockDatabase::findDock``/``findDockPlugin`` do."""

    types: dict[str, DockType]
    docks: dict[str, DockInstance] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.types:
            raise ConfigError("dock database: no dock types (dock_plugins must name at least one)")
        for t in self.types.values():
            if t.plugin != PLUGIN:
                raise ConfigError(
                    f"dock type '{t.name}': plugin '{t.plugin}' is not monodock's; monodock serves its own docks "
                    f"only (plugin: '{PLUGIN}')"
                )
        self.check(self.docks)

    def check(self, docks: dict[str, DockInstance]) -> None:
        """Refuse instances of a type that does not exist (upstream finds out only when a goal names them).

        Raises:
            ConfigError: naming the dock and its type.
        """
        for dock in docks.values():
            if self.find_type(dock.type) is None:
                known = ", ".join(sorted(self.types))
                raise ConfigError(f"dock '{dock.name}': type '{dock.type}' is not among the dock types ({known})")

    def replace_docks(self, docks: dict[str, DockInstance]) -> None:
        """The instances replaced (``reload_database``), after the same checks."""
        self.check(docks)
        self.docks = dict(docks)

    def find_type(self, name: str) -> DockType | None:
        """A dock type by name; an empty name is the only type when there is one (``findDockPlugin``)."""
        if not name and len(self.types) == 1:
            return next(iter(self.types.values()))
        return self.types.get(name)

    def find_dock(self, dock_id: str) -> tuple[DockInstance, DockType]:
        """A goal's dock by its id (``findDock``).

        Raises:
            DockNotInDB: no dock of that id.
            DockNotValid: its type has no plugin.
        """
        dock = self.docks.get(dock_id)
        if dock is None:
            known = ", ".join(sorted(self.docks)) or "none"
            raise DockNotInDB(f"Dock ID requested is not in database! ('{dock_id}'; the database holds: {known})")
        dock_type = self.find_type(dock.type)
        if dock_type is None:
            raise DockNotValid(f"Dock requested has no valid plugin! ('{dock_id}' is of type '{dock.type}')")
        return dock, dock_type

    def pose_goal(self, frame: str, pose: Pose2D, dock_type: str) -> tuple[DockInstance, DockType]:
        """The dock of a goal that gives a ``dock_pose`` (``generateGoalDock``).

        Raises:
            DockNotValid: no dock type of that name (or an empty one with several types).
        """
        found = self.find_type(dock_type)
        if found is None:
            known = ", ".join(sorted(self.types))
            raise DockNotValid(f"Dock requested has no valid plugin! (dock_type '{dock_type}'; the types: {known})")
        return DockInstance(name="", type=found.name, frame=frame, pose=pose), found
