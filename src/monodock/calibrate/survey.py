"""Survey the dock from photographs: every marker's pose and printed side, by bundle adjustment.

A printed dock is never where its layout file says: a marker taped 3 mm off, tilted 2° against the face, printed
at 98 %. From 10-40 views of the dock (photos, a video, frames of a recording; any calibrated camera) this
solves, over every refined corner of every view at once, the pose of each view's camera and each marker's pose
and side, with a robust loss (soft L1: a misdetected corner cannot drag the fit). The nominal layout gives the
dictionary, the ids and the start.

What images can and cannot tell:

- **Shape, not scale.** A dock printed at 98 % looks exactly like a dock 2 % nearer. The survey measures the
  markers' sides relative to one another; their mean is taken to be the nominal's (the kit's 10 cm scale bar
  checks the printer). A drive with odometry measures the scale (``calibrate mount``).
- **The face is not seen**, only the markers on it. The dock's x (into the charger) is the normal of the plane
  through every marker corner; the face passes through the centre marker's centre (its ``x`` is 0).
- **Up and the height above the floor** need the floor. From the robot's own camera with a known mount
  (``robot``) the floor is known in every view: the dock's z is the floor's normal, the heights are measured,
  and the face's direction is its horizontal part. From any other camera the dock's up is the markers' mean up
  and the centre marker keeps its nominal height (the result says so).

The standard deviations come from the fit's covariance (the robust residuals' scale times (JᵀJ)⁻¹), carried
through the definition of the dock frame to every value written.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.config import yaml_text
from monodock.core.frame import Frame
from monodock.core.layout import FACE_R_MARKER, ROLES, DockLayout, MarkerSpec
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.io.frames import open_frames
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.perception.edge_offset import (
    EdgeOffset,
    clipped_roles,
    detection_edge_offset,
    estimate_edge_offset,
    offset_corners,
)
from monodock.perception.marker_fit import fit_marker
from monodock.perception.refine import refine_detection
from monodock.recording.read import is_recording, open_recording

__all__ = [
    "LayoutSurvey",
    "MarkerSurvey",
    "SurveyLimits",
    "SurveyView",
    "ViewNote",
    "survey_layout",
    "survey_views",
    "surveyed_layout_text",
    "views_from_inputs",
]

# The values written per marker, in this order (metres and radians).
VALUES = ("x", "y", "z", "roll", "pitch", "yaw", "size")
# The soft-L1 loss's scale, px: corners within it count as squares, beyond it as their distance.
LOSS_SCALE_PX = 0.5
# A view whose RMS reprojection error is this many times the median view's (and over 1 px) is dropped.
OUTLIER_VIEW_FACTOR = 5.0
# Fewest views the survey accepts (the standard deviations decide whether they were enough).
MIN_VIEWS = 4


@dataclass(frozen=True)
class SurveyLimits:
    """How uncertain (one standard deviation) a surveyed value may be before the survey refuses it.

    Attributes:
        position_sd: a marker centre's x, y, z, metres.
        angle_sd: its roll, pitch, yaw, radians.
        size_sd: its printed side, metres.
    """

    position_sd: float = 0.0003
    angle_sd: float = math.radians(0.15)
    size_sd: float = 0.0002

    def limit(self, value: str) -> float:
        if value in ("x", "y", "z"):
            return self.position_sd
        return self.size_sd if value == "size" else self.angle_sd


@dataclass(frozen=True)
class SurveyView:
    """One view's usable markers: each role's corners (4, 2), px, ArUco order; its image; the roles with clipped
    pixels (the refiner took their edges' shift out already: the edge offset is not theirs); and the roles whose
    corners come from the photometric fit of the whole marker (``perception.marker_fit``: its own edge offset is
    out already)."""

    name: str
    corners: Mapping[str, NDArray[np.float64]]
    image: NDArray[np.uint8] | None = field(default=None, repr=False, compare=False)
    clipped: tuple[str, ...] = ()
    fitted: tuple[str, ...] = ()


@dataclass(frozen=True)
class ViewNote:
    """What became of one input view: used (with its RMS reprojection error) or skipped, and why."""

    name: str
    roles: tuple[str, ...]
    used: bool
    rms_px: float = math.nan
    reason: str = ""


@dataclass(frozen=True)
class MarkerSurvey:
    """One marker as surveyed: the layout entry and each value's standard deviation (``VALUES``' units)."""

    spec: MarkerSpec
    side: float
    sd: Mapping[str, float]


@dataclass(frozen=True)
class LayoutSurvey:
    """The surveyed layout and how well the views determine it.

    Attributes:
        layout: the nominal layout with every marker's surveyed x, y, z, roll, pitch, yaw and size.
        markers: per role, its values' standard deviations.
        rms_px: RMS reprojection error over every used corner.
        views: every input view's fate, in input order.
        heights_measured: whether the heights above the floor (and the dock's up) come from robot views.
        camera_poses: per used view, the camera's optical frame in the dock frame (4x4), for overlays.
        notes: what the user should know (the scale's and the heights' source).
    """

    layout: DockLayout
    markers: Mapping[str, MarkerSurvey]
    rms_px: float
    views: tuple[ViewNote, ...]
    heights_measured: bool
    camera_poses: Mapping[str, NDArray[np.float64]] = field(repr=False)
    notes: tuple[str, ...] = ()

    @property
    def used(self) -> tuple[ViewNote, ...]:
        return tuple(v for v in self.views if v.used)

    def record(self) -> dict[str, Any]:
        """The survey's record, as the layout file's ``survey`` mapping (read by people; ignored by every method)."""
        return {
            "views_used": len(self.used),
            "rms_px": round(self.rms_px, 4),
            "scale": self.notes[0] if self.notes else "",
            "heights": self.notes[1] if len(self.notes) > 1 else "",
            "sd": {role: {k: float(f"{v:.3g}") for k, v in m.sd.items()} for role, m in self.markers.items()},
            "views": [
                f"{v.name}: {'+'.join(v.roles)}, {v.rms_px:.3f} px" if v.used else f"{v.name}: skipped, {v.reason}"
                for v in self.views
            ],
        }

    def summary(self) -> str:
        """Lines for a person: each marker's values with their standard deviations, and the fit."""
        lines = [f"surveyed {len(self.markers)} markers from {len(self.used)} views, RMS {self.rms_px:.3f} px"]
        for role, m in self.markers.items():
            s, sd = m.spec, m.sd
            lines.append(
                f"  {role:6s} id {s.id:3d}: x {s.x * 1e3:+7.2f} ±{sd['x'] * 1e3:.2f}  y {s.y * 1e3:+8.2f} "
                f"±{sd['y'] * 1e3:.2f}  z {s.z * 1e3:7.2f} ±{sd['z'] * 1e3:.2f} mm  roll {math.degrees(s.roll):+.2f} "
                f"±{math.degrees(sd['roll']):.2f}  pitch {math.degrees(s.pitch):+.2f} ±{math.degrees(sd['pitch']):.2f}"
                f"  yaw {math.degrees(s.yaw):+.2f} ±{math.degrees(sd['yaw']):.2f} deg  side {m.side * 1e3:.2f} "
                f"±{sd['size'] * 1e3:.2f} mm"
            )
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines)


