"""The docking mission's extension points, as protocols: the ``Dock`` it docks onto and the ``ControlLaw`` it drives
by, with monodock's own as the defaults (``ArucoChargingDock``, ``PControlLaw``).

The models are Nav2's: ``Dock`` is ``opennav_docking_core::ChargingDock`` (``getStagingPose``, ``getRefinedPose``,
``isDocked``, ``isCharging``), ``ControlLaw`` the ``opennav_docking::Controller`` that turns where the robot is and
where it should be into a velocity command. ``DockingMission(..., dock=..., law=...)`` takes other implementations
without a change to the mission; docs/docking.md lists them under "Extension points".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from monodock.core.pose2d import Pose2D
from monodock.dock import control_law
from monodock.dock.config import DockingConfig
from monodock.dock.far_approach import staging_point
from monodock.dock.interface import Odometry, RobotInterface
from monodock.dock.tracking import DockTrack

__all__ = ["ArucoChargingDock", "ControlLaw", "Dock", "PControlLaw"]


class Dock(Protocol):
    """A charging dock as the mission sees it (Nav2: ``opennav_docking_core::ChargingDock``)."""

    def staging_pose(self, dock: Pose2D) -> Pose2D:
        """Where the robot stands before the final approach (``getStagingPose``), given the dock's pose; both in
        the same frame (the mission's: odometry)."""
        ...

    def refined_pose(self, track: DockTrack) -> Pose2D | None:
        """The dock's pose in odometry as the sensors have refined it so far (``getRefinedPose``); None before any
        frame has given it. The mission finds the dock by it (ACQUIRE), places Point A, the staging point and a
        retry's back-off on it; the per-step errors of Moving₃ are the dock filter's own (``DockTrack``)."""
        ...

    def is_docked(self, pose: Pose2D) -> bool:
        """Whether base_link at ``pose`` (in the dock frame, by the robot's own estimate, standing at the face)
        counts as docked (``isDocked``)."""
        ...

    def is_charging(self, robot: RobotInterface) -> bool | None:
        """Whether the dock charges the robot (``isCharging``); None when it cannot tell."""
        ...


class ControlLaw(Protocol):
    """How the mission turns errors into velocity commands, m/s and rad/s (Nav2: ``opennav_docking::Controller``'s
    ``computeVelocityCommand``, here one method per kind of motion the mission makes)."""

    def limit_command(
        self, v: float, w: float, previous: tuple[float, float], max_speed: float, max_turn: float
    ) -> tuple[float, float]:
        """The command to send for the desired ``(v, w)``, after the speed and acceleration limits."""
        ...

    def is_still(self, odom: Odometry) -> bool:
        """Whether the odometry reads the robot as standing still."""
        ...

    def turn_in_place(self, heading: float, odom: Odometry, max_turn: float) -> tuple[bool, float]:
        """Turning on the spot to ``heading`` (odometry): (there and no longer turning, the turn rate)."""
        ...

    def drive_straight(
        self, target: Pose2D, pose: Pose2D, reverse: bool, max_speed: float
    ) -> tuple[float, float, bool]:
        """Driving straight at ``target`` (odometry): (speed, turn rate, arrived)."""
        ...

    def heading_reference(self, lateral: float, gap: float) -> float:
        """Moving₃'s heading reference (rad, dock frame) for the lateral error and the gap to the face (m)."""
        ...

    def approach_command(self, heading: float, reference: float, gap: float) -> tuple[float, float]:
        """Moving₃'s command for the heading (rad, dock frame), its reference and the gap to the face (m)."""
        ...

    def reverse_stopping_distance(self, speed: float) -> float:
        """The room behind (m) a robot reversing at ``speed`` needs to stop safely."""
        ...


@dataclass(frozen=True)
class ArucoChargingDock:
    """monodock's charger: three ArUco markers on its face, contacts that charge once mated.

    The staging pose is ``staging_distance`` before the face on its axis; the refined pose is the dock filter's
    (``DockTrack``); docked is the final pose inside the tolerances (``tolerance_*``); charging is the robot's
    charging signal (a battery's current or status, or the simulator's contacts).
    """

    config: DockingConfig
    front_offset: float  # base_link to the robot's front edge, m

    def staging_pose(self, dock: Pose2D) -> Pose2D:
        return staging_point(dock, self.config)

    def refined_pose(self, track: DockTrack) -> Pose2D | None:
        return track.mean

    def is_docked(self, pose: Pose2D) -> bool:
        c = self.config
        gap = -pose.x - self.front_offset
        return (
            abs(pose.y) <= c.retry.tolerance_lateral
            and abs(gap) <= c.retry.tolerance_longitudinal
            and abs(pose.theta) <= math.radians(c.retry.tolerance_heading_deg)
        )

    def is_charging(self, robot: RobotInterface) -> bool | None:
        return robot.charging()


@dataclass(frozen=True)
class PControlLaw:
    """The papers' law with monodock's limits: ``dock.control_law``'s functions on the gains of ``config``."""

    config: DockingConfig

    def limit_command(
        self, v: float, w: float, previous: tuple[float, float], max_speed: float, max_turn: float
    ) -> tuple[float, float]:
        return control_law.limit_command(v, w, previous, self.config, max_speed, max_turn)

    def is_still(self, odom: Odometry) -> bool:
        return control_law.is_still(odom, self.config)

    def turn_in_place(self, heading: float, odom: Odometry, max_turn: float) -> tuple[bool, float]:
        return control_law.turn_in_place(heading, odom, self.config, max_turn)

    def drive_straight(
        self, target: Pose2D, pose: Pose2D, reverse: bool, max_speed: float
    ) -> tuple[float, float, bool]:
        return control_law.drive_straight(target, pose, reverse, self.config, max_speed)

    def heading_reference(self, lateral: float, gap: float) -> float:
        return control_law.heading_reference(lateral, gap, self.config)

    def approach_command(self, heading: float, reference: float, gap: float) -> tuple[float, float]:
        return control_law.approach_command(heading, reference, gap, self.config)

    def reverse_stopping_distance(self, speed: float) -> float:
        return control_law.reverse_stopping_distance(speed, self.config)
