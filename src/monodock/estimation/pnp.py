"""The SolvePnP baselines: one marker (IPPE_SQUARE) and the board of all visible markers.

Both take the same calibration (camera model, layout, mounts) and return a DockPose in base_link.
Choosing between IPPE's two solutions uses reprojection error first and, when both fit the corners about
equally well (the frontal-view ambiguity), the one that stands the dock clearly more upright on the floor
the robot stands on (the dock's z axis close to base_link's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.perception.detect import Detection

__all__ = ["PoseEstimate", "estimate_board", "estimate_single_marker", "single_marker_role"]

# Two solutions whose RMS reprojection errors differ by less than this are "equally good" fits.
AMBIGUITY_RATIO = 2.0
AMBIGUITY_FLOOR_PX = 0.3
# How much more upright (degrees) an equally good fit must be to win over the best reprojection. Chosen
# on simulated frames of seeds 5 and 9 (not the benchmark's): over 1,000 frames, single-marker yaw MAE
# 4.1 deg with no prior, 3.0 with the prior and no margin, 2.85 with this margin.
UPRIGHT_MARGIN_DEG = 1.5
_LM_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


@dataclass(frozen=True)
class PoseEstimate:
    """A method's answer for one frame: a DockPose, or None and the reason there is none.

    Attributes:
        method: "pnp" (single marker) or "board".
        pose: the DockPose in base_link, or None.
        reason: why there is no pose ("" when there is one).
        markers_seen: the roles used.
        reprojection_px: RMS reprojection error of the chosen solution.
        tilt_deg: angle between the estimated dock's up axis and base_link's (0 for a perfect estimate on
            a level floor); large values flag a wrong solution.
        base_T_dock: the full 6-DoF estimate.
        covariance: the pose's 3x3 covariance (x m, y m, yaw rad) when the method knows it, else None.
    """

    method: str
    pose: DockPose | None
    reason: str = ""
    markers_seen: tuple[str, ...] = ()
    reprojection_px: float = math.nan
    tilt_deg: float = math.nan
    base_T_dock: NDArray[np.float64] | None = field(default=None, repr=False)
    covariance: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def valid(self) -> bool:
        return self.pose is not None


def _tilt_deg(base_T_dock: NDArray[np.float64]) -> float:
    return math.degrees(math.acos(float(np.clip(base_T_dock[2, 2], -1.0, 1.0))))


def _rms(
    obj: NDArray[np.float64],
    img: NDArray[np.float64],
    rvec: NDArray[np.float64],
    tvec: NDArray[np.float64],
    camera: CameraModel,
) -> float:
    proj, _ = cv2.projectPoints(obj, rvec, tvec, camera.matrix, camera.dist)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))


@dataclass(frozen=True)
class _Candidate:
    base_T_dock: NDArray[np.float64]
    rms: float
    tilt: float
    in_front: bool


def _choose(cands: list[_Candidate]) -> _Candidate | None:
    """Best reprojection, unless a fit about as good stands the dock more upright by a margin.

    Past ~1.7 m IPPE's two solutions fit a 10 cm marker's corners about equally well; the wrong one
    usually tilts the dock off the floor, so the upright prior picks the right one (single-marker yaw
    error past 1.75 m: 8.9-10.8 deg with best reprojection alone, 6.3 with the prior; tests/estimation/test_pnp.py
    test_ippe_choice_*). The margin keeps noise-level tilt differences from overruling the fit.
    """
    cands = [c for c in cands if c.in_front and math.isfinite(c.rms)]
    if not cands:
        return None
    best = min(cands, key=lambda c: c.rms)
    tied = [c for c in cands if c.rms <= max(AMBIGUITY_RATIO * best.rms, best.rms + AMBIGUITY_FLOOR_PX)]
    upright = min(tied, key=lambda c: c.tilt)
    return upright if upright.tilt < best.tilt - UPRIGHT_MARGIN_DEG else best


def _candidate(
    rvec: NDArray[np.float64],
    tvec: NDArray[np.float64],
    optical_T_object_to_dock: NDArray[np.float64],
    robot: RobotConfig,
    obj: NDArray[np.float64],
    img: NDArray[np.float64],
    camera: CameraModel,
) -> _Candidate:
    R, _ = cv2.Rodrigues(rvec)
    optical_T_obj = transforms.transform(R, tvec.ravel())
    base_T_dock = robot.base_T_optical() @ optical_T_obj @ optical_T_object_to_dock
    in_front = bool(np.all(transforms.apply(optical_T_obj, obj)[:, 2] > 0))
    return _Candidate(base_T_dock, _rms(obj, img, rvec, tvec, camera), _tilt_deg(base_T_dock), in_front)


def _result(method: str, chosen: _Candidate | None, roles: tuple[str, ...]) -> PoseEstimate:
    if chosen is None:
        return PoseEstimate(method, None, "no PnP solution in front of the camera", roles)
    return PoseEstimate(
        method,
        DockPose.from_matrix(chosen.base_T_dock),
        "",
        roles,
        chosen.rms,
        chosen.tilt,
        chosen.base_T_dock,
    )


def single_marker_role(detection: Detection, layout: DockLayout) -> str:
    """The marker the single-marker method uses: marker 2 (``center``), the papers' baseline, whenever it is seen;
    on a dock with markers beyond the papers' three, when marker 2 is not seen, the extra marker seen largest in the
    image (the far-field marker at range, where the small ones are not decoded)."""
    extras = [r for r in layout.roles[3:] if r in detection.observations]
    if "center" in detection.observations or not extras:
        return "center"
    return max(extras, key=lambda r: float(cv2.arcLength(detection.observations[r].corners.astype(np.float32), True)))


def estimate_single_marker(
    detection: Detection,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    role: str | None = None,
) -> PoseEstimate:
    """DockPose from one marker's four corners by SOLVEPNP_IPPE_SQUARE (the papers' SolvePnP baseline); the
    marker is ``role``, or by default ``single_marker_role``'s."""
    role = single_marker_role(detection, layout) if role is None else role
    obs = detection.observations.get(role)
    if obs is None:
        return PoseEstimate("pnp", None, f"marker {layout.marker(role).number} ({role}) not seen")
    obj = layout.corners_in_marker(role)
    img = obs.corners
    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not ok:
        return PoseEstimate("pnp", None, "solvePnP failed", (role,))
    marker_T_dock = transforms.invert(layout.dock_T_marker(role))
    cands = [
        _candidate(np.asarray(r), np.asarray(t), marker_T_dock, robot, obj, img, camera)
        for r, t in zip(rvecs, tvecs, strict=True)
    ]
    return _result("pnp", _choose(cands), (role,))


