"""Camera-LiDAR extrinsic calibration: where the 2D LiDAR sits on the base, given the camera's mount.

Two ways, both ending in the LiDAR mount (``laser`` in ``base_link``) and the laser pose in the camera's
optical frame:

- **pairs** (the papers' way): LiDAR returns (laser frame, the scan plane z = 0) matched by hand to the pixels
  where they hit a target. ``cv2.solvePnP`` on the pairs gives optical_T_laser; base_T_laser follows from the
  known camera mount. The points must not all lie on one line in the scan plane (one flat target seen once
  gives a line): put the target at several positions.
- **dock** (no target but the charger): over many recorded views, the charger face plane that the camera sees
  (3-marker board PnP, under the known camera mount) must contain the straight segment the LiDAR sees on the
  same face; the LiDAR mount that puts the scan's face points on the camera's face planes is found by
  point-to-plane least squares (Zhang & Pless 2004). The face is vertical, so these constraints fix the
  laser's x, y and yaw but hardly its z, roll and pitch: those are kept from the prior (the robot file).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.calibrate.target import DiamondTarget, TargetView
from monodock.core import transforms
from monodock.core.atomic import write_text_atomic
from monodock.core.config import yaml_text
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import InputError
from monodock.estimation.pnp import estimate_board
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.recording import open_recording, pair_nearest

if TYPE_CHECKING:
    from monodock.calibrate.target import DiamondTarget, TargetView
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.scan import LaserScan

__all__ = [
    "MIN_PAIRS",
    "DockView",
    "ExtrinsicsResult",
    "edge_pairs_from_views",
    "extrinsics_from_dock_views",
    "extrinsics_from_pairs",
    "extrinsics_from_recording",
    "extrinsics_from_target_views",
    "face_half_width",
    "face_points",
    "read_pairs_csv",
    "result_yaml",
    "target_views_from_recording",
    "tf_line",
    "write_pairs_csv",
    "write_result_yaml",
]

MIN_PAIRS = 6
# The laser points' spread across their best line, metres (RMS): below it the pairs are one line.
COLLINEAR_SPREAD_M = 0.01
# Views for the dock method: the LiDAR face segment needs this many points, this straight (RMS, metres).
MIN_FACE_POINTS = 8
MAX_LINE_RMS_M = 0.02
# Scan points this far from the camera's face plane (under the current mount) are not on the face.
FACE_GATE_M = (0.12, 0.05, 0.03)
PAIRING_TOLERANCE_S = 0.05


@dataclass(frozen=True)
class ExtrinsicsResult:
    """A calibrated LiDAR mount and how well it fits.

    Attributes:
        method: "pairs" (PnP on LiDAR point / pixel pairs) or "dock" (point-to-plane on the charger face).
        laser_mount: the laser frame's pose in base_link (URDF x y z roll pitch yaw).
        optical_T_laser: the laser frame's pose in the camera's optical frame, 4x4.
        prior_mount: the mount the calibration started from (the robot file's).
        rms: RMS residual: pixels for "pairs", metres point-to-plane for "dock".
        residual_unit: "px" or "m".
        count: pairs used ("pairs") or views used ("dock").
        points: LiDAR points used in total.
        view_rms: per-view RMS point-to-plane distance, metres ("dock"; empty for "pairs").
        std: standard deviation of each solved parameter from the fit's covariance (keys as Mount fields).
        condition: condition number of the normalised normal equations (large: poorly observed).
        fixed: mount fields kept from the prior, not solved.
        notes: what a user should know about the result.
    """

    method: str
    laser_mount: Mount
    optical_T_laser: NDArray[np.float64] = dataclasses.field(repr=False)
    prior_mount: Mount
    rms: float
    residual_unit: str
    count: int
    points: int
    view_rms: tuple[float, ...] = ()
    std: dict[str, float] = dataclasses.field(default_factory=dict)
    condition: float = math.nan
    fixed: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def base_T_laser(self) -> NDArray[np.float64]:
        """The calibrated laser frame in base_link, 4x4."""
        return self.laser_mount.matrix()

    def robot(self, base: RobotConfig) -> RobotConfig:
        """The robot description with the calibrated LiDAR mount."""
        return dataclasses.replace(base, laser_mount=self.laser_mount)

    def summary(self) -> str:
        """A few lines for a person: the mount, the change from the prior, residuals and notes."""
        m, p = self.laser_mount, self.prior_mount
        what = f"{self.count} {'pairs' if self.method == 'pairs' else 'views'}, {self.points} LiDAR points"
        lines = [
            f"laser mount in base_link ({self.method}: {what}):",
            f"  x {m.x:+.4f} m  y {m.y:+.4f} m  z {m.z:+.4f} m  roll {math.degrees(m.roll):+.3f} deg  "
            f"pitch {math.degrees(m.pitch):+.3f} deg  yaw {math.degrees(m.yaw):+.3f} deg",
            f"  change from the prior: dx {(m.x - p.x) * 100:+.2f} cm  dy {(m.y - p.y) * 100:+.2f} cm  "
            f"dz {(m.z - p.z) * 100:+.2f} cm  dyaw {math.degrees(m.yaw - p.yaw):+.3f} deg",
        ]
        unit = "px" if self.residual_unit == "px" else "cm"
        scale = 1.0 if self.residual_unit == "px" else 100.0
        lines.append(f"  residual RMS {self.rms * scale:.3f} {unit}" + _view_stats(self.view_rms))
        if self.std:
            parts = [
                f"{k} {math.degrees(v):.3f} deg" if k in ("roll", "pitch", "yaw") else f"{k} {v * 100:.2f} cm"
                for k, v in self.std.items()
            ]
            lines.append(f"  1-sigma: {', '.join(parts)}; condition {self.condition:.1f}")
        lines.append(f"  tf base_link -> laser: {tf_line(self)}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


def _view_stats(view_rms: Sequence[float]) -> str:
    if not view_rms:
        return ""
    v = np.asarray(view_rms) * 100.0
    return f" (per view: median {np.median(v):.2f} cm, max {v.max():.2f} cm)"


# --- small geometry ---------------------------------------------------------------------------------


def _quaternion(R: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """(qx, qy, qz, qw) of a rotation matrix, qw >= 0 (Shepperd's method)."""
    m = np.asarray(R, dtype=np.float64)
    tr = float(np.trace(m))
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (m[j, i] + m[i, j]) / s
        v[k] = (m[k, i] + m[i, k]) / s
        q = (v[0], v[1], v[2], (m[k, j] - m[j, k]) / s)
    qa = np.asarray(q, dtype=np.float64)
    qa = qa / np.linalg.norm(qa)
    if qa[3] < 0:
        qa = -qa
    return float(qa[0]), float(qa[1]), float(qa[2]), float(qa[3])


def _pose_text(T: NDArray[np.float64]) -> str:
    qx, qy, qz, qw = _quaternion(T[:3, :3])
    x, y, z = (float(v) for v in T[:3, 3])
    return f"{x:.6f} {y:.6f} {z:.6f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}"


def tf_line(result: ExtrinsicsResult) -> str:
    """base_link -> laser as ``x y z qx qy qz qw`` (static_transform_publisher's argument order)."""
    return _pose_text(result.base_T_laser())


def _line_spread(xy: NDArray[np.float64]) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """RMS distance of 2-D points from their total-least-squares line, the line's centroid and direction."""
    mean = xy.mean(axis=0)
    _, s, vt = np.linalg.svd(xy - mean, full_matrices=False)
    spread = float(s[1] / math.sqrt(len(xy))) if len(s) > 1 else 0.0
    return spread, mean, vt[0]


# --- (a) pairs: PnP from LiDAR points to pixels -------------------------------------------------------


def _check_pairs(points_laser: ArrayLike, pixels: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p = np.asarray(points_laser, dtype=np.float64)
    px = np.asarray(pixels, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise InputError(f"LiDAR points must have shape (N, 2) or (N, 3), got {p.shape}")
    if px.ndim != 2 or px.shape[1] != 2:
        raise InputError(f"pixels must have shape (N, 2), got {px.shape}")
    if len(p) != len(px):
        raise InputError(f"{len(p)} LiDAR points but {len(px)} pixels; they must pair one to one")
    bad = ~(np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(px), axis=1))
    if bad.any():
        raise InputError(f"pair {int(np.flatnonzero(bad)[0]) + 1} holds NaN or infinity; every value must be a number")
    if len(p) < MIN_PAIRS:
        raise InputError(f"{len(p)} pairs is too few: need at least {MIN_PAIRS}, spread over several target positions")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    p, px = np.ascontiguousarray(p), np.ascontiguousarray(px)
    spread, _, _ = _line_spread(p[:, :2])
    if spread < COLLINEAR_SPREAD_M:
        raise InputError(
            f"the LiDAR points lie on one line in the scan plane (spread {spread * 1000:.1f} mm): "
            "add pairs from other target positions or angles"
        )
    return p, px


def extrinsics_from_pairs(
    points_laser: ArrayLike,
    pixels: ArrayLike,
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    *,
    prior: Mount | None = None,
) -> ExtrinsicsResult:
    """The LiDAR mount from LiDAR points matched to their pixels (SolvePnP, then Levenberg-Marquardt).

    Args:
        points_laser: the LiDAR returns in the laser frame, metres, shape (N, 2) (the scan plane, z = 0) or (N, 3).
        pixels: where each return hits the target in the image, pixels through the lens, shape (N, 2).
        camera: the camera's intrinsics and distortion.
        base_T_optical: the camera optical frame in base_link (the known camera mount).
        prior: the mount to report the change from (default: the solved one).

    Returns:
        The calibration; the residual is the RMS reprojection error in pixels.

    Raises:
        InputError: fewer than MIN_PAIRS pairs, NaN, mismatched shapes, collinear LiDAR points, or no solution
            with the points in front of the camera.
    """

    obj, img = _check_pairs(points_laser, pixels)
    K, D = camera.matrix, camera.dist
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    starts: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    if prior is not None:
        guess = transforms.invert(base_T_optical) @ prior.matrix()
        rv, _ = cv2.Rodrigues(guess[:3, :3])
        starts.append((np.asarray(rv, dtype=np.float64), guess[:3, 3].reshape(3, 1).copy()))
    found, rvec, tvec = cv2.solvePnP(obj, img, K, D, flags=cv2.SOLVEPNP_ITERATIVE)
    if found:
        starts.append((np.asarray(rvec, dtype=np.float64), np.asarray(tvec, dtype=np.float64)))
    count, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, K, D, flags=cv2.SOLVEPNP_IPPE)
    if count:
        starts += [
            (np.asarray(r, dtype=np.float64), np.asarray(t, dtype=np.float64))
            for r, t in zip(rvecs, tvecs, strict=True)
        ]
    best: tuple[float, NDArray[np.float64]] | None = None
    for r0, t0 in starts:
        r, t = cv2.solvePnPRefineLM(obj, img, K, D, r0.copy(), t0.copy(), criteria)
        R, _ = cv2.Rodrigues(r)
        optical_T_laser = transforms.transform(R, np.asarray(t).ravel())
        if not np.all(transforms.apply(optical_T_laser, obj)[:, 2] > 0):
            continue
        proj, _ = cv2.projectPoints(obj, r, t, K, D)
        rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
        if best is None or rms < best[0]:
            best = (rms, optical_T_laser)
    if best is None:
        raise InputError("no LiDAR pose puts the pairs in front of the camera: check the pairs' columns and units")
    rms, optical_T_laser = best
    mount = Mount.from_matrix(base_T_optical @ optical_T_laser)
    notes = []
    if rms > 3.0:
        notes.append(f"reprojection RMS {rms:.1f} px is large: check for mismatched pairs")
    std, cond = _pnp_uncertainty(obj, optical_T_laser, camera, base_T_optical, rms)
    return ExtrinsicsResult(
        method="pairs",
        laser_mount=mount,
        optical_T_laser=optical_T_laser,
        prior_mount=prior or mount,
        rms=rms,
        residual_unit="px",
        count=len(obj),
        points=len(obj),
        std=std,
        condition=cond,
        notes=tuple(notes),
    )


def _pnp_uncertainty(
    obj: NDArray[np.float64],
    optical_T_laser: NDArray[np.float64],
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    rms: float,
) -> tuple[dict[str, float], float]:
    """1-sigma of the mount's six fields by numerical Jacobian of the reprojection, and its condition."""

    base = Mount.from_matrix(base_T_optical @ optical_T_laser)
    optical_T_base = transforms.invert(base_T_optical)
    keys = ("x", "y", "z", "roll", "pitch", "yaw")
    steps = (1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-5)

    def project(m: Mount) -> NDArray[np.float64]:
        p = transforms.apply(optical_T_base @ m.matrix(), obj)
        px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), camera.matrix, camera.dist)
        return np.asarray(px, dtype=np.float64).ravel()

    p0 = project(base)
    J = np.column_stack(
        [
            (project(dataclasses.replace(base, **{k: getattr(base, k) + h})) - p0) / h
            for k, h in zip(keys, steps, strict=True)
        ]
    )
    return _covariance(J, rms * math.sqrt(2.0), keys)


