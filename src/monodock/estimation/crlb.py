"""The Cramér–Rao lower bound on the DockPose (x, y, yaw) from marker corners.

With Gaussian corner noise of known covariance, no unbiased estimator of the DockPose beats the covariance
(JᵀWJ)⁻¹, J the Jacobian of the corner pixels w.r.t. (x, y, yaw) through the real lens and W the inverse
corner covariance. ``estimation.planar.solve_planar`` reaches it (tests/estimation/test_planar.py checks that by
Monte Carlo against the simulator's true corners).

The corner noise it takes is ``corner_noise.CornerNoise``'s; ``evaluation.what_if`` asks what set-up changes buy.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.planar import planar_model

__all__ = ["crlb", "pose_jacobian", "visible_roles"]


def visible_roles(
    pose: DockPose, camera: CameraModel, layout: DockLayout, robot: RobotConfig, margin_px: float = 0.0
) -> tuple[str, ...]:
    """The markers whose four corners all fall inside the image (``margin_px`` from its border) at a pose."""
    roles = layout.roles
    P = planar_model(camera, layout, robot).optical_points(pose, roles).reshape(len(roles), 4, 3)
    in_field = np.asarray(camera.in_view_field(P.reshape(-1, 3)).reshape(len(roles), 4).all(axis=1), dtype=bool)
    field: list[bool] = in_field.tolist()
    if not any(field):
        return ()
    px = camera.project(P.reshape(-1, 3)).reshape(len(roles), 4, 2)
    lo = -0.5 + margin_px
    inside: list[bool] = (
        (px[:, :, 0].min(axis=1) >= lo)
        & (px[:, :, 1].min(axis=1) >= lo)
        & (px[:, :, 0].max(axis=1) <= camera.width - 0.5 - margin_px)
        & (px[:, :, 1].max(axis=1) <= camera.height - 0.5 - margin_px)
    ).tolist()
    return tuple(r for r, f, i in zip(roles, field, inside, strict=True) if f and i)


def pose_jacobian(
    pose: DockPose, camera: CameraModel, layout: DockLayout, robot: RobotConfig, roles: Sequence[str]
) -> NDArray[np.float64]:
    """d(corner pixels)/d(x, y, yaw), shape (8R, 3): rows u, v of each corner, markers in ``roles`` order,
    corners in ArUco order; columns per metre, metre and radian.

    Raises:
        InputError: unknown role, no roles, or a corner behind the camera.
    """
    _, J = planar_model(camera, layout, robot).jacobian(pose, roles)
    return J


def _row_sigmas(corner_sigma_px: float | ArrayLike, n: int) -> NDArray[np.float64]:
    """Per-row (u, v of each corner) sigma, shape (2n,), from a number, (n,) or (n, 2)."""
    a = np.asarray(corner_sigma_px, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape == (n,):
        a = np.repeat(a, 2)
    elif a.shape == (n, 2):
        a = a.reshape(-1)
    else:
        raise InputError(f"corner sigma must be a number or have shape ({n},) or ({n}, 2), got {a.shape}")
    if not np.all(np.isfinite(a) & (a > 0)):
        raise InputError("corner sigmas must be positive and finite")
    return a


def crlb(
    pose: DockPose,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    corner_sigma_px: float | ArrayLike,
    roles: Sequence[str] | None = None,
    correlation: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """The Cramér–Rao bound: the 3x3 covariance of (x m, y m, yaw rad) no unbiased estimator beats.

    Args:
        pose: the true DockPose.
        camera, layout, robot: the set-up.
        corner_sigma_px: the corner noise in pixels: a number, one per corner (N,), or per corner and axis
            (N, 2); N = 4 × markers in ``roles`` order.
        roles: the markers observed; default: those fully in view at this pose.
        correlation: None for errors independent between corners and axes; else the 8x8 correlation of one
            marker's corner errors (u, v of its corners in ArUco order), the same for every marker, markers
            independent of each other.

    Returns:
        σ²(JᵀJ)⁻¹ for iid noise, (JᵀWJ)⁻¹ in general; infinite where the pose is unobservable.

    Raises:
        InputError: no marker in view, bad sigma or correlation, a corner behind the camera.
    """
    use = tuple(roles) if roles is not None else visible_roles(pose, camera, layout, robot)
    if not use:
        raise InputError(f"no dock marker fully in view at {pose}")
    J = pose_jacobian(pose, camera, layout, robot, use)
    Jw = J / _row_sigmas(corner_sigma_px, len(J) // 2)[:, None]
    if correlation is not None:
        C = np.asarray(correlation, dtype=np.float64)
        if C.shape != (8, 8) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T):
            raise InputError("a corner correlation must be a finite symmetric 8x8 matrix")
        try:
            L = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:
            raise InputError("a corner correlation must be positive definite") from None
        # Whitening per marker: L⁻¹ applied to its 8 sigma-scaled rows.
        Jw = np.linalg.solve(L, Jw.reshape(-1, 8, 3)).reshape(-1, 3)
    try:
        cov = np.linalg.inv(Jw.T @ Jw)
    except np.linalg.LinAlgError:
        return np.full((3, 3), np.inf)
    return np.asarray(cov, dtype=np.float64)
