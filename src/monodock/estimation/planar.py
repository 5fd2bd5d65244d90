"""Maximum-likelihood planar PnP: the DockPose (x, y, yaw) that best explains the markers' corner pixels.

The robot stands on the floor and the camera mount is known, so the dock has three degrees of freedom in
base_link, not six. Fitting those three directly, through the real lens, is the efficient estimator for
Gaussian corner noise (its covariance reaches the Cramér–Rao bound of ``monodock.estimation.crlb``) and it cannot
tilt the dock off the floor, which is where 6-DoF PnP goes wrong on small, far markers.

Model: a corner p (dock frame) lands at P = optical_T_base · base_T_dock(x, y, yaw) · p in the optical frame
and at pixel π(P) through the lens. ``cv2.projectPoints(P, 0, 0, K, dist)`` returns dπ/dtvec per point,
which with a zero pose is dπ/dP; the chain rule with dP/d(x, y, yaw) gives the analytic Jacobian.

A lone small marker seen from afar has two planar minima (the yaw sign ambiguity of weak perspective):
``planar_candidates`` starts from both IPPE solutions and returns every distinct local minimum with its cost.

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
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.compiled import kernel
from monodock.core.layout import ROLES, DockLayout
from monodock.core.lens import lens_of, project
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.robot import RobotConfig
from monodock.errors import InputError

__all__ = [
    "DEFAULT_CORNER_SIGMA_PX",
    "PlanarFit",
    "PlanarModel",
    "PosePrior",
    "board_fit",
    "board_fit_stacked",
    "board_start",
    "planar_candidates",
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
# Converged when the next step would lower the cost (χ²) by less than this: a step of 1e-3 standard deviations.
_CHI2_TOLERANCE = 1e-6
# Default cap on the projections a fit evaluates, and the step (m, rad) below which it has converged in any case.
_MAX_ITERATIONS = 20
_TOLERANCE = 1e-9
FIT_ITERATIONS, FIT_TOLERANCE = _MAX_ITERATIONS, _TOLERANCE  # the board fit's, for a caller's compiled copy of it
# Two starts closer than this (metres and radians) are one.
_SAME_START = 0.01
# Two converged minima closer than this (metres and radians) are the same one.
_SAME_MINIMUM = 1e-4


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
                if r not in ROLES:
                    raise InputError(f"unknown marker role '{r}' (expected {', '.join(ROLES)})")
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


def _stack_corners(corners: Mapping[str, ArrayLike]) -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Roles (in the layout's order) and their corner pixels stacked and flattened, shape (8R,)."""
    roles = tuple(r for r in ROLES if r in corners)
    if len(roles) != len(corners):
        unknown = sorted(set(corners) - set(ROLES))
        raise InputError(f"unknown marker role '{unknown[0]}' (expected {', '.join(ROLES)})")
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
    roles, img = _stack_corners(corners)
    model = planar_model(camera, layout, robot)
    parts = model.parts(roles)
    white = _whitening(corner_sigma, len(parts.obj))
    nuisance = _nuisance(pitch_sd, roll_sd)
    if nuisance is None:
        return _solve(model, roles, parts, img, white, _theta(start), prior, max_iterations, tolerance)
    return _solve4(model, roles, parts, img, white, _theta(start), prior, *nuisance, max_iterations, tolerance)


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


def _solve3(A: list[list[float]], b: list[float]) -> tuple[float, float, float] | None:
    """x with A x = b for a 3x3 system (``_solve3_into``), None when A is singular."""
    out = np.empty(3)
    if not _solve3_into(np.array(A, dtype=np.float64), np.array(b, dtype=np.float64), out):
        return None
    x0, x1, x2 = out.tolist()
    return x0, x1, x2