def _covariance(J: NDArray[np.float64], sigma: float, keys: Sequence[str]) -> tuple[dict[str, float], float]:
    """Parameter 1-sigma from J and the residual sigma, and the condition of the column-normalised J^T J."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Jn = J / norms
    JtJ = Jn.T @ Jn
    cond = float(np.linalg.cond(JtJ))
    try:
        cov = np.linalg.inv(JtJ) / np.outer(norms, norms) * sigma**2
        std = {k: float(math.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(keys)}
    except np.linalg.LinAlgError:
        std = dict.fromkeys(keys, math.inf)
    return std, cond


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
        _, mean, direction = _line_spread(pts[keep])
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
        good = [i for i in good if _line_spread(used[i].points_laser[selected[i]])[0] <= MAX_LINE_RMS_M]
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
    std, cond = _covariance(J, rms, ("x", "y", "yaw"))
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


# --- pairs files --------------------------------------------------------------------------------------


def read_pairs_csv(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """LiDAR point / pixel pairs from a CSV with the header ``x,y,u,v`` (optionally ``z``).

    x, y (z) are metres in the laser frame; u, v are pixels through the lens (as the image shows them).

    Returns:
        points (N, 3) in the laser frame (z = 0 when the column is absent) and pixels (N, 2).

    Raises:
        InputError: missing file or column, a value that is not a number, no rows.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"pairs file not found: {p}")
    with p.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip().lower() for h in (reader.fieldnames or [])]
        missing = [c for c in ("x", "y", "u", "v") if c not in header]
        if missing:
            raise InputError(f"{p}: missing column {', '.join(missing)} (the header must be x,y,u,v with optional z)")
        reader.fieldnames = header
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                vals = [float(row.get(c) or "nan") for c in ("x", "y", "z", "u", "v")] if "z" in header else None
                if vals is None:
                    vals = [float(row[c] or "nan") for c in ("x", "y")] + [0.0]
                    vals += [float(row[c] or "nan") for c in ("u", "v")]
            except (TypeError, ValueError):
                raise InputError(f"{p}: line {line}: every value must be a number") from None
            rows.append(vals)
    if not rows:
        raise InputError(f"{p}: no pairs below the header")
    a = np.asarray(rows, dtype=np.float64)
    return np.ascontiguousarray(a[:, :3]), np.ascontiguousarray(a[:, 3:])


