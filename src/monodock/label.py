"""LiDAR labels for the regression (papers §4.1, Fig. 7–9): depth and angle of the dock from the scan points
that fall across marker 2 in the image.

The papers project LiDAR points into the image and keep those inside marker 2's columns. Done in 3-D it is
exact for any camera tilt and lens: the plane through the camera centre and marker 2's left edge contains
that edge's extension down to the scan plane, so a scan point lies "across" the marker when it is between
the planes of the left and right edges. The point nearest the plane through the marker's centre gives the
depth label; the angle comes from the points across the marker, both the papers' way (leftmost and
rightmost point) and by a total-least-squares line through all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock import transforms
from monodock.camera import CameraModel
from monodock.features import lens_centre
from monodock.robot import RobotConfig
from monodock.scan import LaserScan

__all__ = [
    "LABEL_COLUMNS",
    "LidarLabel",
    "label_frame",
    "points_across_marker",
    "project_to_image",
    "scan_in_base",
]

LABEL_COLUMNS = (
    "label_valid",
    "label_reason",
    "label_x_m",
    "label_yaw_deg",
    "label_yaw_endpoints_deg",
    "label_y_m",
    "label_x_line_m",
    "label_points",
    "label_span_m",
    "label_line_rms_m",
    "label_centre_offset_m",
)

MIN_POINTS = 3


@dataclass(frozen=True)
class LidarLabel:
    """The teacher's answer for one frame, in base_link, and how much to trust it.

    Attributes:
        x: depth label, the papers' way: base_link x of the scan point nearest marker 2's centre plane, m.
        yaw: angle label, line fit: the dock's yaw from a total-least-squares line through the points, rad.
        yaw_endpoints: angle label, the papers' way: from the leftmost and rightmost point, rad.
        y: lateral label: where the fitted line crosses marker 2's centre plane, m.
        x_line: depth at that crossing, m (the line's estimate of x, less noisy than one point).
        points: scan points across marker 2.
        span: distance between the outermost points, m.
        line_rms: RMS distance of the points from the fitted line, m.
        centre_offset: distance of the depth point from marker 2's centre plane, m.
        reason: why the label is invalid; empty when valid.
    """

    x: float = math.nan
    yaw: float = math.nan
    yaw_endpoints: float = math.nan
    y: float = math.nan
    x_line: float = math.nan
    points: int = 0
    span: float = math.nan
    line_rms: float = math.nan
    centre_offset: float = math.nan
    reason: str = ""

    @property
    def valid(self) -> bool:
        return not self.reason

    def row(self) -> dict[str, object]:
        """The label's dataset columns (LABEL_COLUMNS), angles in degrees."""
        return {
            "label_valid": self.valid,
            "label_reason": self.reason,
            "label_x_m": self.x,
            "label_yaw_deg": math.degrees(self.yaw),
            "label_yaw_endpoints_deg": math.degrees(self.yaw_endpoints),
            "label_y_m": self.y,
            "label_x_line_m": self.x_line,
            "label_points": self.points,
            "label_span_m": self.span,
            "label_line_rms_m": self.line_rms,
            "label_centre_offset_m": self.centre_offset,
        }


def _ray(camera: CameraModel, pixels: NDArray[np.float64], base_T_optical: NDArray[np.float64]) -> NDArray[np.float64]:
    """Directions in base_link of the rays through pixels (through the lens), shape (N, 3)."""
    n = camera.normalize(pixels)
    d = np.column_stack([n, np.ones(len(n))])
    return np.asarray(d @ base_T_optical[:3, :3].T, dtype=np.float64)


def _plane_normal(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    n = np.cross(a, b)
    return np.asarray(n / np.linalg.norm(n), dtype=np.float64)


def _yaw_of_face(direction: NDArray[np.float64]) -> float:
    """The dock's yaw from a direction along the face that points to the robot's left (the dock's +y)."""
    return float(math.atan2(direction[1], direction[0]) - math.pi / 2)


@dataclass(frozen=True)
class _MarkerPlanes:
    """The planes through the camera centre and marker 2's left edge, right edge and centre, in base_link."""

    centre: NDArray[np.float64]
    n_left: NDArray[np.float64]
    n_right: NDArray[np.float64]
    n_mid: NDArray[np.float64]
    forward: NDArray[np.float64]

    def across(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which points (N, 3) lie between the edge planes, in front of the camera."""
        rel = points - self.centre
        return np.asarray((rel @ self.n_left > 0) & (rel @ self.n_right > 0) & (rel @ self.forward > 0))


def _marker_planes(corners_m2: NDArray[np.float64], camera: CameraModel, robot: RobotConfig) -> _MarkerPlanes:
    base_T_optical = robot.base_T_optical()
    c = np.asarray(corners_m2, dtype=np.float64).reshape(4, 2)
    rays = _ray(camera, np.vstack([c, lens_centre(c, camera)[None, :]]), base_T_optical)
    tl, tr, br, bl, mid = rays
    # Normals oriented so that "inside the marker" is positive for both edge planes.
    n_left = _plane_normal(bl, tl)
    n_right = _plane_normal(tr, br)
    if np.dot(n_left, mid) < 0:
        n_left = -n_left
    if np.dot(n_right, mid) < 0:
        n_right = -n_right
    # The centre plane holds the centre ray and the edges' common direction (vertical on an upright dock).
    n_mid = _plane_normal(mid, np.cross(n_left, n_right))
    return _MarkerPlanes(base_T_optical[:3, 3], n_left, n_right, n_mid, mid)


def scan_in_base(scan: LaserScan, robot: RobotConfig) -> NDArray[np.float64]:
    """The scan's valid returns as points (N, 3) in base_link."""
    pts2 = scan.points()
    return transforms.apply(robot.base_T_laser(), np.column_stack([pts2, np.zeros(len(pts2))]))


def points_across_marker(
    corners_m2: NDArray[np.float64], points: NDArray[np.float64], camera: CameraModel, robot: RobotConfig
) -> NDArray[np.bool_]:
    """Which base_link points (N, 3) fall across marker 2 as the camera sees it (papers Fig. 9)."""
    return _marker_planes(corners_m2, camera, robot).across(points)


def project_to_image(points: NDArray[np.float64], camera: CameraModel, robot: RobotConfig) -> NDArray[np.float64]:
    """Pixels (N, 2) of base_link points through the lens (papers Eq. 1, Fig. 8c); NaN outside the camera's field."""
    p = transforms.apply(transforms.invert(robot.base_T_optical()), points)
    px = camera.project(p) if len(p) else np.zeros((0, 2))
    px[~camera.in_view_field(p)] = np.nan
    return px


def label_frame(
    corners_m2: NDArray[np.float64],
    scan: LaserScan,
    camera: CameraModel,
    robot: RobotConfig,
) -> LidarLabel:
    """The LiDAR label of one frame from marker 2's corners (pixels, ArUco order) and the paired scan.

    Args:
        corners_m2: marker 2's detected corners TL, TR, BR, BL, shape (4, 2), pixels through the lens.
        scan: the LiDAR scan paired with the image.
        camera: the camera calibration (intrinsics and distortion).
        robot: the mounts: base_link → camera optical frame and base_link → laser.

    Returns:
        The label; invalid (with a reason) when fewer than MIN_POINTS returns fall across the marker.
    """
    planes = _marker_planes(corners_m2, camera, robot)
    centre, n_left, n_mid = planes.centre, planes.n_left, planes.n_mid
    pts = scan_in_base(scan, robot)
    if len(pts) == 0:
        return LidarLabel(reason="scan has no valid returns")
    p = pts[planes.across(pts)]
    if len(p) < MIN_POINTS:
        return LidarLabel(points=len(p), reason=f"too few LiDAR points across marker 2 ({len(p)}, need {MIN_POINTS})")

    offset = (p - centre) @ n_mid
    nearest = int(np.argmin(np.abs(offset)))
    x_point = float(p[nearest, 0])

    # The papers' angle: the outermost points along the face (ordered by their position between the planes).
    side = (p - centre) @ n_left
    left_pt, right_pt = p[int(np.argmin(side))], p[int(np.argmax(side))]
    yaw_ends = _yaw_of_face((left_pt - right_pt)[:2])

    # Total least squares: range noise is radial, not along x or y, so neither ordinary regression is right.
    xy = p[:, :2]
    mean = xy.mean(axis=0)
    _, s, vt = np.linalg.svd(xy - mean, full_matrices=False)
    direction = vt[0] if np.dot(vt[0], left_pt[:2] - right_pt[:2]) > 0 else -vt[0]
    rms = float(s[1] / math.sqrt(len(xy))) if len(s) > 1 else 0.0
    yaw_line = _yaw_of_face(direction)

    # Lateral label: the fitted face line crossing marker 2's centre plane (restricted to the scan plane).
    a = np.array([n_mid[0], n_mid[1]])
    denom = float(a @ direction)
    y_line = x_line = math.nan
    if abs(denom) > 1e-9:
        t = float(a @ (centre[:2] - mean) + n_mid[2] * (centre[2] - float(p[:, 2].mean()))) / denom
        hit = mean + t * direction
        x_line, y_line = float(hit[0]), float(hit[1])
    return LidarLabel(
        x=x_point,
        yaw=yaw_line,
        yaw_endpoints=yaw_ends,
        y=y_line,
        x_line=x_line,
        points=len(p),
        span=float(np.linalg.norm(left_pt[:2] - right_pt[:2])),
        line_rms=rms,
        centre_offset=float(abs(offset[nearest])),
    )