def _solve(
    model: PlanarModel,
    roles: tuple[str, ...],
    parts: _Parts,
    img: NDArray[np.float64],
    white: _Whitening,
    theta: NDArray[np.float64],
    prior: PosePrior | None,
    max_iterations: int,
    tolerance: float,
) -> PlanarFit:
    """Levenberg–Marquardt (``_lm3``, compiled) from ``theta``."""
    problem = _problem(model, parts, img, white, prior)
    return _planar_fit(roles, *_lm3(problem, np.array(theta, dtype=np.float64), max_iterations, tolerance))


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
) -> PlanarFit:
    """The PlanarFit of ``_lm3``'s results."""
    x, y, yaw = th_.tolist()
    pose = DockPose(x, y, wrap_angle(yaw))
    if not ok:
        inf = np.full((3, 3), np.inf)
        return PlanarFit(pose, inf, inf, math.nan, math.inf, math.inf, iterations, False, roles)
    return PlanarFit(pose, cov, cov_res, scale, rms, cost, iterations, converged, roles)


_ZERO33 = np.zeros((3, 3))
_NO_ROWS = np.zeros(0)
_NO_BLOCKS = np.zeros((0, 2, 2))


@kernel
def _lm3(
    problem: tuple[Any, ...], theta: Any, max_iterations: int, tolerance: float
) -> tuple[Any, bool, float, Any, Any, float, float, int, bool]:  # pragma: no cover - compiled
    """Levenberg–Marquardt over (x, y, yaw) from ``theta``, one projection (with Jacobian) per iteration.

    ``problem``: the fit's fixed inputs, as ``_evaluate`` reads them. Stops when the next step is below a
    thousandth of the estimate's standard deviation (δᵀHδ < ``_CHI2_TOLERANCE``) or below ``tolerance``.
    Returns the pose, whether any pose could be evaluated, and, from the last accepted evaluation, the cost
    (prior included), the covariance (F + Λ)⁻¹ and the residual-scaled one s²(F + s²Λ)⁻¹ (F the Fisher
    information at unit corner sigma, s the noise scale √(χ²/dof)), s and the RMS residual (px); then the
    projections evaluated and whether it converged.
    """
    n = problem[1].shape[0]
    X, Xt = np.empty((n, 2, 4)), np.empty((n, 2, 4))
    N, Nt = np.empty((4, 4)), np.empty((4, 4))
    H, Ht = np.empty((3, 3)), np.empty((3, 3))
    g, gt = np.empty(3), np.empty(3)
    th = theta.copy()
    ok, cost = _evaluate(th, problem, X, N, H, g)
    iterations, converged, lam = 1, False, 1e-4
    damped, step, trial = np.empty((3, 3)), np.empty(3), np.empty(3)
    while ok and iterations < max_iterations:
        damped[:] = H
        for k in range(3):
            damped[k, k] *= 1.0 + lam
        if not _solve3_into(damped, -g, step):
            break
        # The step's size in standard deviations of the estimate (δᵀHδ, the cost it would remove): once
        # it is a thousandth of one, further steps change nothing that the noise lets anyone measure.
        # With noise, Gauss–Newton converges linearly (rate ~ residual size), so this saves iterations.
        decrease = 0.0
        for k in range(3):
            decrease += step[k] * (H[k, 0] * step[0] + H[k, 1] * step[1] + H[k, 2] * step[2])
        if decrease < _CHI2_TOLERANCE or max(abs(step[0]), abs(step[1]), abs(step[2])) < tolerance:
            th += step
            converged = True
            break
        trial[:] = th + step
        ok_t, cost_t = _evaluate(trial, problem, Xt, Nt, Ht, gt)
        iterations += 1
        if ok_t and cost_t <= cost:
            th[:], X[:], N[:], H[:], g[:], cost = trial, Xt, Nt, Ht, gt, cost_t
            lam = max(lam * 0.1, 1e-12)
        else:
            lam *= 10.0
            if lam > 1e12:
                break
    if not ok:
        return th, ok, np.inf, N, N, np.nan, np.inf, iterations, False
    n_dof = 2 * n - 3
    scale = np.sqrt(N[3, 3] / n_dof) if n_dof > 0 else np.nan
    lam_ = problem[9] if problem[8] else np.zeros((3, 3))
    cov = _inverse3(N[:3, :3] + lam_, 1.0)
    # (F/s² + Λ)⁻¹ written as s²(F + s²Λ)⁻¹, which stays finite for exact corners (s = 0).
    cov_res = _inverse3(N[:3, :3] + scale * scale * lam_, scale * scale)
    rms = np.sqrt(np.sum(X[:, :, 3] ** 2) / n)
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


