"""Between the sensors: LiDAR returns into base_link, base_link points into the camera image, and how close the
robot can come to the dock before marker 2 leaves the image (the blind gap)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.core.scan import LaserScan
from monodock.errors import ConfigError

__all__ = ["blind_gap", "project_to_image", "scan_in_base"]


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


def blind_gap(camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> float:
    """The front edge's distance from the face below which marker 2 no longer fits in the image (robot square on)."""

    def fits(gap: float) -> bool:
        base_T_dock = DockPose(gap + robot.front_offset, 0.0, 0.0).matrix()
        optical_T_dock = transforms.invert(robot.base_T_optical()) @ base_T_dock
        p = transforms.apply(optical_T_dock, layout.corners_in_dock("center"))
        if np.any(p[:, 2] <= 0) or not np.all(camera.in_view_field(p)):
            return False
        px = camera.project(p)
        return bool(np.all((px >= 0) & (px <= np.array(camera.size) - 1)))

    lo, hi = 0.0, 3.0
    if fits(lo):
        return 0.0
    if not fits(hi):
        raise ConfigError("marker 2 never fits in the image in front of the dock; check the camera and layout")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi
