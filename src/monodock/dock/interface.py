"""What the docking controller needs from a robot: velocity commands out, odometry and camera frames in.

The simulator (``monodock.sim.diffdrive``) and the ROS 2 adapter (``monodock.ros.dock_node``) implement it; the
controller never learns which one it drives, and never sees the simulator's truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from monodock.core.pose2d import Pose2D

__all__ = ["CameraFrame", "Odometry", "RobotInterface"]


@dataclass(frozen=True)
class Odometry:
    """The wheel-odometry pose of base_link in the odometry frame, and the measured velocities."""

    stamp: float
    pose: Pose2D
    linear: float
    angular: float


@dataclass(frozen=True)
class CameraFrame:
    """One camera image and the time its exposure was taken (not the time it arrived)."""

    stamp: float
    image: NDArray[np.uint8]


class RobotInterface(Protocol):
    """A differential-drive base with a camera, seen from the docking controller."""

    def now(self) -> float:
        """The robot's clock, seconds."""
        ...

    def send_velocity(self, linear: float, angular: float) -> None:
        """Command base_link's forward speed (m/s) and turn rate (rad/s, counter-clockwise positive)."""
        ...

    def odometry(self) -> Odometry:
        """The latest wheel odometry."""
        ...

    def latest_frame(self) -> CameraFrame | None:
        """The newest camera frame that has arrived, or None before the first."""
        ...

    def contact(self) -> bool | None:
        """Whether the charger contacts (or a bumper) report touch; None when the robot cannot tell."""
        ...

    def charging(self) -> bool | None:
        """Whether the charger delivers current (a battery's CHARGING status); None when the robot cannot tell."""
        ...

    def rear_range(self) -> float | None:
        """Distance (m) from the robot's back edge to the nearest obstacle behind it, as a ``sensor_msgs/Range``
        or a LaserScan's rear sector reports it: ``math.inf`` when nothing is in range, None without a rear
        sensor (reversing is then bounded by distance and speed only)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of robot time pass (the simulator steps its physics; a real robot waits)."""
        ...
