"""The survey's bundle adjustment: every marker's pose and side and every view's camera, packed into one vector,
with the corners' reprojection residuals and their analytic Jacobian (``_Problem``); the robust least-squares solve,
each view's RMS reprojection error and the unknowns' covariance.

``calibrate.survey`` checks the views before and turns the solution into the dock's layout after.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from monodock.calibrate.survey_views import SurveyView
from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import FACE_R_MARKER, ROLES, DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError

__all__: list[str] = []  # nothing public: calibrate.survey is its one user


# The soft-L1 loss's scale, px: corners within it count as squares, beyond it as their distance.
LOSS_SCALE_PX = 0.5


# --- the problem ------------------------------------------------------------------------------------------------


def _rotation(w: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """exp(w) and its derivative: R (3, 3) and dR/dw (3, 3, 3), [i] = dR/dw_i."""
    R, J = cv2.Rodrigues(np.ascontiguousarray(w, dtype=np.float64))
    return np.asarray(R, dtype=np.float64), np.asarray(J, dtype=np.float64).reshape(3, 3, 3)


def _rz_t(theta: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rz(theta) transposed, and its derivative."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([[-s, c, 0.0], [-c, -s, 0.0], [0, 0, 0]])


@dataclass
class _Problem:
    """The bundle adjustment's unknowns, packed into one vector; its residuals and their analytic Jacobian.

    The working frame W: without robot views the centre marker's own frame (fixed: the gauge); with them the dock
    frame with z up the floor's normal, the centre marker's centre above its origin and its yaw fixed (the gauge
    the robot views leave: where on the floor and which way round), its roll, pitch and height free. Each other
    marker: a rotation vector about its start (left-multiplied), its centre in W, and the log of its side
    against the nominal; the centre marker's log side is minus the sum of the others' (their mean is the
    nominal's). Each view: the rotation vector about its start and the translation of cam_T_W, or for a robot
    view base_link's (x, y, yaw) on the floor. Every derivative is chained through the optical-frame point and
    OpenCV's projection Jacobian.
    """

    views: Sequence[SurveyView]
    camera: CameraModel
    nominal: DockLayout
    robot: RobotConfig | None

    def __post_init__(self) -> None:
        nominal = self.nominal
        if self.robot is None:
            centre_T_dock = transforms.invert(nominal.dock_T_marker("center"))
            self.W_T_marker0 = {r: centre_T_dock @ nominal.dock_T_marker(r) for r in ROLES}
        else:
            self.W_T_marker0 = {r: nominal.dock_T_marker(r) for r in ROLES}
            self.optical_T_base = transforms.invert(self.robot.base_T_optical())
        self.free = [r for r in ROLES if r != "center"]
        self.n_marker = 7 * len(self.free) + (3 if self.robot is not None else 0)
        self.n_view = 3 if self.robot is not None else 6
        self.n = self.n_marker + self.n_view * len(self.views)
        self.K, self.dist = self.camera.matrix, self.camera.dist
        self.squares = {r: nominal.corners_in_marker(r) for r in ROLES}
        self.cam_T_W0 = [transforms.invert(self._start_view(v)) for v in self.views]

    # packing --------------------------------------------------------------------------------------------------

    def start(self) -> NDArray[np.float64]:
        p = np.zeros(self.n)
        for i, r in enumerate(self.free):
            p[7 * i + 3 : 7 * i + 6] = self.W_T_marker0[r][:3, 3]
        if self.robot is not None:
            c = self.nominal.marker("center")
            p[7 * len(self.free) : self.n_marker] = (c.roll, c.pitch, c.z)
        for k, cam_T_W in enumerate(self.cam_T_W0):
            q = slice(self.n_marker + self.n_view * k, self.n_marker + self.n_view * (k + 1))
            if self.robot is None:
                p[q][3:] = cam_T_W[:3, 3]
            else:
                base = transforms.invert(cam_T_W) @ self.optical_T_base
                p[q] = (base[0, 3], base[1, 3], transforms.yaw_of(base))
        return p

    def _marker(self, p: NDArray[np.float64], role: str) -> tuple[Any, ...]:
        """Role's rotation R and centre t in W, its side's scale against the nominal, and dR/d(its rotation
        parameters) (3, 3, 3) or, for the robot views' centre marker, d/d(roll, pitch)."""
        if role == "center":
            scale = math.exp(-sum(float(p[7 * i + 6]) for i in range(len(self.free))))
            if self.robot is None:
                return np.eye(3), np.zeros(3), scale, None
            roll, pitch, z = p[7 * len(self.free) : self.n_marker]
            yaw = self.nominal.marker("center").yaw
            R = transforms.rotation_from_rpy(roll, pitch, yaw) @ FACE_R_MARKER
            h = 1e-7
            dR = np.stack(
                [
                    (transforms.rotation_from_rpy(roll + h, pitch, yaw) @ FACE_R_MARKER - R) / h,
                    (transforms.rotation_from_rpy(roll, pitch + h, yaw) @ FACE_R_MARKER - R) / h,
                ]
            )
            return R, np.array([0.0, 0.0, z]), scale, dR
        i = self.free.index(role)
        q = p[7 * i : 7 * i + 7]
        E, dE = _rotation(q[:3])
        R0 = self.W_T_marker0[role][:3, :3]
        return E @ R0, q[3:6], math.exp(float(q[6])), dE @ R0

    def markers(self, p: NDArray[np.float64]) -> tuple[dict[str, NDArray[np.float64]], dict[str, float]]:
        """Each marker's pose in W (4x4) and its side, metres."""
        poses, sides = {}, {}
        for r in ROLES:
            R, t, scale, _ = self._marker(p, r)
            poses[r] = transforms.transform(R, t)
            sides[r] = self.nominal.side(r) * scale
        return poses, sides

    def _view(self, p: NDArray[np.float64], k: int) -> tuple[Any, ...]:
        q = p[self.n_marker + self.n_view * k : self.n_marker + self.n_view * (k + 1)]
        if self.robot is None:
            E, dE = _rotation(q[:3])
            R0 = self.cam_T_W0[k][:3, :3]
            return E @ R0, q[3:6], dE @ R0
        Rt, dRt = _rz_t(float(q[2]))
        R = self.optical_T_base[:3, :3] @ Rt
        return R, self.optical_T_base[:3, 3] - R @ np.array([q[0], q[1], 0.0]), (Rt, dRt, q)

    def view(self, p: NDArray[np.float64], k: int) -> NDArray[np.float64]:
        """View k's camera (optical frame) in W, 4x4."""
        R, t, _ = self._view(p, k)
        return transforms.invert(transforms.transform(R, t))

    # residuals and Jacobian --------------------------------------------------------------------------------------

    def _evaluate(self, p: NDArray[np.float64], jacobian: bool) -> tuple[NDArray[np.float64], Any]:
        rows = sum(8 * len(v.corners) for v in self.views)
        res = np.empty(rows)
        J = np.zeros((rows, self.n)) if jacobian else None
        markers = {r: self._marker(p, r) for r in ROLES}
        row = 0
        for k, view in enumerate(self.views):
            Rv, tv, dv = self._view(p, k)
            vcol = self.n_marker + self.n_view * k
            for r, observed in view.corners.items():
                Rm, tm, scale, dRm = markers[r]
                local = self.squares[r] * scale
                P_W = local @ Rm.T + tm
                P_cam = P_W @ Rv.T + tv
                px, jac = cv2.projectPoints(P_cam, np.zeros(3), np.zeros(3), self.K, self.dist)
                res[row : row + 8] = (np.asarray(px).reshape(-1, 2) - observed).ravel()
                if J is not None:
                    # d pixel / d P_cam per corner: (4, 2, 3); then per unknown d P_cam / d unknown (4, 3, m).
                    D = np.asarray(jac, dtype=np.float64)[:, 3:6].reshape(4, 2, 3)
                    self._fill(J[row : row + 8], D, P_W, local, Rm, Rv, dv, dRm, r, vcol)
                row += 8
        return res, J

    def _fill(
        self,
        block: NDArray[np.float64],
        D: NDArray[np.float64],
        P_W: NDArray[np.float64],
        local: NDArray[np.float64],
        Rm: NDArray[np.float64],
        Rv: NDArray[np.float64],
        dv: Any,
        dRm: NDArray[np.float64] | None,
        role: str,
        vcol: int,
    ) -> None:
        """One marker's 8 rows of the Jacobian in one view."""

        def put(col: int, dP_cam: NDArray[np.float64]) -> None:  # dP_cam (4, 3)
            block[:, col] = np.einsum("nij,nj->ni", D, dP_cam).ravel()

        # The view's unknowns.
        if self.robot is None:
            for i in range(3):
                put(vcol + i, P_W @ dv[i].T)  # d(E R0 P) / dw_i with E R0 = Rv
                put(vcol + 3 + i, np.tile(np.eye(3)[i], (4, 1)))
        else:
            Rt, dRt, q = dv
            Rob = self.optical_T_base[:3, :3]
            for i in range(2):
                put(vcol + i, np.tile(-Rob @ Rt[:, i], (4, 1)))
            put(vcol + 2, (P_W - np.array([q[0], q[1], 0.0])) @ (Rob @ dRt).T)
        # The marker's unknowns, through d P_cam / d P_W = Rv.
        corner_W = local @ Rm.T  # the corners about the marker's centre, in W
        if role != "center":
            c = 7 * self.free.index(role)
            assert dRm is not None
            for i in range(3):
                put(c + i, (local @ dRm[i].T) @ Rv.T)
                put(c + 3 + i, np.tile(Rv[:, i], (4, 1)))
            put(c + 6, corner_W @ Rv.T)
        else:
            for i in range(len(self.free)):
                put(7 * i + 6, -corner_W @ Rv.T)
            if self.robot is not None and dRm is not None:
                c = 7 * len(self.free)
                put(c, (local @ dRm[0].T) @ Rv.T)
                put(c + 1, (local @ dRm[1].T) @ Rv.T)
                put(c + 2, np.tile(Rv[:, 2], (4, 1)))

    def residuals(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._evaluate(p, False)[0]

    def jacobian(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        J = self._evaluate(p, True)[1]
        assert J is not None
        return np.asarray(J)

    def _project(self, cam_T_W: NDArray[np.float64], pts: NDArray[np.float64]) -> NDArray[np.float64]:
        px, _ = cv2.projectPoints(transforms.apply(cam_T_W, pts), np.zeros(3), np.zeros(3), self.K, self.dist)
        return np.asarray(px, dtype=np.float64).reshape(-1, 2)

    # starts ----------------------------------------------------------------------------------------------------

    def _start_view(self, view: SurveyView) -> NDArray[np.float64]:
        """The view's camera in W from PnP on its markers at their nominal places (the best of IPPE's
        solutions by reprojection)."""
        roles = [r for r in ROLES if r in view.corners]
        obj = np.concatenate([transforms.apply(self.W_T_marker0[r], self.nominal.corners_in_marker(r)) for r in roles])
        img = np.concatenate([view.corners[r] for r in roles])
        if len(roles) == 1:
            ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                self.nominal.corners_in_marker(roles[0]), img, self.K, self.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
            )
            inner = self.W_T_marker0[roles[0]]
        else:
            ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, self.K, self.dist, flags=cv2.SOLVEPNP_IPPE)
            if not ok:  # a nominal layout whose markers are not in one plane (a surveyed one): IPPE needs one
                ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, self.K, self.dist, flags=cv2.SOLVEPNP_SQPNP)
            inner = np.eye(4)
        best, best_rms = None, math.inf
        for rvec, tvec in zip(rvecs, tvecs, strict=True) if ok else ():
            T = transforms.transform(_rotation(np.asarray(rvec, dtype=np.float64).ravel())[0], np.asarray(tvec).ravel())
            cam_T_W = T @ transforms.invert(inner)
            rms = float(np.sqrt(np.mean((self._project(cam_T_W, obj) - img) ** 2)))
            if rms < best_rms:
                best, best_rms = cam_T_W, rms
        if best is None:
            raise InputError(f"view {view.name}: no camera pose fits its markers")
        return transforms.invert(best)