def surveyed_layout_text(survey: LayoutSurvey, layout: DockLayout | None = None) -> str:
    """The surveyed layout file: ``layout`` (default the survey's own), then the survey's record (read by people,
    ignored by every method)."""
    head = (
        "# Surveyed by monodock calibrate layout: every marker's pose and printed side from photographs.\n"
        "# The 'survey' mapping records how well the views determined them; no method reads it.\n"
    )
    body = yaml_text((layout or survey.layout).to_dict(), flow=None)
    return head + body + yaml_text({"survey": survey.record()}, flow=None)


# --- the views --------------------------------------------------------------------------------------------------


def survey_views(
    frames: Iterable[Frame], camera: CameraModel, layout: DockLayout, *, keep_images: bool = False
) -> tuple[list[SurveyView], list[ViewNote], EdgeOffset | None]:
    """Each frame's dock markers with bias-free corners, free of the print's edge offset.

    A survey can afford what a robot's frame cannot: each unclipped marker's corners come from the photometric fit
    of its whole printed pattern (``perception.marker_fit``, ~10 ms a marker), which measures the marker's edge
    offset and takes it out. On real photographs of a printed board its corners are 0.17-0.30 px RMS from the
    truth where the per-frame refiner's, with the pooled offset, are 0.19-0.58 px (``bench/real_photos.py``).
    A marker the fit refuses, or one with clipped pixels (whose edges the fit's linear levels cannot model),
    keeps the refiner's corners, corrected by the pooled offset.

    Returns the views (a marker whose corners could not be refined is left out), a note per skipped frame, and
    the edge offset pooled over every unclipped marker's code runs (``perception.edge_offset``; None when the
    markers are too small to measure it, and then no correction): the layout's ``edge_offset``, which the
    per-frame methods apply to the refiner's corners.
    """
    detector = MarkerDetector(layout)
    views: list[SurveyView] = []
    skipped: list[ViewNote] = []
    runs: list[NDArray[np.float64]] = []
    for frame in frames:
        if frame.image is None:
            skipped.append(ViewNote(frame.name, (), False, reason=frame.error or "unreadable"))
            continue
        gray = as_gray(frame.image)
        if (gray.shape[1], gray.shape[0]) != camera.size:
            raise InputError(
                f"{frame.name} is {gray.shape[1]}x{gray.shape[0]} but the camera is {camera.width}x{camera.height}"
            )
        detection = refine_detection(gray, detector.detect(gray), camera, modules=layout.modules)
        corners = {r: o.corners for r, o in detection.observations.items() if r not in detection.unrefined}
        if not corners:
            skipped.append(ViewNote(frame.name, (), False, reason="no dock marker found"))
            continue
        runs += detection_edge_offset(gray, detection, camera, layout)
        clipped = clipped_roles(gray, detection, modules=layout.modules)
        fitted = []
        for role, refined in list(corners.items()):
            if role in clipped:
                continue
            fit = fit_marker(gray, refined, camera, layout.marker_bits(layout.marker(role).id))
            if fit is not None:
                corners[role] = fit.corners
                fitted.append(role)
        views.append(SurveyView(frame.name, corners, gray if keep_images else None, clipped, tuple(fitted)))
    offset = pooled_edge_offset(runs)
    if offset is not None:
        views = [corrected_view(v, offset.offset_px) for v in views]
    return views, skipped, offset