@kernel
def _solve3_into(A: Any, b: Any, out: Any) -> bool:  # pragma: no cover - compiled
    """out = x with A x = b for a 3x3 system, by cofactors; False when A is singular."""
    a, b_, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 0], A[1, 1], A[1, 2]
    g, h, i = A[2, 0], A[2, 1], A[2, 2]
    c0, c1, c2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c0 + b_ * c1 + c * c2
    if det == 0.0 or not np.isfinite(det):
        return False
    r0, r1, r2 = b[0], b[1], b[2]
    out[0] = (r0 * c0 + r1 * (c * h - b_ * i) + r2 * (b_ * f - c * e)) / det
    out[1] = (r0 * c1 + r1 * (a * i - c * g) + r2 * (c * d - a * f)) / det
    out[2] = (r0 * c2 + r1 * (b_ * g - a * h) + r2 * (a * e - b_ * d)) / det
    return True


@kernel
def _inverse3(m: NDArray[np.float64], factor: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """factor · m⁻¹ for a 3x3 information matrix; infinite where it is singular (the pose is unobservable)."""
    out = np.empty((3, 3))
    a, b, c = m[0, 0], m[0, 1], m[0, 2]
    d, e, f = m[1, 0], m[1, 1], m[1, 2]
    g, h, i = m[2, 0], m[2, 1], m[2, 2]
    c0, c1, c2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c0 + b * c1 + c * c2
    if det == 0.0 or not np.isfinite(det) or not np.isfinite(factor):
        out[:] = np.inf if np.isfinite(factor) else np.nan
        return out
    k = factor / det
    out[0, 0], out[0, 1], out[0, 2] = c0 * k, (c * h - b * i) * k, (b * f - c * e) * k
    out[1, 0], out[1, 1], out[1, 2] = c1 * k, (a * i - c * g) * k, (c * d - a * f) * k
    out[2, 0], out[2, 1], out[2, 2] = c2 * k, (b * g - a * h) * k, (a * e - b * d) * k
    return out


# --- the solver with the camera's pitch offset ------------------------------------------------------------


def _solve4(
    model: PlanarModel,
    roles: tuple[str, ...],
    parts: _Parts,
    img: NDArray[np.float64],
    white: _Whitening,
    theta: NDArray[np.float64],
    prior: PosePrior | None,
    pitch_info: float,
    axis: int,
    max_iterations: int,
    tolerance: float,
) -> PlanarFit:
    """``_solve`` over (x, y, yaw, δ) with the prior δ ~ N(0, 1/pitch_info): the same loop, a 4x4 system.
    δ turns the camera about its optical ``axis`` (PITCH_AXIS or ROLL_AXIS)."""
    info = prior.information().tolist() if prior is not None else None
    mu = (prior.mean.x, prior.mean.y, prior.mean.yaw) if prior is not None else (0.0, 0.0, 0.0)
    target = img.reshape(-1, 2)
    Evaluation = tuple[float, list[list[float]], list[float], NDArray[np.float64], list[list[float]]]

    def evaluate(th: list[float]) -> Evaluation | None:
        """Cost, H = JᵀWJ + priors, gradient, the design [J | r] and [J | r]ᵀW[J | r] at (x, y, yaw, δ)."""
        X = model._design4(th[0], th[1], th[2], th[3], parts, target, axis)
        if X is None:
            return None
        N = white.normal(X)
        H = [N[0][:4], N[1][:4], N[2][:4], N[3][:4]]
        g = [N[0][4], N[1][4], N[2][4], N[3][4]]
        cost = N[4][4]
        H[3][3] += pitch_info
        g[3] += pitch_info * th[3]
        cost += pitch_info * th[3] * th[3]
        if info is not None:
            e = (th[0] - mu[0], th[1] - mu[1], wrap_angle(th[2] - mu[2]))
            for k in range(3):
                ie = info[k][0] * e[0] + info[k][1] * e[1] + info[k][2] * e[2]
                g[k] += ie
                cost += e[k] * ie
                for m in range(3):
                    H[k][m] += info[k][m]
        if not math.isfinite(cost):
            return None
        return cost, H, g, X, N

    th = [float(theta[0]), float(theta[1]), float(theta[2]), 0.0]
    current = evaluate(th)
    iterations = 1
    converged = False
    lam = 1e-4
    while current is not None and iterations < max_iterations:
        cost, H, g, _, _ = current
        damped = [[H[k][m] * (1.0 + lam) if k == m else H[k][m] for m in range(4)] for k in range(4)]
        step = _solve4x4(damped, g)
        if step is None:
            break
        # δᵀHδ = −δᵀg − λ Σ H_kk δ_k² for the damped step: no second product needed.
        decrease = -(step[0] * g[0] + step[1] * g[1] + step[2] * g[2] + step[3] * g[3]) - lam * (
            H[0][0] * step[0] ** 2 + H[1][1] * step[1] ** 2 + H[2][2] * step[2] ** 2 + H[3][3] * step[3] ** 2
        )
        trial_th = [th[0] + step[0], th[1] + step[1], th[2] + step[2], th[3] + step[3]]
        if decrease < _CHI2_TOLERANCE or max(abs(d) for d in step) < tolerance:
            th = trial_th
            converged = True
            break
        trial = evaluate(trial_th)
        iterations += 1
        if trial is not None and trial[0] <= cost:
            current, th = trial, trial_th
            lam = max(lam * 0.1, 1e-12)
        else:
            lam *= 10.0
            if lam > 1e12:
                break
    pose = DockPose(th[0], th[1], wrap_angle(th[2]))
    if current is None:
        inf = np.full((3, 3), np.inf)
        return PlanarFit(pose, inf, inf, math.nan, math.inf, math.inf, iterations, False, roles, *_offsets(th[3], axis))
    cost, _, _, X, N = current
    offsets = _offsets(th[3], axis)
    return _planar_fit_result(pose, cost, X, N, len(parts.obj), info, pitch_info, iterations, converged, roles, offsets)


def _planar_fit_result(
    pose: DockPose,
    cost: float,
    X: NDArray[np.float64],
    N: list[list[float]],
    n: int,
    info: list[list[float]] | None,
    pitch_info: float,
    iterations: int,
    converged: bool,
    roles: tuple[str, ...],
    offsets: tuple[float, float],
) -> PlanarFit:
    """``_solve4``'s answer at its last evaluation: the (x, y, yaw) covariances with δ marginalised, by the
    corners' noise model and by the residuals, the scale and the RMS."""
    dof = 2 * n - 4
    chi2 = N[4][4]
    scale = math.sqrt(chi2 / dof) if dof > 0 else math.nan
    lam4 = [[0.0] * 4 for _ in range(4)]
    lam4[3][3] = pitch_info
    if info is not None:
        for k in range(3):
            lam4[k][:3] = info[k]
    cov = _marginal3([[N[k][m] + lam4[k][m] for m in range(4)] for k in range(4)], 1.0)
    # (F/s² + Λ)⁻¹ = s²(F + s²Λ)⁻¹, finite for exact corners (s = 0) as in ``_solve``.
    s2 = scale * scale
    cov_res = _marginal3([[N[k][m] + s2 * lam4[k][m] for m in range(4)] for k in range(4)], s2)
    r = X[:, :, 4].ravel()
    rms = math.sqrt(float(r @ r) / n)
    return PlanarFit(pose, cov, cov_res, scale, rms, cost, iterations, converged, roles, *offsets)


def _offsets(delta: float, axis: int) -> tuple[float, float]:
    """(pitch_offset, roll_offset) of a fitted turn δ about ``axis``."""
    return (delta, 0.0) if axis == PITCH_AXIS else (0.0, delta)


def _schur(H: list[list[float]]) -> tuple[list[list[float]], list[float], float] | None:
    """δ eliminated from a 4x4 information matrix: (A − b bᵀ/d, b, d) with H = [[A, b], [bᵀ, d]]; None if d ≤ 0.

    A − b bᵀ/d is the information of (x, y, yaw) with δ marginalised, so its inverse is their covariance.
    """
    d = H[3][3]
    if not d > 0.0 or not math.isfinite(d):
        return None
    b = [H[0][3], H[1][3], H[2][3]]
    return [[H[k][m] - b[k] * b[m] / d for m in range(3)] for k in range(3)], b, d


def _solve4x4(H: list[list[float]], g: list[float]) -> list[float] | None:
    """The step x with H x = −g for the 4x4 (x, y, yaw, δ) system, by the Schur complement on δ."""
    reduced = _schur(H)
    if reduced is None:
        return None
    A, b, d = reduced
    s = _solve3(A, [-g[k] + b[k] * g[3] / d for k in range(3)])
    if s is None:
        return None
    return [s[0], s[1], s[2], (-g[3] - b[0] * s[0] - b[1] * s[1] - b[2] * s[2]) / d]


def _marginal3(information: list[list[float]], factor: float) -> NDArray[np.float64]:
    """The (x, y, yaw) block of factor · information⁻¹ for a 4x4 information; infinite where it is singular."""
    reduced = _schur(information)
    if reduced is None:
        return np.full((3, 3), np.inf if math.isfinite(factor) else np.nan)
    return _inverse3(np.array(reduced[0]), factor)


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
        return _inverse3(np.array([row[:3] for row in F[:3]]), 1.0)
    F[3][3] += pitch_info
    return _marginal3(F, 1.0)


# --- candidate starts -------------------------------------------------------------------------------------


def _planar_start(
    rvec: ArrayLike, tvec: ArrayLike, base_T_optical: NDArray[np.float64], obj_T_dock: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """The planar pose (x, y, yaw) of one solvePnP solution (z, roll and pitch dropped), None if not finite."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    optical_T_obj = transforms.transform(R, np.asarray(tvec, dtype=np.float64).ravel())
    base_T_dock = base_T_optical @ optical_T_obj @ obj_T_dock
    return _theta(DockPose.from_matrix(base_T_dock)) if np.all(np.isfinite(base_T_dock)) else None


def board_start(
    corners: Mapping[str, ArrayLike], camera: CameraModel, layout: DockLayout, robot: RobotConfig
) -> DockPose | None:
    """A start for ``solve_planar`` from two or more markers: the board's better IPPE solution, as a planar pose.

    With two or more markers the board is wide enough that its IPPE solutions rarely fit alike (a lone
    far marker's do: use ``planar_candidates`` there). None for fewer than two markers or when IPPE fails.
    """
    roles, img = _stack_corners(corners)
    th = _board_theta(planar_model(camera, layout, robot), roles, img)
    return DockPose(float(th[0]), float(th[1]), float(th[2])) if th is not None else None


def board_fit(
    corners: Mapping[str, ArrayLike],
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    *,
    corner_sigma: float | ArrayLike = DEFAULT_CORNER_SIGMA_PX,
) -> PlanarFit | None:
    """``solve_planar`` from a start for two or more markers (``board_fit_stacked``); None for fewer, or where
    neither start can be found."""
    roles, img = _stack_corners(corners)
    if len(roles) < 2:
        return None
    model = planar_model(camera, layout, robot)
    return _board_fit(model, roles, img, _whitening(corner_sigma, 4 * len(roles)))


def board_fit_stacked(
    model: PlanarModel, roles: tuple[str, ...], corners: NDArray[np.float64], corner_sigma: NDArray[np.float64]
) -> PlanarFit | None:
    """``board_fit`` for a caller that has checked and stacked its inputs already (the fused method, per frame).

    Args:
        model: ``planar_model`` of the set-up.
        roles: the markers, in the layout's order.
        corners: their corner pixels stacked, shape (4R, 2), finite.
        corner_sigma: one positive finite sigma (px) per corner, shape (4R,).
    """
    if len(roles) < 2:
        return None
    rows = np.repeat(1.0 / corner_sigma, 2)
    parts = model.parts(roles)
    # _problem's tuple, built here: this runs on every frame.
    problem = (parts.Z, parts.T, corners, 1, 1.0, rows, _NO_BLOCKS, model.lens, False, _ZERO33, _ZERO3)
    return _board_fit(model, roles, corners, _Whitening(rows=rows), problem)


def _board_fit(
    model: PlanarModel,
    roles: tuple[str, ...],
    img: NDArray[np.float64],
    white: _Whitening,
    problem: tuple[Any, ...] | None = None,
) -> PlanarFit | None:
    """The fit of two or more markers from the floor-constrained linear start (``_floor_start``): the pose
    (x, y, yaw) that zeroes every corner's algebraic projection error, one 4x4 solve in compiled code, where
    IPPE's 6-DoF solution took longer than the fit itself. Where that start cannot be found or the fit from it
    does not converge, from the board's IPPE solution (``board_start``); None if there is none either."""
    parts = model.parts(roles)
    if problem is None:
        problem = _problem(model, parts, img, white, None)
    started, *result = _board_lm(problem, _MAX_ITERATIONS, _TOLERANCE)
    if started and result[1] and result[-1]:
        return _planar_fit(roles, *result)
    th = _board_theta(model, roles, img)
    if th is None:
        return None
    return _solve(model, roles, parts, img, white, th, None, _MAX_ITERATIONS, _TOLERANCE)


@kernel
def _board_lm(
    problem: tuple[Any, ...], max_iterations: int, tolerance: float
) -> tuple[bool, Any, bool, float, Any, Any, float, float, int, bool]:  # pragma: no cover - compiled
    """``_lm3`` from ``_floor_start``; first whether that start exists (if not, the rest is meaningless)."""
    Z, target, mode, scale, rows, lens = problem[0], problem[2], problem[3], problem[4], problem[5], problem[7]
    started, theta = _floor_start(Z, target, mode, scale, rows, lens)
    if not started:
        nan3 = np.full((3, 3), np.nan)
        return False, theta, False, np.inf, nan3, nan3, np.nan, np.inf, 0, False
    th, ok, cost, cov, cov_res, scale, rms, iterations, converged = _lm3(problem, theta, max_iterations, tolerance)
    return True, th, ok, cost, cov, cov_res, scale, rms, iterations, converged


@kernel
def _floor_start(  # noqa: PLR0912 - a compiled kernel
    Z: Any, target: Any, mode: int, scale: float, rows: Any, lens: Any
) -> tuple[bool, Any]:  # pragma: no cover - compiled
    """A start for the planar fit, (x, y, yaw), from corner pixels ``target`` (N, 2), and whether it exists.

    Each corner through the lens to undistorted normalised (u, v) (OpenCV's fixed-point iteration, 10 steps);
    then, with P = c U + s V + W + x a0 + y a1 (``PlanarModel``), P_x - u P_z = 0 and P_y - v P_z = 0 are
    linear in (c, s, x, y): least squares, each weighted as the whitening weighs its pixel (``rows`` with
    ``mode`` 1, else ``scale``: 2x2 blocks weigh alike), yaw = atan2(s, c). The floor is built in (4 unknowns,
    not 6), so it lands nearer the minimum than IPPE's start does.
    """
    fx, skew, cx, fy, cy = lens[0], lens[1], lens[2], lens[3], lens[4]
    k1, k2, p1, p2, k3 = lens[5], lens[6], lens[7], lens[8], lens[9]
    A = np.zeros((4, 4))
    b = np.zeros(4)
    row = np.empty(4)
    for i in range(target.shape[0]):
        y0 = (target[i, 1] - cy) / fy
        x0 = (target[i, 0] - cx - skew * y0) / fx
        x, y = x0, y0
        for _ in range(10):
            xx, yy, xy = x * x, y * y, x * y
            r2 = xx + yy
            icdist = 1.0 / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
            if lens[13] != 0.0:
                icdist *= 1.0 + r2 * (lens[10] + r2 * (lens[11] + r2 * lens[12]))
            if not icdist > 0.0:
                x, y = x0, y0
                break
            x = (x0 - (2.0 * p1 * xy + p2 * (r2 + 2.0 * xx))) * icdist
            y = (y0 - (p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy)) * icdist
        for d in range(2):
            m = x if d == 0 else y
            w = rows[2 * i + d] if mode == 1 else scale
            for k in range(4):
                col = k if k < 2 else k + 1  # U, V, (W), a0, a1
                row[k] = w * (Z[3 * i + d, col] - m * Z[3 * i + 2, col])
            rhs = -w * (Z[3 * i + d, 2] - m * Z[3 * i + 2, 2])
            for k in range(4):
                b[k] += row[k] * rhs
                for j in range(4):
                    A[k, j] += row[k] * row[j]
    theta = np.zeros(3)
    # Gauss-Jordan with partial pivoting on the 4x4 normal equations (a LAPACK call costs more here).
    for k in range(4):
        p = k
        for j in range(k + 1, 4):
            if abs(A[j, k]) > abs(A[p, k]):
                p = j
        if not abs(A[p, k]) > 0.0:  # singular, or NaN
            return False, theta
        if p != k:
            for j in range(4):
                A[k, j], A[p, j] = A[p, j], A[k, j]
            b[k], b[p] = b[p], b[k]
        for j in range(4):
            if j != k:
                f = A[j, k] / A[k, k]
                for m in range(k, 4):
                    A[j, m] -= f * A[k, m]
                b[j] -= f * b[k]
    q0, q1, q2, q3 = b[0] / A[0, 0], b[1] / A[1, 1], b[2] / A[2, 2], b[3] / A[3, 3]
    if not (np.isfinite(q0 + q1 + q2 + q3) and np.hypot(q0, q1) > 1e-3):
        return False, theta
    theta[0], theta[1], theta[2] = q2, q3, np.arctan2(q1, q0)
    return True, theta


def _board_theta(model: PlanarModel, roles: tuple[str, ...], img: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """``board_start`` as (x, y, yaw), from the stacked corners."""
    if len(roles) < 2:
        return None
    camera = model.camera
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            model.parts(roles).obj, img.reshape(-1, 2), camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE
        )
    except cv2.error:
        return None
    return _planar_start(rvecs[0], tvecs[0], model.base_T_optical, _EYE4) if n else None


_EYE4 = np.eye(4)


def _ippe_starts(roles: tuple[str, ...], img: NDArray[np.float64], model: PlanarModel) -> list[NDArray[np.float64]]:
    """Planar starts from every IPPE solution: each marker alone (IPPE_SQUARE) and, for several, the board."""
    camera, layout = model.camera, model.layout
    pixels = img.reshape(-1, 4, 2)
    starts: list[NDArray[np.float64]] = []

    def add(rvecs: Iterable[ArrayLike], tvecs: Iterable[ArrayLike], obj_T_dock: NDArray[np.float64]) -> None:
        for rv, tv in zip(rvecs, tvecs, strict=True):
            th = _planar_start(rv, tv, model.base_T_optical, obj_T_dock)
            if th is not None:
                starts.append(th)

    square = layout.corners_in_marker()
    for k, role in enumerate(roles):
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                square, pixels[k], camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
            )
        except cv2.error:
            continue
        if n:
            add(rvecs, tvecs, transforms.invert(layout.dock_T_marker(role)))
    if len(roles) == 1:
        # Both sides of a lone marker's yaw ambiguity, whatever IPPE returned: its second solution is not always
        # the mirror of its first (OpenCV 5.0.0's IPPE_SQUARE can return a rotation 4.7 px off for a marker
        # 2.3 m away on an x86_64 build), and a missing side is a missing minimum.
        starts += [_mirrored(th, roles[0], model) for th in starts]
    if len(roles) > 1:
        obj = model.parts(roles).obj
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                obj, pixels.reshape(-1, 2), camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE
            )
        except cv2.error:
            n = 0
        if n:
            add(rvecs, tvecs, _EYE4)
    return starts


def _mirrored(th: NDArray[np.float64], role: str, model: PlanarModel) -> NDArray[np.float64]:
    """The planar pose on the other side of a lone marker's yaw ambiguity: the marker's normal reflected about the
    camera's line of sight to its centre (yaw -> 2 bearing - yaw), the marker's centre where it was."""
    x, y, yaw = (float(v) for v in th)
    offset = model.layout.marker(role).y  # the marker's centre in the dock frame is (0, offset, z)
    mx, my = x - math.sin(yaw) * offset, y + math.cos(yaw) * offset
    bearing = math.atan2(my - float(model.base_T_optical[1, 3]), mx - float(model.base_T_optical[0, 3]))
    turned = wrap_angle(2.0 * bearing - yaw)
    return np.array([mx + math.sin(turned) * offset, my - math.cos(turned) * offset, turned])


def _same(a: NDArray[np.float64], b: NDArray[np.float64], tol: float) -> bool:
    return abs(a[0] - b[0]) < tol and abs(a[1] - b[1]) < tol and abs(wrap_angle(float(a[2] - b[2]))) < tol


def planar_candidates(
    corners: Mapping[str, ArrayLike],
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    *,
    corner_sigma: float | ArrayLike = DEFAULT_CORNER_SIGMA_PX,
    prior: PosePrior | None = None,
    starts: Sequence[DockPose] = (),
    max_iterations: int = 50,
    tolerance: float = _TOLERANCE,
    pitch_sd: float | None = None,
    roll_sd: float | None = None,
) -> list[PlanarFit]:
    """Every distinct converged local minimum of the planar fit, lowest cost first.

    Starts are ``starts`` (e.g. a regression estimate or the last frame's pose) and both IPPE solutions
    of each marker (SOLVEPNP_IPPE_SQUARE) and, with several markers, of the board (SOLVEPNP_IPPE), each
    turned into a planar pose (z, roll and pitch dropped). For a lone far marker the two IPPE solutions
    lead to the two minima of the yaw sign ambiguity; the caller scores them (cost, a prior, a tracker).
    ``pitch_sd``, ``roll_sd`` as in ``solve_planar`` (every start with δ = 0).

    Raises:
        InputError: as ``solve_planar``.
    """
    roles, img = _stack_corners(corners)
    model = planar_model(camera, layout, robot)
    parts = model.parts(roles)
    white = _whitening(corner_sigma, len(parts.obj))
    nuisance = _nuisance(pitch_sd, roll_sd)
    seeds = [_theta(s) for s in starts] + _ippe_starts(roles, img, model)
    tried: list[NDArray[np.float64]] = []
    found: list[PlanarFit] = []
    for seed in seeds:
        # Starts this close run to the same minimum (IPPE of each marker and of the board mostly agree).
        if any(_same(seed, t, _SAME_START) for t in tried):
            continue
        tried.append(seed)
        if nuisance is None:
            fit = _solve(model, roles, parts, img, white, seed, prior, max_iterations, tolerance)
        else:
            fit = _solve4(model, roles, parts, img, white, seed, prior, *nuisance, max_iterations, tolerance)
        if not fit.converged:
            continue
        th = _theta(fit.pose)
        if any(_same(th, _theta(f.pose), _SAME_MINIMUM) for f in found):
            continue
        found.append(fit)
    return sorted(found, key=lambda f: f.cost)