def write_pairs_csv(
    path: str | os.PathLike[str],
    points_laser: NDArray[np.float64],
    pixels: NDArray[np.float64],
    *,
    force: bool = False,
) -> None:
    """Write pairs as the CSV that read_pairs_csv reads (x, y metres in the laser frame; u, v pixels)."""

    lines = ["x,y,u,v"] + [
        f"{p[0]:.6f},{p[1]:.6f},{q[0]:.4f},{q[1]:.4f}" for p, q in zip(points_laser, pixels, strict=True)
    ]
    write_text_atomic(path, "\n".join(lines) + "\n", force=force)


# --- outputs ------------------------------------------------------------------------------------------


def result_yaml(result: ExtrinsicsResult) -> str:
    """The result as YAML: ``laser_mount`` (as in the robot file), the laser in camera_optical, the tf line."""

    o = result.optical_T_laser
    qx, qy, qz, qw = _quaternion(o[:3, :3])
    data: dict[str, Any] = {
        "laser_mount": result.laser_mount.to_dict(),
        "camera_optical_to_laser": {
            "x": float(o[0, 3]),
            "y": float(o[1, 3]),
            "z": float(o[2, 3]),
            "qx": qx,
            "qy": qy,
            "qz": qz,
            "qw": qw,
        },
        "tf_base_link_to_laser": tf_line(result),
        "method": result.method,
        "solved": [k for k in ("x", "y", "z", "roll", "pitch", "yaw") if k not in result.fixed],
        "fixed_from_prior": list(result.fixed),
        "prior_laser_mount": result.prior_mount.to_dict(),
        "residual_rms": float(result.rms),
        "residual_unit": result.residual_unit,
        "pairs" if result.method == "pairs" else "views": result.count,
        "lidar_points": result.points,
        "std": {k: float(v) for k, v in result.std.items()},
        "condition": float(result.condition),
        "notes": list(result.notes),
    }
    if result.view_rms:
        data["view_rms_m"] = [round(float(v), 6) for v in result.view_rms]
    head = (
        "# monodock calibrate extrinsics: the LiDAR (laser frame) in base_link; paste laser_mount into the robot file\n"
    )
    return head + yaml_text(data, flow=None, width=1000)