def _marker_starts(
    detection: Detection, camera: CameraModel, layout: DockLayout, roles: tuple[str, ...]
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Starts (rvec, tvec of the dock in the optical frame) from each marker's own IPPE_SQUARE solutions."""
    out = []
    for role in roles:
        ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            layout.corners_in_marker(role),
            detection.observations[role].corners,
            camera.matrix,
            camera.dist,
            flags=cv2.SOLVEPNP_IPPE_SQUARE,
        )
        marker_T_dock = transforms.invert(layout.dock_T_marker(role))
        for r, t in zip(rvecs, tvecs, strict=True) if ok else ():
            R, _ = cv2.Rodrigues(np.asarray(r))
            T = transforms.transform(R, np.asarray(t).ravel()) @ marker_T_dock
            rv, _ = cv2.Rodrigues(T[:3, :3])
            out.append((np.asarray(rv, dtype=np.float64), T[:3, 3].reshape(3, 1).copy()))
    return out


def estimate_board(
    detection: Detection,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
) -> PoseEstimate:
    """DockPose from the corners of every visible dock marker jointly (iterative PnP, then LM refinement).

    Planar boards still have a two-fold ambiguity when they look small; IPPE's two solutions join the
    iterative one as starting points, each is refined with Levenberg-Marquardt, and the choice follows
    the same rule as the single-marker baseline.
    """
    roles = detection.roles_seen
    if not roles:
        return PoseEstimate("board", None, "no dock marker seen")
    obj = np.concatenate([layout.corners_in_dock(r) for r in roles])
    img = np.concatenate([detection.observations[r].corners for r in roles])
    starts: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    found, rvec, tvec = cv2.solvePnP(obj, img, camera.matrix, camera.dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if found:
        starts.append((np.asarray(rvec, dtype=np.float64), np.asarray(tvec, dtype=np.float64)))
    count, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    if count:
        starts += [(np.asarray(r), np.asarray(t)) for r, t in zip(rvecs, tvecs, strict=True)]
    else:
        # A surveyed dock's markers are not exactly in one plane (a card standing off, a tilt): IPPE needs one.
        # Each marker alone is a plane; both of its IPPE solutions, moved to the dock's origin, start the fit.
        starts += _marker_starts(detection, camera, layout, roles)
    if not starts:
        return PoseEstimate("board", None, "solvePnP failed", roles)
    identity = np.eye(4)
    cands = []
    for r0, t0 in starts:
        r, t = cv2.solvePnPRefineLM(obj, img, camera.matrix, camera.dist, r0.copy(), t0.copy(), _LM_CRITERIA)
        cands.append(_candidate(np.asarray(r), np.asarray(t), identity, robot, obj, img, camera))
    return _result("board", _choose(cands), roles)
