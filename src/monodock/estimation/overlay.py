"""Pictures a person would rather look at than read: detections, truth and the estimated dock axes.

OpenCV alone, so the robot side draws them too (the detector's debug image); the reports and the command line use
the same pictures.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.estimator import Estimator, FrameEstimates
from monodock.estimation.pnp import PoseEstimate
from monodock.perception.detect import Detection

__all__ = ["draw_overlay", "estimates_png"]

_GREEN, _RED, _BLUE = (60, 200, 60), (40, 40, 230), (230, 120, 30)
_YELLOW, _WHITE, _MAGENTA = (0, 220, 240), (255, 255, 255), (220, 40, 220)


def _pt(p: NDArray[np.float64], scale: float) -> tuple[int, int]:
    # cv2 draws on integer pixel centres; shift=4 keeps 1/16 px of the sub-pixel position.
    return int(round((p[0] + 0.5) * scale * 16 - 8)), int(round((p[1] + 0.5) * scale * 16 - 8))


def _draw_lidar(
    out: np.ndarray,
    shape: tuple[int, ...],
    lidar_px: NDArray[np.float64],
    lidar_selected: NDArray[np.bool_] | None,
    scale: float,
) -> None:
    """The LiDAR points inside the (unscaled) image of ``shape``: blue dots, larger magenta ones where selected."""
    chosen = lidar_selected if lidar_selected is not None else np.zeros(len(lidar_px), bool)
    h, w = shape
    for p, sel in zip(lidar_px, chosen, strict=True):
        if np.all(np.isfinite(p)) and -0.5 <= p[0] < w - 0.5 and -0.5 <= p[1] < h - 0.5:
            cv2.circle(out, _pt(p, scale), (3 if sel else 2) * 16, _MAGENTA if sel else _BLUE, -1, cv2.LINE_AA, 4)


def _draw_truth(out: np.ndarray, truth_corners: Mapping[str, NDArray[np.float64]], scale: float) -> None:
    """The true corners as red crosses, skipping non-finite ones."""
    for c in truth_corners.values():
        for p in c:
            if np.all(np.isfinite(p)):
                cv2.drawMarker(out, _pt(p, scale), _RED, cv2.MARKER_CROSS, 9 * 16, 1, cv2.LINE_AA)


def _draw_dock_axes(
    out: np.ndarray,
    base_T_dock: NDArray[np.float64],
    layout: DockLayout,
    camera: CameraModel,
    robot: RobotConfig,
    scale: float,
) -> None:
    """The estimated dock frame's axes as arrows (x red, y green, z blue), when all are in front of the camera."""
    optical_T_dock = transforms.invert(robot.base_T_optical()) @ base_T_dock
    s = layout.marker_size * 1.5
    pts3 = transforms.apply(optical_T_dock, np.array([[0, 0, 0], [s, 0, 0], [0, s, 0], [0, 0, s]], float))
    if np.all(pts3[:, 2] > 0.01):
        px = camera.project(pts3)
        o = _pt(px[0], scale)
        for p, colour in zip(px[1:], (_RED, _GREEN, _BLUE), strict=True):
            cv2.arrowedLine(out, o, _pt(p, scale), colour, 2, cv2.LINE_AA, shift=4, tipLength=0.15)


def _caption_lines(detection: Detection, estimate: PoseEstimate | None) -> list[str]:
    """The caption's text: the estimate (or why there is none) and the ids the detection ignored."""
    lines = []
    if estimate is not None:
        if estimate.pose is not None:
            p = estimate.pose
            lines.append(f"{estimate.method}: x {p.x:.3f} m  y {p.y:+.3f} m  yaw {p.yaw_deg:+.2f} deg")
            if estimate.covariance is not None and np.all(np.isfinite(np.diag(estimate.covariance))):
                sx, sy, syaw = np.sqrt(np.maximum(np.diag(estimate.covariance), 0.0))
                lines.append(f"sigma: x {sx * 1e3:.1f} mm  y {sy * 1e3:.1f} mm  yaw {np.degrees(syaw):.2f} deg")
        else:
            lines.append(f"{estimate.method}: no estimate ({estimate.reason})")
    if detection.ignored_ids:
        lines.append("ignored ids: " + ", ".join(str(i) for i in detection.ignored_ids))
    return lines


