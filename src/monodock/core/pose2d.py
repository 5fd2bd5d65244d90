"""Poses on the floor, (x, y, heading), for the controller's fast loop: plain floats, no 4x4 matrices."""

from __future__ import annotations

import math
from typing import NamedTuple

from monodock.core.pose import wrap_angle

__all__ = ["Pose2D"]


class Pose2D(NamedTuple):
    """A frame on the floor: position in metres and heading in radians (counter-clockwise from x)."""

    x: float
    y: float
    theta: float

    def compose(self, other: Pose2D) -> Pose2D:
        """self ∘ other: ``other`` given in this frame, expressed in this frame's parent."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2D(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            wrap_angle(self.theta + other.theta),
        )

    def inverse(self) -> Pose2D:
        """The parent's pose seen from this frame."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2D(-c * self.x - s * self.y, s * self.x - c * self.y, wrap_angle(-self.theta))

    def relative_to(self, frame: Pose2D) -> Pose2D:
        """This pose (given in the parent) expressed in ``frame`` (also given in the parent)."""
        return frame.inverse().compose(self)

    def point(self, x: float, y: float) -> tuple[float, float]:
        """A point given in this frame, in the parent."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return self.x + c * x - s * y, self.y + s * x + c * y

    def distance(self, other: Pose2D) -> float:
        return math.hypot(other.x - self.x, other.y - self.y)
