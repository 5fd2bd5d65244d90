"""Where the planar fit starts, and the fits that search from there: the starting poses, the board fit of two or more
markers, and every local minimum of a fit (``planar_candidates``).

The fit itself (its model and Levenberg–Marquardt) is ``estimation.planar``'s. The starts: the floor-constrained
linear solution of two or more markers' corners (``_floor_start``, compiled, where the fused method's fit starts on
every frame), and the IPPE solutions of each marker and of the board, flattened onto the floor (z, roll and pitch
dropped), with the mirror image of a lone marker's: a lone small marker seen from afar has two planar minima (the yaw
sign ambiguity of weak perspective), and ``planar_candidates`` starts from both sides.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.compiled import kernel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.robot import RobotConfig
from monodock.estimation.planar import (
    _MAX_ITERATIONS,
    _NO_BLOCKS,
    _TOLERANCE,
    _ZERO3,
    _ZERO33,
    DEFAULT_CORNER_SIGMA_PX,
    PlanarFit,
    PlanarModel,
    PosePrior,
    _lm3,
    _nuisance,
    _planar_fit,
    _problem,
    _solve,
    _stack_corners,
    _theta,
    _Whitening,
    _whitening,
    planar_model,
)

__all__ = ["board_fit", "board_fit_stacked", "board_start", "planar_candidates"]

# Two starts closer than this (metres and radians) are one.
_SAME_START = 0.01
# Two converged minima closer than this (metres and radians) are the same one.
_SAME_MINIMUM = 1e-4


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
    """A start for ``planar.solve_planar`` from two or more markers: the board's better IPPE solution, as a planar pose.

    With two or more markers the board is wide enough that its IPPE solutions rarely fit alike (a lone
    far marker's do: use ``planar_candidates`` there). None for fewer than two markers or when IPPE fails.
    """
    roles, img = _stack_corners(corners, layout)
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
    """``planar.solve_planar`` from a start for two or more markers (``board_fit_stacked``); None for fewer, or where
    neither start can be found."""
    roles, img = _stack_corners(corners, layout)
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
    return _solve(model, roles, parts, img, white, th, None, None, _MAX_ITERATIONS, _TOLERANCE)


@kernel
def _board_lm(
    problem: tuple[Any, ...], max_iterations: int, tolerance: float
) -> tuple[bool, Any, bool, float, Any, Any, float, float, int, bool]:  # pragma: no cover - compiled
    """``planar._lm3`` from ``_floor_start``; first whether that start exists (if not, the rest is meaningless)."""
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

    for k, role in enumerate(roles):
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                layout.corners_in_marker(role), pixels[k], camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
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
    m = model.layout.marker(role)  # the marker's centre in the dock frame is (m.x, m.y, z)
    c, s = math.cos(yaw), math.sin(yaw)
    mx, my = x + c * m.x - s * m.y, y + s * m.x + c * m.y
    bearing = math.atan2(my - float(model.base_T_optical[1, 3]), mx - float(model.base_T_optical[0, 3]))
    turned = wrap_angle(2.0 * bearing - yaw)
    c, s = math.cos(turned), math.sin(turned)
    return np.array([mx - c * m.x + s * m.y, my - s * m.x - c * m.y, turned])


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
    ``pitch_sd``, ``roll_sd`` as in ``planar.solve_planar`` (every start with δ = 0).

    Raises:
        InputError: as ``planar.solve_planar``.
    """
    roles, img = _stack_corners(corners, layout)
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
        fit = _solve(model, roles, parts, img, white, seed, prior, nuisance, max_iterations, tolerance)
        if not fit.converged:
            continue
        th = _theta(fit.pose)
        if any(_same(th, _theta(f.pose), _SAME_MINIMUM) for f in found):
            continue
        found.append(fit)
    return sorted(found, key=lambda f: f.cost)
