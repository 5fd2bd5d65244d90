"""The far approach's geometry: whether the robot stands beyond what the manoeuvre takes on, and the staging point
on the dock's axis it makes for first, a leg at a time (``State.FAR_APPROACH``; ``DockingConfig``'s ``far_*`` and
``staging_distance``).

Pure functions of poses; the mission (``dock.controller``) drives the legs with ``dock.control_law``.
"""

from __future__ import annotations

import math

from monodock.core.pose2d import Pose2D
from monodock.dock.config import DockingConfig

__all__ = ["beyond_manoeuvre", "leg_end", "off_axis", "staging_point"]


def off_axis(robot: Pose2D) -> float:
    """How far the robot (base_link, dock frame) stands off the dock's axis, seen from the face centre (rad, ≥ 0)."""
    return abs(math.atan2(robot.y, -robot.x))


def beyond_manoeuvre(robot: Pose2D, c: DockingConfig) -> bool:
    """Whether the robot (dock frame) stands beyond what the manoeuvre takes on: farther than ``far_distance`` from
    the face centre or more than ``far_bearing_deg`` off the axis; the far approach brings it in first."""
    return math.hypot(robot.x, robot.y) > c.far.far_distance or off_axis(robot) > math.radians(c.far.far_bearing_deg)


def staging_point(dock: Pose2D, c: DockingConfig) -> Pose2D:
    """Where the far approach makes for, in odometry: ``staging_distance`` before the face on the dock's axis
    (``dock``: the dock's pose in odometry), facing the face."""
    return dock.compose(Pose2D(-c.far.staging_distance, 0.0, 0.0))


def leg_end(pose: Pose2D, stage: Pose2D, remaining: float) -> Pose2D:
    """Where the current far leg ends: the staging point, or ``remaining`` metres towards it when it is farther."""
    d = pose.distance(stage)
    if d <= max(remaining, 0.0) or d == 0.0:
        return stage
    k = max(remaining, 0.0) / d
    return Pose2D(pose.x + k * (stage.x - pose.x), pose.y + k * (stage.y - pose.y), stage.theta)