def pooled_edge_offset(runs: Sequence[NDArray[np.float64]]) -> EdgeOffset | None:
    """The edge offset of many markers' runs, or None when they are too few to tell it."""
    try:
        return estimate_edge_offset(runs)
    except InputError:
        return None


def corrected_view(view: SurveyView, offset_px: float) -> SurveyView:
    """The view with its refiner's corners (neither clipped nor fitted) corrected by the edge offset."""
    keep = (*view.clipped, *view.fitted)
    corners = {r: c if r in keep else offset_corners(c, offset_px) for r, c in view.corners.items()}
    return replace(view, corners=corners)


def views_from_inputs(
    images: Sequence[str],
    camera: CameraModel | None,
    nominal: DockLayout,
    *,
    max_views: int = 40,
    keep_images: bool = False,
) -> tuple[list[SurveyView], list[ViewNote], CameraModel, EdgeOffset | None]:
    """The views of the inputs (every frame of a video or recording; the views thinned evenly to ``max_views``),
    the skipped frames and the camera."""
    if camera is None:
        recordings = [i for i in images if is_recording(i)]
        if not recordings:
            raise InputError("give --camera (the calibration of the camera that took the views)")
        with open_recording(recordings[0]) as rec:
            camera = rec.camera()
        if camera is None:
            raise InputError(f"{recordings[0]} has no CameraInfo: give --camera")
    with open_frames(images, skip_bad=True) as source:
        views, skipped, offset = survey_views(source, camera, nominal, keep_images=keep_images)
    if len(views) > max_views:
        step = (len(views) - 1) / (max_views - 1)
        views = [views[round(k * step)] for k in range(max_views)]
    return views, skipped, camera, offset


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


