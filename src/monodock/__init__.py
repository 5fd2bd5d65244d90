"""monodock: dock a low-cost robot onto its charger with one camera and three ArUco markers."""

from __future__ import annotations

from monodock.camera import CameraModel
from monodock.errors import ConfigError, InputError, MonodockError
from monodock.layout import DockLayout, MarkerSpec
from monodock.pose import DockPose
from monodock.robot import Mount, RobotConfig

__all__ = [
    "CameraModel",
    "ConfigError",
    "DockLayout",
    "DockPose",
    "InputError",
    "MarkerSpec",
    "MonodockError",
    "Mount",
    "RobotConfig",
]
__version__ = "0.1.0"
