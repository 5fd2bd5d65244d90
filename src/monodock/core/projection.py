"""Between the sensors: LiDAR returns into base_link, and base_link points into the camera image."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.robot import RobotConfig
from monodock.core.scan import LaserScan

__all__ = ["project_to_image", "scan_in_base"]


def scan_in_base(scan: LaserScan, robot: RobotConfig) -> NDArray[np.float64]:
    """The scan's valid returns as points (N, 3) in base_link."""
    pts2 = scan.points()
    return transforms.apply(robot.base_T_laser(), np.column_stack([pts2, np.zeros(len(pts2))]))


def project_to_image(points: NDArray[np.float64], camera: CameraModel, robot: RobotConfig) -> NDArray[np.float64]:
    """Pixels (N, 2) of base_link points through the lens (papers Eq. 1, Fig. 8c); NaN outside the camera's field."""
    p = transforms.apply(transforms.invert(robot.base_T_optical()), points)
    px = camera.project(p) if len(p) else np.zeros((0, 2))
    px[~camera.in_view_field(p)] = np.nan
    return px