def write_result_yaml(path: str | os.PathLike[str], result: ExtrinsicsResult, *, force: bool = False) -> None:
    """Write result_yaml atomically (an existing file only with ``force``)."""

    write_text_atomic(path, result_yaml(result), force=force)


# --- (c) diamond target: LiDAR segment ends on the board's slanted edges ------------------------------

MIN_TARGET_VIEWS = 6
MIN_SEGMENT_BEAMS = 6
# Scan points this far from the board's plane / outside the diamond (under the prior mount) are not on it.
TARGET_PLANE_GATE_M = 0.10
TARGET_EDGE_MARGIN_M = 0.10
# Consecutive beams on one surface differ in range by less than this, metres.
RANGE_JUMP_M = 0.06


@dataclass(frozen=True)
class _EdgeEnd:
    """One end of a view's LiDAR segment on the target: the point (laser frame) and the view's board pose."""

    view: int
    point: NDArray[np.float64]
    base_T_target: NDArray[np.float64]
    optical_T_target: NDArray[np.float64]


def _target_board_pose(
    image: NDArray[np.generic], camera: CameraModel, target: DiamondTarget, detector: Any
) -> NDArray[np.float64] | None:
    """optical_T_target from the target's markers in an image (two markers at least), or None."""

    corners, ids, _ = detector.detectMarkers(as_gray(image))
    if ids is None:
        return None
    obj, img = [], []
    for quad, mid in zip(corners, ids.ravel(), strict=True):
        if int(mid) in target.marker_ids:
            obj.append(target.marker_corners_in_target(int(mid)))
            img.append(np.asarray(quad, dtype=np.float64).reshape(4, 2))
    if len(obj) < 2:
        return None
    o, p = np.ascontiguousarray(np.vstack(obj)), np.ascontiguousarray(np.vstack(img))
    count, rvecs, tvecs, errs = cv2.solvePnPGeneric(o, p, camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    if not count:
        return None
    k = int(np.argmin(np.asarray(errs).ravel()))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    r, t = cv2.solvePnPRefineLM(o, p, camera.matrix, camera.dist, rvecs[k].copy(), tvecs[k].copy(), criteria)
    R, _ = cv2.Rodrigues(r)
    T = transforms.transform(R, np.asarray(t).ravel())
    return T if T[2, 3] > 0 else None


def _segment_ends(
    scan: LaserScan, target_T_laser: NDArray[np.float64], half_diagonal: float
) -> list[NDArray[np.float64]] | None:
    """The LiDAR segment on the board and its ends (laser frame, z = 0), or None when no segment is found.

    The segment is the run of consecutive beams without a range jump that holds the most returns near the board
    (under the prior mount). Each end whose outside neighbour lies farther (a true edge, not an occlusion) is
    refined: the segment's fitted line cut by the bisector of the last beam on and the first beam off.
    """
    r = scan.ranges.astype(np.float64)
    a = scan.angles()
    valid = np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)
    rr = np.where(valid, r, np.inf)
    xyz = np.stack([rr * np.cos(a), rr * np.sin(a), np.zeros_like(a)], axis=1)
    with np.errstate(invalid="ignore"):
        pt = transforms.apply(target_T_laser, np.where(valid[:, None], xyz, 0.0))
    near = (
        valid
        & (np.abs(pt[:, 2]) < TARGET_PLANE_GATE_M)
        & (np.abs(pt[:, 0]) + np.abs(pt[:, 1]) < half_diagonal + TARGET_EDGE_MARGIN_M)
    )
    if near.sum() < MIN_SEGMENT_BEAMS:
        return None
    n = len(r)
    # Runs of returns without a range jump; a single dropped beam (NaN) inside a run does not split it.
    idx = np.flatnonzero(valid)
    best: tuple[int, int, int] | None = None
    start = 0
    for q in range(1, len(idx) + 1):
        if q < len(idx):
            gap = idx[q] - idx[q - 1]
            same = (gap == 1 or (gap == 2 and np.isnan(r[idx[q] - 1]))) and abs(
                rr[idx[q]] - rr[idx[q - 1]]
            ) < RANGE_JUMP_M
            if same:
                continue
        i, j = int(idx[start]), int(idx[q - 1])
        hits = int(near[i : j + 1].sum())
        if best is None or hits > best[0]:
            best = (hits, i, j)
        start = q
    if best is None or best[0] < MIN_SEGMENT_BEAMS or best[2] - best[1] + 1 < MIN_SEGMENT_BEAMS:
        return None
    _, i0, i1 = best
    seg = xyz[i0 : i1 + 1, :2][valid[i0 : i1 + 1]]
    spread, c, d = _line_spread(seg)
    if spread > MAX_LINE_RMS_M:
        return None
    ends = []
    for last, off in ((i0, i0 - 1), (i1, i1 + 1)):
        if off < 0 or off >= n or np.isnan(r[off]) or (valid[off] and rr[off] < rr[last] + RANGE_JUMP_M):
            continue  # the scan's border, a dropped beam, or something nearer hides the board's edge
        phi = 0.5 * (a[last] + a[off])
        u = np.array([math.cos(phi), math.sin(phi)])
        A = np.column_stack([u, -d])
        if abs(np.linalg.det(A)) < 1e-9:
            continue
        lam, _ = np.linalg.solve(A, c)
        if lam <= 0:
            continue
        ends.append(np.array([lam * u[0], lam * u[1], 0.0]))
    return ends


