"""The docking node's dock model (Nav2's ``opennav_docking::SimpleChargingDock``): monodock's ArUco charger whose
charging is a dock type's battery signal, and the already-docked test of a DockRobot goal.

``DockNode.dock_model`` makes a ``Dock`` for a dock type; assign another ``DockModel`` to plug in another dock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from monodock.core.pose2d import Pose2D
from monodock.dock.config import DockingConfig
from monodock.dock.database import DockType
from monodock.dock.extensions import ArucoChargingDock, Dock
from monodock.dock.interface import RobotInterface
from monodock.ros.ros2_robot import ChargingSignal, Ros2Robot

__all__ = ["DockModel", "SimpleChargingDock", "already_docked", "simple_charging_dock"]

DockModel = Callable[[DockType, DockingConfig, float], Dock]
"""A dock of a dock type, for the docking config and the robot's ``front_offset`` (m)."""


@dataclass(frozen=True)
class SimpleChargingDock(ArucoChargingDock):
    """monodock's charger; charging is the battery's current above the dock type's ``charging_threshold`` (else
    its CHARGING or FULL status; ``use_battery_status`` false: it cannot tell)."""

    signal: ChargingSignal = field(default_factory=ChargingSignal)

    def is_charging(self, robot: RobotInterface) -> bool | None:
        return robot.charging(self.signal) if isinstance(robot, Ros2Robot) else robot.charging()


def simple_charging_dock(dock_type: DockType, config: DockingConfig, front_offset: float) -> Dock:
    """The default ``DockModel``: a ``SimpleChargingDock`` on ``dock_type``'s charging signal."""
    signal = ChargingSignal(dock_type.charging_threshold, dock_type.use_battery_status)
    return SimpleChargingDock(config, front_offset, signal)


def already_docked(dock: Dock, robot: Ros2Robot, docked_at: Pose2D | None, threshold: float) -> bool:
    """Whether the robot stands on ``dock`` (SimpleChargingDock's ``isDocked() || isCharging()``): the dock says
    it charges, the contact switch is closed, or it is within ``threshold`` (m, by odometry) of ``docked_at``, where
    the last docking ended."""
    if dock.is_charging(robot) or robot.contact():
        return True
    if docked_at is None or robot.odom.value is None:
        return False
    here = robot.odometry().pose
    return math.hypot(here.x - docked_at.x, here.y - docked_at.y) < threshold