# --- the solve --------------------------------------------------------------------------------------------------


def _solve(
    views: Sequence[SurveyView], camera: CameraModel, nominal: DockLayout, robot: RobotConfig | None
) -> tuple[_Problem, Any]:
    problem = _Problem(views, camera, nominal, robot)
    result = least_squares(
        problem.residuals,
        problem.start(),
        jac=problem.jacobian,
        loss="soft_l1",
        f_scale=LOSS_SCALE_PX,
        method="trf",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )
    return problem, result


def _view_rms(problem: _Problem, p: NDArray[np.float64]) -> NDArray[np.float64]:
    res = problem.residuals(p)
    sizes = [8 * len(v.corners) for v in problem.views]
    bounds = np.cumsum([0, *sizes])
    return np.array([math.sqrt(2.0 * float(np.mean(res[a:b] ** 2))) for a, b in itertools.pairwise(bounds)])


def _covariance(result: Any, m: int) -> NDArray[np.float64]:
    """The unknowns' covariance: the robust residuals' variance times (JᵀJ)⁻¹ (a pseudo-inverse: a gauge left
    free shows as a huge variance, not as a crash)."""
    J = np.asarray(result.jac.toarray() if hasattr(result.jac, "toarray") else result.jac, dtype=np.float64)
    n = J.shape[1]
    s2 = 2.0 * float(result.cost) / max(m - n, 1)
    return np.asarray(s2 * np.linalg.pinv(J.T @ J, rcond=1e-12), dtype=np.float64)