def _draw_caption(out: np.ndarray, lines: list[str]) -> None:
    """``lines`` in white at the bottom of ``out``, over a darkened strip."""
    if lines:
        top = out.shape[0] - 12 - 22 * len(lines)
        out[top:, :] = (out[top:, :] * 0.3).astype(np.uint8)
    for i, text in enumerate(lines):
        y = out.shape[0] - 12 - 22 * (len(lines) - 1 - i)
        cv2.putText(out, text, (10, y), cv2.FONT_HERSHEY_SIMPLEX, 0.6, _WHITE, 1, cv2.LINE_AA)


def draw_overlay(
    image: NDArray[np.uint8],
    detection: Detection,
    layout: DockLayout,
    camera: CameraModel | None = None,
    robot: RobotConfig | None = None,
    estimate: PoseEstimate | None = None,
    truth_corners: Mapping[str, NDArray[np.float64]] | None = None,
    scale: float | None = None,
    lidar_px: NDArray[np.float64] | None = None,
    lidar_selected: NDArray[np.bool_] | None = None,
) -> NDArray[np.uint8]:
    """A BGR picture: detected corners (green, corner 0 filled), marker ids, true corners (red crosses),
    and the dock axes of the estimate (x red into the charger, y green left, z blue up), about 1280 px wide.
    ``lidar_px`` adds the LiDAR points projected into the image (the papers' Fig. 8c): blue, and magenta for
    those ``lidar_selected`` (across marker 2, the label's points).
    """
    if scale is None:  # about 1280 px wide: small cameras scaled up to see sub-pixel corners, large ones kept
        scale = max(1.0, min(2.0, 1280.0 / image.shape[1]))
    base = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    out = cv2.resize(base, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    for role, obs in detection.observations.items():
        pts = np.array([_pt(c, scale) for c in obs.corners], np.int32)
        cv2.polylines(out, [pts], True, _GREEN, 1, cv2.LINE_AA, shift=4)
        cv2.circle(out, tuple(pts[0]), 4 * 16, _GREEN, -1, cv2.LINE_AA, shift=4)
        x, y = (obs.corners.min(axis=0) * scale).astype(int)
        label = f"{layout.marker(role).label} id {obs.marker_id}"
        cv2.putText(out, label, (x, max(12, y - 6)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _YELLOW, 1, cv2.LINE_AA)
    if lidar_px is not None:
        _draw_lidar(out, image.shape[:2], lidar_px, lidar_selected, scale)
    if truth_corners:
        _draw_truth(out, truth_corners, scale)
    if estimate is not None and estimate.base_T_dock is not None and camera is not None and robot is not None:
        _draw_dock_axes(out, estimate.base_T_dock, layout, camera, robot, scale)
    _draw_caption(out, _caption_lines(detection, estimate))
    return np.asarray(out, dtype=np.uint8)


def estimates_png(
    image: np.ndarray,
    result: FrameEstimates,
    estimator: Estimator,
    truth_corners: dict[str, np.ndarray] | None = None,
    method: str = "board",
) -> bytes:
    """The overlay of one estimated frame (its detection and ``method``'s estimate), PNG-encoded."""
    assert result.detection is not None
    pic = draw_overlay(
        image,
        result.detection,
        estimator.layout,
        estimator.camera,
        estimator.robot,
        result.estimates.get(method),
        truth_corners,
    )
    ok, buf = cv2.imencode(".png", pic)
    if not ok:
        raise InputError("cannot encode the overlay PNG")
    return bytes(buf.tobytes())
