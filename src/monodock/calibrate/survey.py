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

The parts: the views and their corners (``calibrate.survey_views``) and the bundle adjustment
(``calibrate.survey_fit``); this module checks the views, defines the dock frame, writes the layout and refuses
what the views leave uncertain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.calibrate.survey_fit import _covariance, _Problem, _solve, _view_rms
from monodock.calibrate.survey_views import SurveyView, ViewNote
from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.config import yaml_text
from monodock.core.layout import FACE_R_MARKER, ROLES, DockLayout, MarkerSpec
from monodock.core.robot import RobotConfig
from monodock.core.settings import to_mapping
from monodock.errors import InputError
from monodock.perception.edge_offset import EdgeOffset

__all__ = [
    "LayoutSurvey",
    "MarkerSurvey",
    "SurveyLimits",
    "survey_layout",
    "surveyed_layout_text",
]

# The values written per marker, in this order (metres and radians).
VALUES = ("x", "y", "z", "roll", "pitch", "yaw", "size")
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
    body = yaml_text(to_mapping(layout or survey.layout), flow=None)
    return head + body + yaml_text({"survey": survey.record()}, flow=None)


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