# --- the dock frame and the layout ------------------------------------------------------------------------------


def _dock_frame(
    poses: Mapping[str, NDArray[np.float64]],
    sides: Mapping[str, float],
    nominal: DockLayout,
    cameras: NDArray[np.float64],
    robot: bool,
) -> NDArray[np.float64]:
    """W_T_dock: x the normal of the plane through every marker corner (horizontal with robot views), pointing
    away from the cameras; z up (the floor's normal with robot views, else the markers' mean up); the origin
    below the centre marker's centre, its nominal height down (measured with robot views)."""
    corners = np.concatenate(
        [transforms.apply(poses[r], nominal.corners_in_marker(r) * (sides[r] / nominal.side(r))) for r in ROLES]
    )
    centroid = corners.mean(axis=0)
    if robot:
        up = np.array([0.0, 0.0, 1.0])
        flat = corners[:, :2] - centroid[:2]
        _, _, vt = np.linalg.svd(flat, full_matrices=False)
        normal = np.array([vt[1, 0], vt[1, 1], 0.0])
    else:
        _, _, vt = np.linalg.svd(corners - centroid, full_matrices=False)
        normal = vt[2]
        up = np.mean([poses[r][:3, 1] for r in ROLES], axis=0)
        up = up - (up @ normal) * normal
        up /= np.linalg.norm(up)
    if normal @ (cameras.mean(axis=0) - centroid) > 0:
        normal = -normal
    y = np.cross(up, normal)
    R = np.column_stack([normal, y, up])
    centre = poses["center"][:3, 3]
    height = centre[2] if robot else nominal.marker("center").z
    origin = centre - height * up
    if robot:
        origin = np.array([centre[0], centre[1], 0.0])
    return transforms.transform(R, origin)


