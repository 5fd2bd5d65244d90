"""monodock: dock a low-cost robot onto its charger with one camera and three ArUco markers."""

from __future__ import annotations

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout, MarkerSpec
from monodock.core.pose import DockPose
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import ConfigError, InputError, MonodockError

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