def _edge_frames(target: DiamondTarget) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The edges' start vertices, unit directions and in-plane unit normals, each shape (4, 3)."""
    edges = target.edges_in_target()
    v0 = np.array([e[0] for e in edges])
    d = np.array([e[1] - e[0] for e in edges])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    nrm = np.cross(np.array([0.0, 0.0, 1.0]), d)
    return v0, d, nrm


def _ends_in_target(ends: Sequence[_EdgeEnd], mount: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each end point in its view's target frame under a mount (x y z roll pitch yaw), shape (N, 3)."""
    M = transforms.transform(transforms.rotation_from_rpy(*mount[3:]), mount[:3])
    return np.array([transforms.apply(transforms.invert(e.base_T_target) @ M, e.point[None])[0] for e in ends])


def _assign_edges(p_target: NDArray[np.float64], target: DiamondTarget) -> NDArray[np.intp]:
    """The nearest edge (as a segment, in the board plane) to each point."""
    edges = target.edges_in_target()
    dist = np.empty((len(p_target), 4))
    for k, (a, b) in enumerate(edges):
        ab = b - a
        s = np.clip((p_target[:, :2] - a[:2]) @ ab[:2] / (ab[:2] @ ab[:2]), 0.0, 1.0)
        dist[:, k] = np.linalg.norm(p_target[:, :2] - (a[:2] + s[:, None] * ab[:2]), axis=1)
    return np.asarray(np.argmin(dist, axis=1), dtype=np.intp)


def _edge_residuals(
    ends: Sequence[_EdgeEnd], mount: NDArray[np.float64], edge: NDArray[np.intp], target: DiamondTarget
) -> NDArray[np.float64]:
    """Point-to-line residuals: each end's offset from its edge across the board and out of its plane, (2N,)."""
    v0, _, nrm = _edge_frames(target)
    p = _ends_in_target(ends, mount)
    across = np.einsum("ij,ij->i", p - v0[edge], nrm[edge])
    return np.column_stack([across, p[:, 2]]).ravel()


def _solve_edge_mount(
    ends: Sequence[_EdgeEnd], prior: Mount, target: DiamondTarget
) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """Levenberg-Marquardt on the six mount fields from the prior, re-assigning edges between rounds.

    Returns the mount vector, each end's edge, the final residuals and the Jacobian there.
    """
    x = np.array([prior.x, prior.y, prior.z, prior.roll, prior.pitch, prior.yaw], dtype=np.float64)
    steps = np.array([1e-6, 1e-6, 1e-6, 1e-7, 1e-7, 1e-7])
    edge = _assign_edges(_ends_in_target(ends, x), target)
    J = np.zeros((2 * len(ends), 6))
    res = _edge_residuals(ends, x, edge, target)
    for _ in range(3):
        lam = 1e-3
        for _ in range(50):
            res = _edge_residuals(ends, x, edge, target)
            J = np.column_stack(
                [(_edge_residuals(ends, x + h * np.eye(6)[i], edge, target) - res) / h for i, h in enumerate(steps)]
            )
            A = J.T @ J
            g = J.T @ res
            improved = False
            while lam < 1e8:
                dx = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), g)
                new = _edge_residuals(ends, x + dx, edge, target)
                if new @ new < res @ res:
                    x, lam, improved = x + dx, lam * 0.3, True
                    break
                lam *= 10.0
            if not improved or np.max(np.abs(dx)) < 1e-9:
                break
        new_edge = _assign_edges(_ends_in_target(ends, x), target)
        if np.array_equal(new_edge, edge):
            break
        edge = new_edge
    res = _edge_residuals(ends, x, edge, target)
    return x, edge, res, J


