"""DockPose: where the charger is, seen from the robot."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core import transforms

__all__ = ["DockPose", "wrap_angle"]


def wrap_angle(angle: float) -> float:
    """Angle in radians wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class DockPose:
    """Pose of the ``dock`` frame in ``base_link`` on the floor (docs/architecture.md, frames and contracts).

    Attributes:
        x: the papers' depth D in metres: how far ahead of base_link the docking point is.
        y: the papers' lateral offset K in metres; positive when the dock is to the robot's left.
        yaw: the papers' angle theta in radians; 0 when the robot faces the charger square on,
            counter-clockwise positive.
    """

    x: float
    y: float
    yaw: float

    @property
    def yaw_deg(self) -> float:
        """The yaw in degrees, for people."""
        return math.degrees(self.yaw)

    def matrix(self) -> NDArray[np.float64]:
        """base_T_dock as a 4x4 transform."""
        return transforms.planar(self.x, self.y, self.yaw)

    @classmethod
    def from_matrix(cls, base_T_dock: ArrayLike) -> DockPose:
        """The floor-plane part of a full 6-DoF base_T_dock (its roll, pitch and z are dropped)."""
        T = np.asarray(base_T_dock, dtype=np.float64)
        return cls(float(T[0, 3]), float(T[1, 3]), transforms.yaw_of(T))

    @classmethod
    def from_robot_in_dock(cls, x: float, y: float, yaw: float) -> DockPose:
        """DockPose of a robot standing at (x, y, yaw) in the dock frame."""
        return cls.from_matrix(transforms.invert(transforms.planar(x, y, yaw)))

    def robot_in_dock(self) -> tuple[float, float, float]:
        """The robot's (x, y, yaw) in the dock frame: the inverse view of the same pose."""
        T = transforms.invert(self.matrix())
        return float(T[0, 3]), float(T[1, 3]), transforms.yaw_of(T)
