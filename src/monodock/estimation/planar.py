"""Maximum-likelihood planar PnP: the DockPose (x, y, yaw) that best explains the markers' corner pixels.

The robot stands on the floor and the camera mount is known, so the dock has three degrees of freedom in
base_link, not six. Fitting those three directly, through the real lens, is the efficient estimator for
Gaussian corner noise (its covariance reaches the Cramér–Rao bound of ``monodock.estimation.crlb``) and it cannot
tilt the dock off the floor, which is where 6-DoF PnP goes wrong on small, far markers.

Model: a corner p (dock frame) lands at P = optical_T_base · base_T_dock(x, y, yaw) · p in the optical frame
and at pixel π(P) through the lens. ``cv2.projectPoints(P, 0, 0, K, dist)`` returns dπ/dtvec per point,
which with a zero pose is dπ/dP; the chain rule with dP/d(x, y, yaw) gives the analytic Jacobian.

A lone small marker seen from afar has two planar minima (the yaw sign ambiguity of weak perspective):
``planar_starts.planar_candidates`` starts from both IPPE solutions and returns every distinct local minimum
with its cost; ``planar_starts`` also holds the starts and fits of two or more markers (``board_fit``).
The Levenberg–Marquardt loop, shared by the fit with and without a camera turn, is ``levenberg``'s.

The 3-DoF model trusts the mount: a pitch 1° off moves every corner ~10 px vertically at f = 600 px, which
it can only explain by moving the dock in depth (~30 cm) and yaw (~20°). With ``pitch_sd`` the fit also
estimates a pitch offset δ of the camera about its optical x axis, P' = R_x(δ)·P, under a prior δ ~ N(0, σ²);
dP'/dδ = (0, −P'_z, P'_y). For a mount with zero roll δ is the error of the mount's pitch (true − configured,
> 0: the camera looks further down than configured); it also soaks up most of a height error, which shifts
the corners nearly the same way. ``pose_information`` gives the bound with δ marginalised.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.compiled import kernel
from monodock.core.layout import DockLayout
from monodock.core.lens import lens_of, project
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.levenberg import (
    compiled_levenberg_marquardt,
    inverse3,
    levenberg_marquardt,
    marginal3,
    marginal4,
    step3,
    step4,
)

__all__ = [
    "DEFAULT_CORNER_SIGMA_PX",
    "PlanarFit",
    "PlanarModel",
    "PosePrior",
    "planar_model",
    "pose_information",
    "solve_planar",
]

# The optical axes a camera turn can be fitted about (see ``solve_planar``): x is the mount's pitch, z its roll.
PITCH_AXIS, ROLL_AXIS = 0, 2

# One iid corner sigma for every marker size, on the conservative side: the random part of OpenCV's SUBPIX
# corners on the simulator's default frames is ~0.05-0.1 px per axis on markers over ~31 px and ~0.46 px on
# smaller ones (bench/crlb_whatif.py --measure-c); crlb.CornerNoise gives per-corner values to pass instead.
DEFAULT_CORNER_SIGMA_PX = 0.3
# Points closer to the camera plane than this (metres, optical z) make a pose invalid.
_MIN_DEPTH = 1e-3
_ZERO3 = np.zeros(3)
# Default cap on the projections a fit evaluates, and the step (m, rad) below which it has converged in any case.
_MAX_ITERATIONS = 20
_TOLERANCE = 1e-9
FIT_ITERATIONS, FIT_TOLERANCE = _MAX_ITERATIONS, _TOLERANCE  # the board fit's, for a caller's compiled copy of it


@dataclass(frozen=True)
class PosePrior:
    """A Gaussian prior on the DockPose: mean and 3x3 covariance of (x m, y m, yaw rad).

    Used to pull the fit towards another estimate (e.g. the regression's) where the corners say little.
    """

    mean: DockPose
    covariance: NDArray[np.float64] = field(repr=False)

    def information(self) -> NDArray[np.float64]:
        """The inverse covariance; raises InputError unless the covariance is symmetric positive definite."""
        c = np.asarray(self.covariance, dtype=np.float64)
        if c.shape != (3, 3) or not np.all(np.isfinite(c)) or not np.allclose(c, c.T, rtol=1e-9, atol=0.0):
            raise InputError("prior covariance must be a finite symmetric 3x3 matrix")
        try:
            np.linalg.cholesky(c)
        except np.linalg.LinAlgError:
            raise InputError("prior covariance must be positive definite") from None
        return np.asarray(np.linalg.inv(c), dtype=np.float64)


@dataclass(frozen=True)
class PlanarFit:
    """The result of one planar fit.

    Attributes:
        pose: the DockPose at the minimum (yaw wrapped into [-pi, pi)).
        covariance: 3x3 covariance of (x m, y m, yaw rad) for the given corner noise: (JᵀWJ + Λ)⁻¹, with W
            the inverse corner covariance and Λ the prior's information (0 without a prior).
        covariance_from_residuals: the same with the corner noise scaled by ``noise_scale`` as the residuals
            measure it: (JᵀWJ / s² + Λ)⁻¹.
        noise_scale: s = sqrt(χ² / (2N − 3)), the residuals' size relative to the given corner noise
            (≈ 1 when the given sigma is right; NaN with fewer than 2 corners).
        rms_px: RMS reprojection error of the corners (per corner, 2D distance), pixels.
        cost: χ² of the whitened corner residuals plus the prior's Mahalanobis term.
        iterations: projections evaluated.
        converged: whether the last step was below the tolerance.
        roles: the markers used, in the order their corners were stacked.
        pitch_offset: the estimated camera pitch offset δ (rad) when fitted with ``pitch_sd``, else 0.0;
            the covariances are then the (x, y, yaw) marginals of the 4x4 one.
        roll_offset: the same for a camera roll offset (about the optical z axis) fitted with ``roll_sd``.
    """

    pose: DockPose
    covariance: NDArray[np.float64] = field(repr=False)
    covariance_from_residuals: NDArray[np.float64] = field(repr=False)
    noise_scale: float
    rms_px: float
    cost: float
    iterations: int
    converged: bool
    roles: tuple[str, ...] = ()
    pitch_offset: float = 0.0
    roll_offset: float = 0.0

    def sd(self) -> tuple[float, float, float]:
        """Standard deviations of x (m), y (m) and yaw (rad) from ``covariance``."""
        d = np.sqrt(np.diag(self.covariance))
        return float(d[0]), float(d[1]), float(d[2])


class PlanarModel:
    """Projects the dock's corners for a planar DockPose, with the Jacobian; the fixed parts precomputed.

    For a corner p and pose (x, y, yaw) with c = cos yaw, s = sin yaw, the optical-frame point is
    P = c·U + s·V + W + x·a₀ + y·a₁ with U = p_x a₀ + p_y a₁, V = p_x a₁ − p_y a₀, W = p_z a₂ + t, where
    (a₀ a₁ a₂ | t) = optical_T_base; and dP/dyaw = −s·U + c·V. Stacking [U V W a₀ a₁] per coordinate makes
    both one small matrix product.

    Args:
        camera: the lens (matrix and distortion are used as they are).
        layout: where the markers sit on the dock.
        robot: the camera mount (``base_T_optical``).
    """

    def __init__(self, camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> None:
        self.camera = camera
        self.layout = layout
        self.robot = robot
        self._K = camera.matrix
        self._dist = camera.dist
        self.lens = lens_of(camera)  # as the kernels read it
        self.base_T_optical = robot.base_T_optical()
        optical_T_base = transforms.invert(self.base_T_optical)
        self._A = np.ascontiguousarray(optical_T_base[:3, :3])
        self._t = np.ascontiguousarray(optical_T_base[:3, 3])
        self._parts: dict[tuple[str, ...], _Parts] = {}

    def parts(self, roles: Sequence[str]) -> _Parts:
        """The precomputed per-corner terms of these markers (cached per role tuple)."""
        key = tuple(roles)
        cached = self._parts.get(key)
        if cached is None:
            for r in key:
                if r not in self.layout.roles:
                    raise InputError(f"unknown marker role '{r}' (expected {', '.join(self.layout.roles)})")
            if not key:
                raise InputError("no marker roles given")
            obj = np.concatenate([self.layout.corners_in_dock(r) for r in key])
            a0, a1, a2 = self._A[:, 0], self._A[:, 1], self._A[:, 2]
            n = len(obj)
            U = np.outer(obj[:, 0], a0) + np.outer(obj[:, 1], a1)
            V = np.outer(obj[:, 0], a1) - np.outer(obj[:, 1], a0)
            W = np.outer(obj[:, 2], a2) + self._t
            Z = np.stack([U.ravel(), V.ravel(), W.ravel(), np.tile(a0, n), np.tile(a1, n)], axis=1)
            T = np.empty((n, 3, 3))
            T[:, :, 0] = a0
            T[:, :, 1] = a1
            cached = _Parts(np.ascontiguousarray(Z), T, obj)
            self._parts[key] = cached
        return cached

    def optical_points(self, pose: DockPose, roles: Sequence[str]) -> NDArray[np.float64]:
        """The markers' corners in the optical frame at this pose, shape (4R, 3), in role order."""
        PD = self.parts(roles).Z @ _coefficients(pose.x, pose.y, pose.yaw)
        return np.ascontiguousarray(PD[:, 0].reshape(-1, 3))

    def project(self, pose: DockPose, roles: Sequence[str]) -> NDArray[np.float64]:
        """The corner pixels of these markers at this pose, through the lens, shape (4R, 2)."""
        px, _ = cv2.projectPoints(self.optical_points(pose, roles), _ZERO3, _ZERO3, self._K, self._dist)
        return np.asarray(px, dtype=np.float64).reshape(-1, 2)

    def jacobian(
        self, pose: DockPose, roles: Sequence[str], pitch_offset: float | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Corner pixels, shape (4R, 2), and their Jacobian w.r.t. (x, y, yaw), shape (8R, 3), rows u0, v0, u1, ...;
        with ``pitch_offset`` (rad) at that camera pitch offset and w.r.t. (x, y, yaw, δ), shape (8R, 4).

        Raises:
            InputError: a corner is not in front of the camera.
        """
        parts = self.parts(roles)
        if pitch_offset is None:
            X = self._design(pose.x, pose.y, pose.yaw, parts, None)
        else:
            X = self._design4(pose.x, pose.y, pose.yaw, float(pitch_offset), parts, None)
        if X is None:
            raise InputError("a marker corner is behind the camera at this pose")
        k = X.shape[2] - 1
        return X[:, :, k].copy(), X[:, :, :k].reshape(-1, k).copy()

    def _design(
        self, x: float, y: float, yaw: float, parts: _Parts, img: NDArray[np.float64] | None
    ) -> NDArray[np.float64] | None:
        """[J | r] per corner, shape (N, 2, 4): the Jacobian rows and the residual (pixel − img), or the
        pixels themselves when ``img`` is None; None when a point is not in front of the camera."""
        PD = parts.Z @ _coefficients(x, y, yaw)
        P = PD[:, 0].reshape(-1, 3)
        if min(P[:, 2].tolist()) <= _MIN_DEPTH:
            return None
        px, jac = cv2.projectPoints(P, _ZERO3, _ZERO3, self._K, self._dist)
        T = parts.T.copy()
        T[:, :, 2] = PD[:, 1].reshape(-1, 3)
        X = np.empty((len(T), 2, 4))
        # With rvec = tvec = 0 the tvec columns of projectPoints' Jacobian are dπ/dP per point.
        np.matmul(jac[:, 3:6].reshape(-1, 2, 3), T, out=X[:, :, :3])
        X[:, :, 3] = px.reshape(-1, 2) if img is None else px.reshape(-1, 2) - img
        return X

    def _design4(
        self,
        x: float,
        y: float,
        yaw: float,
        delta: float,
        parts: _Parts,
        img: NDArray[np.float64] | None,
        axis: int = PITCH_AXIS,
    ) -> NDArray[np.float64] | None:
        """``_design`` with the camera turned by δ about its optical x axis (pitch) or z axis (roll, ``axis``
        ROLL_AXIS): [J | r] of shape (N, 2, 5), columns x, y, yaw, δ; still one projection."""
        c, s = math.cos(delta), math.sin(delta)
        # G = [R(δ); S·R(δ)] with S·Q = e × Q for the axis e: one product gives Q = R·P, dQ/dyaw = R·dP/dyaw
        # and dQ/dδ = e × Q: (0, −Q_z, Q_y) about x, (−Q_y, Q_x, 0) about z.
        if axis == PITCH_AXIS:
            G = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c], [0.0, 0.0, 0.0], [0.0, -s, -c], [0.0, c, -s]])
        else:
            G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0], [-s, -c, 0.0], [c, -s, 0.0], [0.0, 0.0, 0.0]])
        M = np.matmul(G, (parts.Z @ _coefficients(x, y, yaw)).reshape(-1, 3, 2))
        Q = np.ascontiguousarray(M[:, :3, 0])
        if min(Q[:, 2].tolist()) <= _MIN_DEPTH:
            return None
        px, jac = cv2.projectPoints(Q, _ZERO3, _ZERO3, self._K, self._dist)
        T = np.empty((len(Q), 3, 4))
        T[:, :, :2] = G[:3] @ self._A[:, :2]  # dQ/dx, dQ/dy = R·a₀, R·a₁
        T[:, :, 2] = M[:, :3, 1]
        T[:, :, 3] = M[:, 3:, 0]
        X = np.empty((len(Q), 2, 5))
        np.matmul(jac[:, 3:6].reshape(-1, 2, 3), T, out=X[:, :, :4])
        X[:, :, 4] = px.reshape(-1, 2) if img is None else px.reshape(-1, 2) - img
        return X


@dataclass(frozen=True)
class _Parts:
    """Per-corner terms of a role set: Z (3N, 5) = [U V W a₀ a₁] per coordinate, T (N, 3, 3) with dP/dx,
    dP/dy filled in (dP/dyaw goes in column 2), and the dock-frame points (N, 3)."""

    Z: NDArray[np.float64]
    T: NDArray[np.float64]
    obj: NDArray[np.float64]


def _coefficients(x: float, y: float, yaw: float) -> NDArray[np.float64]:
    """Z @ this = [P, dP/dyaw] stacked per coordinate."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c], [1.0, 0.0], [x, 0.0], [y, 0.0]])


@functools.lru_cache(maxsize=16)
def planar_model(camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> PlanarModel:
    """The (cached) PlanarModel of a camera, layout and robot."""
    return PlanarModel(camera, layout, robot)


# --- noise -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Whitening:
    """How to whiten corner residuals: by a scalar, per row (2N,), or by per-corner 2x2 matrices (N, 2, 2)."""

    scalar: float = 1.0
    rows: NDArray[np.float64] | None = None
    blocks: NDArray[np.float64] | None = None

    def normal(self, X: NDArray[np.float64]) -> list[list[float]]:
        """[J | r]ᵀ W [J | r] as nested lists (4x4, 5x5 with the pitch): JᵀWJ, JᵀWr and rᵀWr in one product."""
        k = X.shape[2]
        if self.blocks is not None:
            Xw = np.matmul(self.blocks, X).reshape(-1, k)
        elif self.rows is not None:
            Xw = X.reshape(-1, k) * self.rows[:, None]
        else:
            Xf = X.reshape(-1, k)
            return (Xf.T @ Xf * self.scalar**2).tolist()  # type: ignore[no-any-return]
        return (Xw.T @ Xw).tolist()  # type: ignore[no-any-return]


def _whitening(corner_sigma: float | ArrayLike, n: int) -> _Whitening:
    """Whitening of ``n`` corners' residuals from a sigma (px): scalar, per corner (n,), per axis (n, 2),
    or a 2x2 covariance (px²) per corner (n, 2, 2)."""
    if isinstance(corner_sigma, int | float):
        s = float(corner_sigma)
        if not (s > 0 and math.isfinite(s)):
            raise InputError(f"corner sigma must be positive, got {corner_sigma}")
        return _Whitening(scalar=1.0 / s)
    a = np.asarray(corner_sigma, dtype=np.float64)
    if a.ndim == 0:
        return _whitening(float(a), n)
    if a.shape == (n, 2, 2):
        if not np.all(np.isfinite(a)) or not np.allclose(a, np.swapaxes(a, 1, 2)):
            raise InputError("corner covariances must be finite symmetric 2x2 matrices")
        try:
            L = np.linalg.cholesky(a)
        except np.linalg.LinAlgError:
            raise InputError("corner covariances must be positive definite") from None
        return _Whitening(blocks=np.ascontiguousarray(np.linalg.inv(L)))
    if a.shape in ((n,), (n, 2)):
        if not np.all(np.isfinite(a) & (a > 0)):
            raise InputError("corner sigmas must be positive and finite")
        rows = np.repeat(1.0 / a, 2) if a.ndim == 1 else (1.0 / a).reshape(-1)
        return _Whitening(rows=np.ascontiguousarray(rows))
    raise InputError(f"corner sigma must be a number or have shape ({n},), ({n}, 2) or ({n}, 2, 2), got {a.shape}")


# --- the solver ----------------------------------------------------------------------------------------


def _stack_corners(corners: Mapping[str, ArrayLike], layout: DockLayout) -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Roles (in the layout's order) and their corner pixels stacked and flattened, shape (8R,)."""
    roles = tuple(r for r in layout.roles if r in corners)
    if len(roles) != len(corners):
        unknown = sorted(set(corners) - set(layout.roles))
        raise InputError(f"unknown marker role '{unknown[0]}' (expected {', '.join(layout.roles)})")
    if not roles:
        raise InputError("no marker corners to fit")
    parts = []
    for r in roles:
        c = np.asarray(corners[r], dtype=np.float64)
        if c.size != 8:
            raise InputError(f"marker {r}: expected 4 corners (4, 2), got shape {c.shape}")
        parts.append(c.reshape(8))
    img = np.concatenate(parts) if len(parts) > 1 else parts[0]
    if not np.all(np.isfinite(img)):
        raise InputError("corner pixels must be finite")
    return roles, img


def _theta(pose: DockPose) -> NDArray[np.float64]:
    return np.array([pose.x, pose.y, pose.yaw], dtype=np.float64)


def solve_planar(
    corners: Mapping[str, ArrayLike],
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    *,
    start: DockPose,
    corner_sigma: float | ArrayLike = DEFAULT_CORNER_SIGMA_PX,
    prior: PosePrior | None = None,
    max_iterations: int = _MAX_ITERATIONS,
    tolerance: float = _TOLERANCE,
    pitch_sd: float | None = None,
    roll_sd: float | None = None,
) -> PlanarFit:
    """The maximum-likelihood (or, with a prior, maximum a posteriori) DockPose from marker corners.

    Levenberg–Marquardt over (x, y, yaw) with the analytic Jacobian, from ``start``; one projection per
    iteration, stopping when the next step is below a thousandth of the estimate's standard deviation
    (δᵀHδ < 1e-6) or below ``tolerance`` (metres and radians).

    Args:
        corners: pixel corners per marker role, ArUco order (TL, TR, BR, BL), shape (4, 2) each; any subset.
        camera, layout, robot: the lens, the marker layout and the camera mount.
        start: the pose to start from.
        corner_sigma: corner noise in pixels: a number (iid), one per corner (N,), per corner and axis
            (N, 2), or a 2x2 covariance per corner (N, 2, 2) in px², N = 4 × markers in role order
            (left, center, right).
        prior: a Gaussian prior on the pose, or None.
        max_iterations: cap on projections evaluated.
        tolerance: absolute step size (m, rad) below which the fit has converged in any case.
        pitch_sd: None fits (x, y, yaw) with the mount as given; a number (rad) also fits the camera's
            pitch offset δ about its optical x axis, with the prior δ ~ N(0, pitch_sd²), starting at 0.
        roll_sd: the same for a roll offset about the optical z axis (``roll_offset``); not with pitch_sd.

    Returns:
        The fit; ``converged`` is False when the cap was hit or no valid pose was reachable (then the
        pose is the best one seen, possibly the start, and the cost may be infinite).

    Raises:
        InputError: unknown roles, wrong shapes, non-finite pixels, bad sigma, prior or pitch_sd.
    """
    roles, img = _stack_corners(corners, layout)
    model = planar_model(camera, layout, robot)
    parts = model.parts(roles)
    white = _whitening(corner_sigma, len(parts.obj))
    nuisance = _nuisance(pitch_sd, roll_sd)
    return _solve(model, roles, parts, img, white, _theta(start), prior, nuisance, max_iterations, tolerance)


def _nuisance(pitch_sd: float | None, roll_sd: float | None) -> tuple[float, int] | None:
    """(1/σ², axis) of the camera turn to fit, or None for the 3-DoF fit."""
    if pitch_sd is not None and roll_sd is not None:
        raise InputError("fit a camera pitch or a roll offset, not both at once")
    if pitch_sd is not None:
        return _pitch_information(pitch_sd), PITCH_AXIS
    if roll_sd is not None:
        return _pitch_information(roll_sd), ROLL_AXIS
    return None


def _pitch_information(pitch_sd: float) -> float:
    """1/σ² of the pitch prior; raises InputError unless σ is a positive finite number."""
    try:
        sd = float(pitch_sd)
    except (TypeError, ValueError):
        raise InputError(f"pitch_sd must be a number of radians or None, got {pitch_sd!r}") from None
    if not (sd > 0 and math.isfinite(sd)):
        raise InputError(f"pitch_sd must be positive and finite, got {pitch_sd}")
    return 1.0 / (sd * sd)


def _solve(
    model: PlanarModel,
    roles: tuple[str, ...],
    parts: _Parts,
    img: NDArray[np.float64],
    white: _Whitening,
    theta: NDArray[np.float64],
    prior: PosePrior | None,
    nuisance: tuple[float, int] | None,
    max_iterations: int,
    tolerance: float,
) -> PlanarFit:
    """Levenberg–Marquardt from ``theta``: over (x, y, yaw), compiled (``_lm3``); with ``nuisance`` (1/σ², axis, as
    ``_nuisance`` gives it) over (x, y, yaw, δ), δ a turn of the camera about that optical axis under the prior
    δ ~ N(0, σ²), from δ = 0 (``_evaluate4``)."""
    if nuisance is None:
        problem = _problem(model, parts, img, white, prior)
        return _planar_fit(roles, *_lm3(problem, np.array(theta, dtype=np.float64), max_iterations, tolerance))
    problem4, prior_information = _problem4(model, parts, img, white, prior, *nuisance)
    start = np.array([theta[0], theta[1], theta[2], 0.0])
    th, ok, cost, cov, cov_res, scale, X, iterations, converged = levenberg_marquardt(
        problem4, start, prior_information, max_iterations, tolerance, _evaluate4, step4, marginal4
    )
    # The squares summed by BLAS, as this fit always has (``_lm3`` adds them one by one: another last bit).
    r = X[:, :, 4].ravel()
    rms = math.sqrt(float(r @ r) / len(parts.obj)) if ok else math.inf
    offsets = _offsets(float(th[3]), nuisance[1])
    return _planar_fit(roles, th[:3], ok, cost, cov, cov_res, scale, rms, iterations, converged, offsets)


def _problem(
    model: PlanarModel, parts: _Parts, img: NDArray[np.float64], white: _Whitening, prior: PosePrior | None
) -> tuple[Any, ...]:
    """The fit's fixed inputs, as one tuple for the kernels (``_evaluate`` unpacks it)."""
    info = prior.information() if prior is not None else _ZERO33
    mu = _theta(prior.mean) if prior is not None else _ZERO3
    mode = 2 if white.blocks is not None else 1 if white.rows is not None else 0
    rows = white.rows if white.rows is not None else _NO_ROWS
    blocks = white.blocks if white.blocks is not None else _NO_BLOCKS
    return (
        parts.Z,
        parts.T,
        img.reshape(-1, 2),
        mode,
        float(white.scalar),
        rows,
        blocks,
        model.lens,
        prior is not None,
        info,
        mu,
    )


def _planar_fit(
    roles: tuple[str, ...],
    th_: NDArray[np.float64],
    ok: bool,
    cost: float,
    cov: NDArray[np.float64],
    cov_res: NDArray[np.float64],
    scale: float,
    rms: float,
    iterations: int,
    converged: bool,
    offsets: tuple[float, float] = (0.0, 0.0),
) -> PlanarFit:
    """The PlanarFit of a fit's results (``_lm3``'s, with the camera's (pitch, roll) offsets)."""
    x, y, yaw = th_.tolist()
    pose = DockPose(x, y, wrap_angle(yaw))
    if not ok:
        inf = np.full((3, 3), np.inf)
        return PlanarFit(pose, inf, inf, math.nan, math.inf, math.inf, iterations, False, roles, *offsets)
    return PlanarFit(pose, cov, cov_res, scale, rms, cost, iterations, converged, roles, *offsets)


_ZERO33 = np.zeros((3, 3))
_NO_ROWS = np.zeros(0)
_NO_BLOCKS = np.zeros((0, 2, 2))


@kernel
def _lm3(
    problem: tuple[Any, ...], theta: Any, max_iterations: int, tolerance: float
) -> tuple[Any, bool, float, Any, Any, float, float, int, bool]:  # pragma: no cover - compiled
    """``levenberg_marquardt`` over (x, y, yaw) from ``theta``, compiled, with the model ``_evaluate``.

    ``problem``: the fit's fixed inputs, as ``_evaluate`` reads them. Returns the pose, whether any pose could be
    evaluated, and, from the last accepted evaluation, the cost (prior included), the covariance (F + Λ)⁻¹, the
    residual-scaled one s²(F + s²Λ)⁻¹, the noise scale s and the RMS residual (px); then the projections evaluated
    and whether it converged.
    """
    prior_information = problem[9] if problem[8] else np.zeros((3, 3))
    th, ok, cost, cov, cov_res, scale, X, iterations, converged = compiled_levenberg_marquardt(
        problem, theta, prior_information, max_iterations, tolerance, _evaluate, step3, inverse3
    )
    rms = np.sqrt(np.sum(X[:, :, 3] ** 2) / X.shape[0]) if ok else np.inf
    return th, ok, cost, cov, cov_res, scale, rms, iterations, converged


@kernel
def _evaluate(  # noqa: PLR0912 - a compiled kernel
    th: Any, problem: tuple[Any, ...], X: Any, N: Any, H: Any, g: Any
) -> tuple[bool, float]:  # pragma: no cover - compiled
    """The design X = [J | r] (pixel − target), N = XᵀWX, H = JᵀWJ (+Λ), g = JᵀWr (+Λe) at pose ``th``,
    filled in place, and the cost; False when a corner is not in front of the camera or the cost is not finite.

    ``problem``: ``Z``, ``Tm`` the role set's ``_Parts``; ``target`` (N, 2) the corner pixels; the whitening,
    ``mode`` 0 by ``scale``, 1 by ``rows`` (2N,), 2 by ``blocks`` (N, 2, 2); the lens (``lens_of``); and the
    prior's information and mean when ``use_prior``.
    """
    Z, Tm, target, mode, scale, rows, blocks, lens, use_prior, info, mu = problem
    c, s = np.cos(th[2]), np.sin(th[2])
    x, y = th[0], th[1]
    # Scalars, not small arrays: an allocation per corner and evaluation cost more than the arithmetic.
    for i in range(Tm.shape[0]):
        r0, r1, r2 = 3 * i, 3 * i + 1, 3 * i + 2
        p0 = Z[r0, 0] * c + Z[r0, 1] * s + Z[r0, 2] + Z[r0, 3] * x + Z[r0, 4] * y
        p1 = Z[r1, 0] * c + Z[r1, 1] * s + Z[r1, 2] + Z[r1, 3] * x + Z[r1, 4] * y
        p2 = Z[r2, 0] * c + Z[r2, 1] * s + Z[r2, 2] + Z[r2, 3] * x + Z[r2, 4] * y
        # dP/dyaw
        d0, d1, d2 = Z[r0, 1] * c - Z[r0, 0] * s, Z[r1, 1] * c - Z[r1, 0] * s, Z[r2, 1] * c - Z[r2, 0] * s
        if p2 <= _MIN_DEPTH:
            return False, np.inf
        u, v, j00, j01, j02, j10, j11, j12 = project(lens, p0, p1, p2)
        for col in range(2):
            X[i, 0, col] = j00 * Tm[i, 0, col] + j01 * Tm[i, 1, col] + j02 * Tm[i, 2, col]
            X[i, 1, col] = j10 * Tm[i, 0, col] + j11 * Tm[i, 1, col] + j12 * Tm[i, 2, col]
        X[i, 0, 2] = j00 * d0 + j01 * d1 + j02 * d2
        X[i, 1, 2] = j10 * d0 + j11 * d1 + j12 * d2
        X[i, 0, 3] = u - target[i, 0]
        X[i, 1, 3] = v - target[i, 1]
    N[:] = 0.0
    for i in range(Tm.shape[0]):
        if mode == 0:
            a00, a01, a10, a11 = scale, 0.0, 0.0, scale
        elif mode == 1:
            a00, a01, a10, a11 = rows[2 * i], 0.0, 0.0, rows[2 * i + 1]
        else:
            a00, a01, a10, a11 = blocks[i, 0, 0], blocks[i, 0, 1], blocks[i, 1, 0], blocks[i, 1, 1]
        for a in range(4):
            wa0 = a00 * X[i, 0, a] + a01 * X[i, 1, a]
            wa1 = a10 * X[i, 0, a] + a11 * X[i, 1, a]
            for b in range(a, 4):
                N[a, b] += wa0 * (a00 * X[i, 0, b] + a01 * X[i, 1, b]) + wa1 * (a10 * X[i, 0, b] + a11 * X[i, 1, b])
    for a in range(4):
        for b in range(a):
            N[a, b] = N[b, a]
    cost = N[3, 3]
    for k in range(3):
        g[k] = N[k, 3]
        for m in range(3):
            H[k, m] = N[k, m]
    if use_prior:
        e0, e1, e2 = x - mu[0], y - mu[1], (th[2] - mu[2] + np.pi) % (2.0 * np.pi) - np.pi
        for k in range(3):
            ie = info[k, 0] * e0 + info[k, 1] * e1 + info[k, 2] * e2
            g[k] += ie
            cost += (e0 if k == 0 else e1 if k == 1 else e2) * ie
            for m in range(3):
                H[k, m] += info[k, m]
    return bool(np.isfinite(cost)), cost


# --- the model with a camera turn ------------------------------------------------------------------------


def _problem4(
    model: PlanarModel,
    parts: _Parts,
    img: NDArray[np.float64],
    white: _Whitening,
    prior: PosePrior | None,
    turn_information: float,
    axis: int,
) -> tuple[tuple[Any, ...], NDArray[np.float64]]:
    """The fixed inputs of the fit with a camera turn δ about the optical ``axis`` (PITCH_AXIS or ROLL_AXIS), as
    ``_evaluate4`` reads them, and the priors' 4x4 information: the pose prior's and 1/σ² of δ's."""
    info = prior.information() if prior is not None else None
    mu = (prior.mean.x, prior.mean.y, prior.mean.yaw) if prior is not None else (0.0, 0.0, 0.0)
    prior_information = np.zeros((4, 4))
    prior_information[3, 3] = turn_information
    if info is not None:
        prior_information[:3, :3] = info
    info_rows = info.tolist() if info is not None else None
    return (model, parts, img.reshape(-1, 2), white, axis, turn_information, info_rows, mu), prior_information


def _evaluate4(
    th: NDArray[np.float64],
    problem: tuple[Any, ...],
    X: NDArray[np.float64],
    N: NDArray[np.float64],
    H: NDArray[np.float64],
    g: NDArray[np.float64],
) -> tuple[bool, float]:
    """``_evaluate`` at (x, y, yaw, δ) through OpenCV (``PlanarModel._design4``), with the prior on δ: fills
    X = [J | r] (N, 2, 5), N = XᵀWX, H = JᵀWJ + priors and g = JᵀWr + priors, and returns whether the pose is valid
    and the cost."""
    model, parts, target, white, axis, turn_information, info, mu = problem
    x, y, yaw, delta = th.tolist()
    design = model._design4(x, y, yaw, delta, parts, target, axis)
    if design is None:
        return False, math.inf
    normal = white.normal(design)
    h = [normal[0][:4], normal[1][:4], normal[2][:4], normal[3][:4]]
    grad = [normal[0][4], normal[1][4], normal[2][4], normal[3][4]]
    cost = normal[4][4]
    h[3][3] += turn_information
    grad[3] += turn_information * delta
    cost += turn_information * delta * delta
    if info is not None:
        e = (x - mu[0], y - mu[1], wrap_angle(yaw - mu[2]))
        for k in range(3):
            ie = info[k][0] * e[0] + info[k][1] * e[1] + info[k][2] * e[2]
            grad[k] += ie
            cost += e[k] * ie
            for m in range(3):
                h[k][m] += info[k][m]
    if not math.isfinite(cost):
        return False, cost
    X[:], N[:], H[:], g[:] = design, normal, h, grad
    return True, cost


def _offsets(delta: float, axis: int) -> tuple[float, float]:
    """(pitch_offset, roll_offset) of a fitted turn δ about ``axis``."""
    return (delta, 0.0) if axis == PITCH_AXIS else (0.0, delta)


def pose_information(
    pose: DockPose,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    roles: Sequence[str],
    corner_sigma: float | ArrayLike,
    pitch_sd: float | None = None,
) -> NDArray[np.float64]:
    """The Cramér–Rao bound on (x m, y m, yaw rad) at a true pose, with the camera pitch as a nuisance.

    Without ``pitch_sd`` this is ``crlb.crlb`` (the mount trusted); with it, the (x, y, yaw) block of the
    inverse of the 4x4 information JᵀWJ + diag(0, 0, 0, 1/pitch_sd²) at δ = 0: the bound of a fit that
    estimates the pitch under that prior. The ratio of the two is what freeing the pitch costs.

    Args:
        pose: the true DockPose.
        camera, layout, robot: the set-up.
        roles: the markers observed.
        corner_sigma: as in ``solve_planar`` (a number, (N,), (N, 2) or (N, 2, 2)).
        pitch_sd: the pitch prior's standard deviation (rad), or None.

    Returns:
        The 3x3 covariance bound; infinite where the pose is unobservable.

    Raises:
        InputError: unknown or no roles, a corner behind the camera, bad sigma or pitch_sd.
    """
    model = planar_model(camera, layout, robot)
    parts = model.parts(roles)
    white = _whitening(corner_sigma, len(parts.obj))
    pitch_info = _pitch_information(pitch_sd) if pitch_sd is not None else None
    X = model._design4(pose.x, pose.y, pose.yaw, 0.0, parts, None)
    if X is None:
        raise InputError("a marker corner is behind the camera at this pose")
    F = [row[:4] for row in white.normal(X)[:4]]
    if pitch_info is None:
        return inverse3(np.array([row[:3] for row in F[:3]]), 1.0)
    F[3][3] += pitch_info
    return marginal3(F, 1.0)