def edge_pairs_from_views(
    views: Sequence[TargetView],
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    target: DiamondTarget,
    prior_mount: Mount,
) -> tuple[NDArray[np.float64], NDArray[np.float64], dict[str, Any]]:
    """LiDAR point / pixel pairs from views of the diamond target: segment ends matched to the board's edges.

    Per view the camera gives the board's pose (its markers, PnP) and the scan its segment on the board, whose
    two ends lie on two slanted edges. The 6-DoF laser mount that puts the ends on their edges is found by
    point-to-line least squares from ``prior_mount``; each end is then paired with the pixel of its closest
    point on its edge.

    Returns:
        points (N, 3) in the laser frame, pixels (N, 2), and facts for the result's notes: ``views`` used,
        ``skipped`` (reason -> count), ``mount`` (the point-to-line solution), ``rms_m``, ``std``, ``condition``.

    Raises:
        InputError: fewer than MIN_TARGET_VIEWS views with the board and its segment found.
    """

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 50
    detector = cv2.aruco.ArucoDetector(target.aruco_dictionary(), params)
    prior_T = prior_mount.matrix()
    skipped: dict[str, int] = {}
    ends: list[_EdgeEnd] = []
    used = 0
    for k, view in enumerate(views):
        optical_T_target = _target_board_pose(view.image, camera, target, detector)
        if optical_T_target is None:
            skipped["board not found"] = skipped.get("board not found", 0) + 1
            continue
        base_T_target = base_T_optical @ optical_T_target
        found = _segment_ends(view.scan, transforms.invert(base_T_target) @ prior_T, target.half_diagonal)
        if not found:
            skipped["no LiDAR segment on the board"] = skipped.get("no LiDAR segment on the board", 0) + 1
            continue
        used += 1
        ends += [_EdgeEnd(k, p, base_T_target, optical_T_target) for p in found]
    if used < MIN_TARGET_VIEWS or len(ends) < MIN_PAIRS:
        why = ", ".join(f"{n} {r}" for r, n in skipped.items()) or "no views"
        raise InputError(
            f"only {used} of {len(views)} target views are usable ({why}); need at least {MIN_TARGET_VIEWS}"
        )
    x, edge, res, J = _solve_edge_mount(ends, prior_mount, target)
    # Drop ends far off their edge (a mis-found segment end), then solve again from the first solution.
    dist = np.hypot(res[0::2], res[1::2])
    keep = dist < max(3.0 * float(np.median(dist)) * 1.4826, 0.01)
    if not keep.all() and keep.sum() >= MIN_PAIRS:
        skipped["segment ends off their edge"] = int((~keep).sum())
        ends = [e for e, k in zip(ends, keep, strict=True) if k]
        x, edge, res, J = _solve_edge_mount(ends, Mount(*(float(v) for v in x)), target)
    v0, d, _ = _edge_frames(target)
    p_t = _ends_in_target(ends, x)
    q_t = v0[edge] + np.einsum("ij,ij->i", p_t - v0[edge], d[edge])[:, None] * d[edge]
    q_opt = np.array([transforms.apply(e.optical_T_target, q[None])[0] for e, q in zip(ends, q_t, strict=True)])
    pixels = camera.project(q_opt)
    points = np.array([e.point for e in ends])
    rms = float(np.sqrt(np.mean(res**2)))
    std, cond = _covariance(J, rms, ("x", "y", "z", "roll", "pitch", "yaw"))
    facts: dict[str, Any] = {
        "views": used,
        "skipped": skipped,
        "mount": Mount(*(float(v) for v in x)),
        "rms_m": rms,
        "std": std,
        "condition": cond,
    }
    return points, pixels, facts


