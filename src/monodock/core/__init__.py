"""The ground everything stands on: frames and poses, transforms, the camera and lens model, the dock layout, the
robot file, LaserScan, files."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.core.atomic import atomic_directory, check_writable
    from monodock.core.camera import CameraModel
    from monodock.core.frame import Frame
    from monodock.core.layout import ROLES, DockLayout
    from monodock.core.pose import DockPose, wrap_angle
    from monodock.core.pose2d import Pose2D
    from monodock.core.robot import Mount, RobotConfig
    from monodock.core.scan import LaserScan

__all__ = [
    "ROLES",
    "CameraModel",
    "DockLayout",
    "DockPose",
    "Frame",
    "LaserScan",
    "Mount",
    "Pose2D",
    "RobotConfig",
    "atomic_directory",
    "check_writable",
    "wrap_angle",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
