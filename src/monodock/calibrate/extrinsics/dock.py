"""Camera-LiDAR extrinsics from dock views: point-to-plane on the charger face (x, y, yaw of the LiDAR)."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import InputError
from monodock.estimation.pnp import estimate_board
from monodock.perception.detect import MarkerDetector
from monodock.recording import open_recording, pair_nearest

if TYPE_CHECKING:
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.scan import LaserScan
from monodock.calibrate.extrinsics.result import (
    MAX_LINE_RMS_M,
    PAIRING_TOLERANCE_S,
    ExtrinsicsResult,
    covariance,
    line_spread,
)

# Views for the dock method: the LiDAR face segment needs this many points, this straight (RMS, metres).
MIN_FACE_POINTS = 8
# Scan points this far from the camera's face plane (under the current mount) are not on the face.
FACE_GATE_M = (0.12, 0.05, 0.03)


# --- (b) dock: point-to-plane on the charger face ----------------------------------------------------


@dataclass(frozen=True)
class DockView:
    """One view for the dock method: the charger face the camera sees, and the paired scan's points.

    Attributes:
        name: the frame's name (index in the recording).
        base_T_dock: the board PnP's dock pose in base_link (under the known camera mount).
        points_laser: the scan's valid returns in the laser frame, shape (N, 2).
        reprojection_px: the board PnP's RMS reprojection error.
    """

    name: str
    base_T_dock: NDArray[np.float64]
    points_laser: NDArray[np.float64]
    reprojection_px: float = math.nan


def _mount_with(prior: Mount, x: float, y: float, yaw: float) -> Mount:
    return dataclasses.replace(prior, x=x, y=y, yaw=yaw)


def face_points(view: DockView, base_T_laser: NDArray[np.float64], half_width: float, gate: float) -> NDArray[np.bool_]:
    """Which of the view's scan points lie on the charger face: near the camera's face plane, within its width,
    and on one straight line (a RANSAC-free robust fit: the TLS line of the gated points, trimmed twice)."""
    pts = view.points_laser
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    p_base = transforms.apply(base_T_laser, np.column_stack([pts, np.zeros(len(pts))]))
    p_dock = transforms.apply(transforms.invert(view.base_T_dock), p_base)
    keep = (np.abs(p_dock[:, 0]) < gate) & (np.abs(p_dock[:, 1]) < half_width)
    for trim in (0.04, 0.025):
        if keep.sum() < MIN_FACE_POINTS:
            break
        _, mean, direction = line_spread(pts[keep])
        normal = np.array([-direction[1], direction[0]])
        keep &= np.abs((pts - mean) @ normal) < trim
    return np.asarray(keep, dtype=bool)


def _solve_xy_yaw(
    views: Sequence[DockView],
    selected: Sequence[NDArray[np.bool_]],
    prior: Mount,
    start: Mount,
) -> tuple[Mount, NDArray[np.float64], list[NDArray[np.float64]]]:
    """Gauss-Newton on (x, y, yaw) with Huber weights; returns the mount, the Jacobian and per-view residuals."""
    fixed = transforms.rotation_from_rpy(prior.roll, prior.pitch, 0.0)
    z = prior.z
    qs, normals, offsets, owners = [], [], [], []
    for k, (v, sel) in enumerate(zip(views, selected, strict=True)):
        p = v.points_laser[sel]
        if len(p) == 0:
            continue
        q = np.column_stack([p, np.zeros(len(p))]) @ fixed.T
        n = v.base_T_dock[:3, 0]
        qs.append(q)
        normals.append(np.tile(n, (len(p), 1)))
        offsets.append(np.full(len(p), float(n @ v.base_T_dock[:3, 3])))
        owners.append(np.full(len(p), k))
    Q, N, c, own = np.vstack(qs), np.vstack(normals), np.concatenate(offsets), np.concatenate(owners)
    theta = np.array([start.x, start.y, start.yaw], dtype=np.float64)

    def residual_and_jacobian(th: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        cy, sy = math.cos(th[2]), math.sin(th[2])
        Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        dRz = np.array([[-sy, -cy, 0.0], [cy, -sy, 0.0], [0.0, 0.0, 0.0]])
        p = Q @ Rz.T + np.array([th[0], th[1], z])
        r = np.einsum("ij,ij->i", N, p) - c
        J = np.column_stack([N[:, 0], N[:, 1], np.einsum("ij,ij->i", N, Q @ dRz.T)])
        return r, J

    for _ in range(30):
        r, J = residual_and_jacobian(theta)
        scale = max(1.4826 * float(np.median(np.abs(r))), 0.005)
        a = np.abs(r) / (1.345 * scale)
        w = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
        Jw = J * w[:, None]
        step = np.linalg.lstsq(Jw.T @ J, -(Jw.T @ r), rcond=None)[0]
        theta = theta + step
        if abs(step[0]) < 1e-7 and abs(step[1]) < 1e-7 and abs(step[2]) < 1e-8:
            break
    r, J = residual_and_jacobian(theta)
    per_view = [r[own == k] for k in range(len(views))]
    return _mount_with(prior, float(theta[0]), float(theta[1]), float(theta[2])), J, per_view


def extrinsics_from_dock_views(
    views: Sequence[DockView],
    base_T_optical: NDArray[np.float64],
    prior: Mount,
    *,
    half_width: float,
    max_view_rms: float = MAX_LINE_RMS_M,
) -> ExtrinsicsResult:
    """The LiDAR's x, y and yaw that put its charger-face points on the camera's face planes (point-to-plane).

    Args:
        views: the views (board PnP dock pose and the paired scan's points).
        base_T_optical: the camera optical frame in base_link (the known camera mount).
        prior: the starting guess; its z, roll and pitch are kept (the vertical face cannot fix them).
        half_width: half the usable face width, metres (scan points farther from the dock's centre line are
            not used).
        max_view_rms: views whose face points fit their plane worse than this (RMS, metres) are dropped.

    Returns:
        The calibration; the residual is the RMS point-to-plane distance in metres, per view in ``view_rms``.

    Raises:
        InputError: fewer than 3 usable views, or views whose face normals do not vary enough.
    """
    if len(views) < 3:
        raise InputError(f"{len(views)} usable views is too few: need at least 3 (10 or more spread in yaw)")
    mount = prior
    selected: list[NDArray[np.bool_]] = []
    used = list(views)
    J = np.zeros((0, 3))
    per_view: list[NDArray[np.float64]] = []
    dropped_line = dropped_fit = 0
    for gate in FACE_GATE_M:
        selected = [face_points(v, mount.matrix(), half_width, gate) for v in used]
        good = [i for i, s in enumerate(selected) if s.sum() >= MIN_FACE_POINTS]
        good = [i for i in good if line_spread(used[i].points_laser[selected[i]])[0] <= MAX_LINE_RMS_M]
        dropped_line += len(used) - len(good)
        used = [used[i] for i in good]
        selected = [selected[i] for i in good]
        if len(used) < 3:
            raise InputError(
                f"only {len(used)} views have a straight LiDAR segment on the charger face; need at least 3 "
                "(check the robot file's laser mount is roughly right and the LiDAR sees the charger)"
            )
        mount, J, per_view = _solve_xy_yaw(used, selected, prior, mount)
    rms_views = np.array([math.sqrt(float(np.mean(r**2))) for r in per_view])
    bad = rms_views > max(3.0 * float(np.median(rms_views)), max_view_rms)
    if bad.any() and (~bad).sum() >= 3:
        dropped_fit = int(bad.sum())
        used = [v for v, b in zip(used, bad, strict=True) if not b]
        selected = [s for s, b in zip(selected, bad, strict=True) if not b]
        mount, J, per_view = _solve_xy_yaw(used, selected, prior, mount)
        rms_views = np.array([math.sqrt(float(np.mean(r**2))) for r in per_view])
    normals = np.array([v.base_T_dock[:2, 0] for v in used])
    yaws = np.degrees(np.arctan2(normals[:, 1], normals[:, 0]))
    spread = float(yaws.max() - yaws.min())
    if spread < 5.0:
        raise InputError(
            f"the views' charger faces differ by only {spread:.1f} deg in yaw: record views at several "
            "angles to the charger (at least 20 deg apart) so that x, y and yaw are all observed"
        )
    r_all = np.concatenate(per_view)
    rms = math.sqrt(float(np.mean(r_all**2)))
    std, cond = covariance(J, rms, ("x", "y", "yaw"))
    notes = [
        "z, roll and pitch are kept from the robot file: the charger face is vertical, so point-to-plane "
        "constraints fix only x, y and yaw",
        f"{len(used)} views spanning {spread:.0f} deg of face yaw",
    ]
    if dropped_line:
        notes.append(f"{dropped_line} views dropped: too few or not straight LiDAR points on the face")
    if dropped_fit:
        notes.append(f"{dropped_fit} views dropped: they fit their face plane much worse than the others")
    if cond > 1e4:
        notes.append(f"the problem is poorly conditioned ({cond:.0f}): spread the views more in yaw and position")
    optical_T_laser = transforms.invert(base_T_optical) @ mount.matrix()
    return ExtrinsicsResult(
        method="dock",
        laser_mount=mount,
        optical_T_laser=optical_T_laser,
        prior_mount=prior,
        rms=rms,
        residual_unit="m",
        count=len(used),
        points=int(sum(int(s.sum()) for s in selected)),
        view_rms=tuple(float(v) for v in rms_views),
        std=std,
        condition=cond,
        fixed=("z", "roll", "pitch"),
        notes=tuple(notes),
    )


def face_half_width(layout: DockLayout) -> float:
    """Half the face width that certainly holds charger: the markers' extent, a quarter marker beyond."""
    return max(abs(m.y) for m in layout.markers) + 0.25 * layout.marker_size


@dataclass(frozen=True)
class RecordingViews:
    """The dock method's views of a recording, and what is needed to draw the overlay of one of them."""

    views: list[DockView]
    camera: CameraModel
    frames_seen: int
    rejected: dict[str, int]
    overlay_frame: tuple[NDArray[np.uint8], LaserScan, Any] | None
    warnings: list[str]


def dock_views_from_recording(
    path: str | os.PathLike[str],
    layout: DockLayout,
    robot: RobotConfig,
    *,
    camera: CameraModel | None = None,
    tolerance_s: float = PAIRING_TOLERANCE_S,
    min_markers: int = 3,
    max_reprojection_px: float = 1.5,
) -> RecordingViews:
    """Board PnP views paired with their nearest scan (within ``tolerance_s``) from a recording.

    Views whose board PnP fails, sees fewer than ``min_markers`` markers or fits its corners worse than
    ``max_reprojection_px`` are rejected (counted by reason).
    """

    rejected: dict[str, int] = {}

    def reject(reason: str) -> None:
        rejected[reason] = rejected.get(reason, 0) + 1

    with open_recording(path) as rec:
        if rec.scan_topic is None:
            raise InputError(f"{path}: no sensor_msgs/LaserScan topic; the LiDAR calibration needs its scans")
        cam = camera or rec.camera()
        if cam is None:
            raise InputError(f"{path}: no sensor_msgs/CameraInfo topic; give the calibration with --camera")
        scans = rec.scans()
        stamps = np.array([s.stamp for s in scans], dtype=np.float64)
        detector = MarkerDetector(layout)
        views: list[DockView] = []
        overlay = None
        seen = 0
        for f in rec.images():
            seen += 1
            if f.image is None:
                reject("image does not decode")
                continue
            if (f.image.shape[1], f.image.shape[0]) != cam.size:
                raise InputError(
                    f"{path}: images are {f.image.shape[1]}x{f.image.shape[0]}, the camera calibration is "
                    f"{cam.width}x{cam.height}"
                )
            j = int(pair_nearest([f.stamp], stamps, tolerance_s)[0])
            if j < 0:
                reject(f"no scan within {tolerance_s * 1000:.0f} ms")
                continue
            det = detector.detect(f.image)
            if len(det.roles_seen) < min_markers:
                reject(f"fewer than {min_markers} markers seen")
                continue
            est = estimate_board(det, cam, layout, robot)
            if est.base_T_dock is None:
                reject("board PnP failed")
                continue
            if not est.reprojection_px <= max_reprojection_px:
                reject(f"board PnP reprojection above {max_reprojection_px} px")
                continue
            views.append(DockView(f.name, est.base_T_dock, scans[j].points(), est.reprojection_px))
            if overlay is None or len(views) == 1:
                overlay = (f.image, scans[j], det)
        warnings = list(rec.warnings)
    return RecordingViews(views, cam, seen, rejected, overlay, warnings)


def extrinsics_from_recording(
    path: str | os.PathLike[str],
    layout: DockLayout,
    robot: RobotConfig,
    *,
    camera: CameraModel | None = None,
    tolerance_s: float = PAIRING_TOLERANCE_S,
) -> tuple[ExtrinsicsResult, RecordingViews]:
    """The dock method on a recording: ``robot``'s camera mount is known, its laser mount is the prior."""
    rv = dock_views_from_recording(path, layout, robot, camera=camera, tolerance_s=tolerance_s)
    if len(rv.views) < 3:
        why = ", ".join(f"{n} {r}" for r, n in rv.rejected.items()) or "no images"
        raise InputError(f"{path}: only {len(rv.views)} of {rv.frames_seen} frames are usable views ({why})")
    result = extrinsics_from_dock_views(
        rv.views, robot.base_T_optical(), robot.laser_mount, half_width=face_half_width(layout)
    )
    if rv.rejected:
        why = ", ".join(f"{n} {r}" for r, n in rv.rejected.items())
        result = dataclasses.replace(result, notes=(*result.notes, f"frames rejected: {why}"))
    return result, rv