def _layout_values(
    problem: _Problem, p: NDArray[np.float64], cameras: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Every marker's ``VALUES`` in the dock frame (3 x 7, ROLES order) and W_T_dock."""
    poses, sides = problem.markers(p)
    W_T_dock = _dock_frame(poses, sides, problem.nominal, cameras, problem.robot is not None)
    dock_T_W = transforms.invert(W_T_dock)
    out = np.empty((len(ROLES), len(VALUES)))
    for i, r in enumerate(ROLES):
        T = dock_T_W @ poses[r]
        roll, pitch, yaw = transforms.rpy_from_rotation(T[:3, :3] @ FACE_R_MARKER.T)
        out[i] = (T[0, 3], T[1, 3], T[2, 3], roll, pitch, yaw, sides[r])
    return out, W_T_dock


def _covariance(result: Any, m: int) -> NDArray[np.float64]:
    """The unknowns' covariance: the robust residuals' variance times (JᵀJ)⁻¹ (a pseudo-inverse: a gauge left
    free shows as a huge variance, not as a crash)."""
    J = np.asarray(result.jac.toarray() if hasattr(result.jac, "toarray") else result.jac, dtype=np.float64)
    n = J.shape[1]
    s2 = 2.0 * float(result.cost) / max(m - n, 1)
    return np.asarray(s2 * np.linalg.pinv(J.T @ J, rcond=1e-12), dtype=np.float64)


def _value_sd(
    problem: _Problem, p: NDArray[np.float64], cov: NDArray[np.float64], cameras: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Each value's standard deviation, (3, 7): the covariance carried through the dock frame's definition."""
    base, _ = _layout_values(problem, p, cameras)
    G = np.empty((base.size, p.size))
    for j in range(p.size):
        h = 1e-7 * max(1.0, abs(p[j]))
        q = p.copy()
        q[j] += h
        G[:, j] = ((_layout_values(problem, q, cameras)[0] - base) / h).ravel()
    var = np.einsum("ij,jk,ik->i", G, cov, G)
    return np.asarray(np.sqrt(np.maximum(var, 0.0)).reshape(base.shape), dtype=np.float64)


# --- the survey -------------------------------------------------------------------------------------------------


def _ties(views: Sequence[SurveyView], nominal: DockLayout) -> None:
    """Refuse unless every marker is seen and the views tie every marker to the centre one."""
    for r in ROLES:
        if not any(r in v.corners for v in views):
            m = nominal.marker(r)
            raise InputError(f"marker {r} (id {m.id}) is in no view: add views that show it beside the centre marker")
    linked = {"center"}
    grew = True
    while grew:
        grew = False
        for v in views:
            seen = set(v.corners)
            if len(seen) > 1 and seen & linked and not seen <= linked:
                linked |= seen
                grew = True
    loose = [r for r in ROLES if r not in linked]
    if loose:
        raise InputError(
            f"no view ties marker {loose[0]} to the others: add views that show {loose[0]} and the centre marker "
            "together"
        )


def _advice(role: str, value: str) -> str:
    """What views pin down a value."""
    if value in ("roll", "pitch", "yaw"):
        side = "above and below it" if value == "pitch" else "further to its sides"
        return f"closer views of {role} from {side} (a tilt shows in oblique views)"
    if value == "x":
        return f"views of {role} and the centre marker from further to the side"
    if value == "size":
        return f"views of {role} from nearer and farther"
    return f"closer views showing {role} with the centre marker"


def survey_layout(
    views: Sequence[SurveyView],
    camera: CameraModel,
    nominal: DockLayout,
    *,
    robot: RobotConfig | None = None,
    limits: SurveyLimits | None = None,
    skipped: Sequence[ViewNote] = (),
    edge_offset: EdgeOffset | None = None,
) -> LayoutSurvey:
    """The dock's layout as the views see it, with each value's standard deviation.

    Args:
        views: the views (``survey_views``); those that show a single marker only help with ``robot``.
        camera: the camera that took them.
        nominal: the layout the dock was built to: dictionary, ids, and the start.
        robot: the views are the robot's own camera on the floor, with this mount: heights and up are measured.
        limits: the largest standard deviations accepted.
        skipped: notes on input frames already dropped (they appear in the result's ``views``).
        edge_offset: the offset the views measured (``survey_views``; their corners are corrected already),
            written into the layout.

    Raises:
        InputError: too few views, markers not tied together, or a value more uncertain than ``limits``
            (one line that says what views to add).
    """
    limits = limits or SurveyLimits()
    if len(nominal.markers) > len(ROLES):
        # Its values are the papers' three markers' (VALUES); another marker would leave the survey unmeasured.
        extra = ", ".join(nominal.roles[len(ROLES) :])
        raise InputError(
            f"the layout carries markers beyond the papers' three ({extra}): the survey measures left, center and "
            "right only; survey those, then add the others by hand"
        )
    usable = [v for v in views if len(v.corners) >= (1 if robot is not None else 2)]
    for r in ROLES:
        alone = sum(1 for v in views if set(v.corners) == {r})
        if alone and not any(r in v.corners for v in usable):
            m = nominal.marker(r)
            raise InputError(
                f"marker {r} (id {m.id}) is seen only alone ({alone} views): add views that show it beside the "
                "centre marker"
            )
    notes = list(skipped) + [
        ViewNote(v.name, tuple(v.corners), False, reason="one marker only") for v in views if v not in usable
    ]
    if len(usable) < MIN_VIEWS:
        raise InputError(
            f"{len(usable)} views show two or more dock markers; the survey needs at least {MIN_VIEWS} "
            "(10-40 from different sides and distances)"
        )
    _ties(usable, nominal)
    problem, result = _solve(usable, camera, nominal, robot)
    # Drop views that do not fit (a misdetection, a moved marker) and solve again without them.
    rms = _view_rms(problem, result.x)
    median = float(np.median(rms))
    bad = [k for k, e in enumerate(rms) if e > max(OUTLIER_VIEW_FACTOR * median, 1.0)]
    if bad and len(usable) - len(bad) >= MIN_VIEWS:
        notes += [
            ViewNote(usable[k].name, tuple(usable[k].corners), False, rms[k], f"does not fit ({rms[k]:.2f} px)")
            for k in bad
        ]
        usable = [v for k, v in enumerate(usable) if k not in bad]
        _ties(usable, nominal)
        problem, result = _solve(usable, camera, nominal, robot)
        rms = _view_rms(problem, result.x)
    p = result.x
    cameras = np.array([problem.view(p, k)[:3, 3] for k in range(len(usable))])
    values, W_T_dock = _layout_values(problem, p, cameras)
    sd = _value_sd(problem, p, _covariance(result, result.fun.size), cameras)
    _check_limits(sd, limits, robot is not None)
    residual = problem.residuals(p)
    specs = []
    for i, r in enumerate(ROLES):
        x, y, z, roll, pitch, yaw, side = values[i]
        m = nominal.marker(r)
        specs.append(
            MarkerSpec(r, m.id, float(y), float(z), float(x), float(roll), float(pitch), float(yaw), float(side))
        )
    offset = edge_offset.offset_px if edge_offset is not None else 0.0
    layout = replace(nominal, markers=tuple(specs), edge_offset=offset)
    dock_T_W = transforms.invert(W_T_dock)
    mean_side = math.exp(np.mean([math.log(nominal.side(r)) for r in ROLES]))
    notes_text = (
        f"scale from the printed size: the markers' mean side is the nominal {mean_side * 1e3:.1f} mm",
        "heights measured from the robot views (the mount known)"
        if robot is not None
        else f"heights nominal: the centre marker at {nominal.marker('center').z * 1e3:.1f} mm (no robot views); "
        "up is the markers' mean up",
        f"edge offset {edge_offset.offset_px:+.3f} ±{edge_offset.sd_px:.3f} px from {edge_offset.runs} code runs of "
        f"{edge_offset.markers} markers (black looks {'thinner' if edge_offset.offset_px < 0 else 'thicker'} than "
        "printed); every corner corrected by it"
        if edge_offset is not None
        else "edge offset: the markers are too small in the views to measure it; none applied",
    )
    order = {v.name: k for k, v in enumerate(views)}
    used_notes = [ViewNote(v.name, tuple(v.corners), True, float(rms[k])) for k, v in enumerate(usable)]
    all_notes = sorted(used_notes + notes, key=lambda n: order.get(n.name, len(order)))
    return LayoutSurvey(
        layout=layout,
        markers={
            r: MarkerSurvey(layout.marker(r), float(values[i, 6]), dict(zip(VALUES, sd[i].tolist(), strict=True)))
            for i, r in enumerate(ROLES)
        },
        rms_px=float(np.sqrt(np.mean(residual**2) * 2.0)),
        views=tuple(all_notes),
        heights_measured=robot is not None,
        camera_poses={v.name: dock_T_W @ problem.view(p, k) for k, v in enumerate(usable)},
        notes=notes_text,
    )


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


def _check_limits(sd: NDArray[np.float64], limits: SurveyLimits, robot: bool) -> None:
    """Refuse the worst value beyond its limit (relative to it), saying which views would pin it down."""
    worst: tuple[float, str, str] | None = None
    for i, r in enumerate(ROLES):
        for j, v in enumerate(VALUES):
            if r == "center" and (v in ("x", "y") or (v == "z" and not robot)):
                continue  # fixed by the dock frame's definition
            ratio = sd[i, j] / limits.limit(v)
            if ratio > 1.0 and (worst is None or ratio > worst[0]):
                worst = (ratio, r, v)
    if worst is not None:
        _, r, v = worst
        shown = math.degrees(sd[ROLES.index(r), VALUES.index(v)]) if v in ("roll", "pitch", "yaw") else None
        unit = "deg" if shown is not None else "mm"
        value = shown if shown is not None else sd[ROLES.index(r), VALUES.index(v)] * 1e3
        limit = math.degrees(limits.limit(v)) if shown is not None else limits.limit(v) * 1e3
        raise InputError(
            f"the views leave marker {r}'s {v} uncertain by {value:.3g} {unit} (limit {limit:.3g} {unit}): add "
            f"{_advice(r, v)}; nothing written"
        )