def extrinsics_from_target_views(
    views: Sequence[TargetView],
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    prior_mount: Mount,
    target: DiamondTarget | None = None,
) -> ExtrinsicsResult:
    """The full 6-DoF LiDAR mount from views of the diamond target: edge pairs, then SolvePnP on them."""

    tgt = target or DiamondTarget()
    points, pixels, facts = edge_pairs_from_views(views, camera, base_T_optical, tgt, prior_mount)
    result = extrinsics_from_pairs(points, pixels, camera, base_T_optical, prior=prior_mount)
    m: Mount = facts["mount"]
    notes = [
        f"point-to-line solution: x {m.x:+.4f} y {m.y:+.4f} z {m.z:+.4f} m, roll {math.degrees(m.roll):+.3f} "
        f"pitch {math.degrees(m.pitch):+.3f} yaw {math.degrees(m.yaw):+.3f} deg, RMS {facts['rms_m'] * 100:.2f} cm",
        *result.notes,
    ]
    if facts["skipped"]:
        notes.append("views skipped: " + ", ".join(f"{n} {r}" for r, n in facts["skipped"].items()))
    return dataclasses.replace(
        result, method="target pairs (SolvePnP)", count=int(facts["views"]), points=len(points), notes=tuple(notes)
    )


def target_views_from_recording(
    path: str | os.PathLike[str], *, tolerance_s: float = 0.05
) -> tuple[list[TargetView], CameraModel | None, list[str]]:
    """Views of the diamond target from a recording: each image with the scan nearest in stamp (within
    ``tolerance_s``), the recording's camera (CameraInfo) if it has one, and the reader's warnings."""

    with open_recording(path) as rec:
        if rec.scan_topic is None:
            raise InputError(f"{path}: no sensor_msgs/LaserScan topic; the target's ends come from the LiDAR")
        scans = rec.scans()
        frames = [f for f in rec.images() if f.image is not None]
        camera = rec.camera()
        warnings = list(rec.warnings)
    pairing = pair_nearest([f.stamp for f in frames], [s.stamp for s in scans], tolerance_s)
    views = [
        TargetView(f.image, scans[int(j)])
        for f, j in zip(frames, pairing, strict=True)
        if j >= 0 and f.image is not None
    ]
    if not views:
        raise InputError(f"{path}: no image has a scan within {tolerance_s * 1000:.0f} ms")
    return views, camera, warnings
