"""Commission a new robot and dock: survey the dock, calibrate the camera mount, teach the charging pose.

The three steps in order, each feeding the next (``monodock commission`` runs them and writes one report):

1. the survey (``calibrate.survey``): photographs of the dock → every marker's pose and printed side;
2. the mount (``calibrate.mount``): a minute's drive → the camera mount and the odometry's errors, with the
   surveyed layout; and the layout stood up on the floor (its lean) and, with ``scale_from="odometry"``, scaled;
3. the charging pose (``calibrate.teach``): a back-off from the contacts → where base_link charges, seen through
   the commissioned layout, mount and odometry.

A step that cannot be done (too few views, a drive that did not excite the mount) is recorded with its reason and
what to redo, and the steps after it that need it are skipped: the result says whether the robot is ready.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from monodock.calibrate.mount import MountCalibration, calibrate_mount_of, frames_from_recording
from monodock.calibrate.survey import LayoutSurvey, SurveyLimits, survey_layout
from monodock.calibrate.survey_views import SurveyView, views_from_inputs
from monodock.calibrate.teach import TaughtPose, teach_from_recording
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.core.settings import to_mapping
from monodock.dock.config import ChargingOffset
from monodock.errors import InputError

__all__ = ["STEPS", "Commissioning", "StepFailure", "commission"]

STEPS = ("survey", "mount", "teach")


@dataclass(frozen=True)
class StepFailure:
    """A step that could not be done, and why (its one-line reason says what to redo)."""

    step: str
    reason: str


@dataclass(frozen=True)
class Commissioning:
    """What commissioning found: each step's result (None when it failed or was skipped), and the files it makes.

    Attributes:
        nominal_layout, nominal_robot, camera: what it started from.
        survey, mount, teach: each step's result.
        layout: the commissioned layout (surveyed, stood up and scaled by the drive); the nominal one when the
            survey failed.
        robot: the commissioned robot file (its camera mount and odometry calibrated).
        charging_offset: the taught charging pose, for the docking config.
        views: the survey's views (with their images), for the report.
        failures: the steps that failed, in order.
        skipped: the steps not run because one before them failed.
    """

    nominal_layout: DockLayout
    nominal_robot: RobotConfig
    camera: CameraModel
    survey: LayoutSurvey | None
    mount: MountCalibration | None
    teach: TaughtPose | None
    layout: DockLayout
    robot: RobotConfig
    charging_offset: ChargingOffset
    views: Sequence[SurveyView] = field(repr=False, default=())
    failures: tuple[StepFailure, ...] = ()
    skipped: tuple[str, ...] = ()

    @property
    def ready(self) -> bool:
        """Every step done, and the drive excited every part of the mount."""
        return not self.failures and not self.skipped and self.mount is not None and not self.mount.unexcited

    def verdict(self) -> list[str]:
        """One line per thing to redo, or the one line that says it is ready."""
        if self.ready:
            return ["ready to dock: the layout, the robot file and the docking config are commissioned"]
        out = [f"redo the {f.step}: {f.reason}" for f in self.failures]
        out += [f"then the {s} (it needs the steps before it)" for s in self.skipped]
        if self.mount is not None:
            out += [f"redo the drive: it did not excite {u}" for u in self.mount.unexcited]
        return out


def commission(
    survey_inputs: Sequence[str],
    drive: str,
    teach_recording: str,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    *,
    scale_from: str = "print",
    max_views: int = 40,
    limits: SurveyLimits | None = None,
    survey_camera: CameraModel | None = None,
    teach_method: str = "fused",
    docked_at_start: bool = False,
) -> Commissioning:
    """Survey, calibrate the mount, teach; a step's InputError is recorded, not raised.

    Args:
        survey_inputs: the survey's photographs (files, folders, a video or a recording).
        drive: the commissioning drive's recording (images, camera_info, odometry).
        teach_recording: the back-off from the contacts (images, odometry, battery state).
        camera: the robot's camera.
        layout, robot: the nominal files (what the dock and the robot were built to).
        scale_from: the ruler of lengths, "print" or "odometry" (``calibrate.mount``).
        max_views, limits: the survey's.
        survey_camera: the survey photos' camera when it is not the robot's.
        teach_method: "fused" or "board".
        docked_at_start: the teach recording has no battery state and starts on the contacts.
    """
    failures: list[StepFailure] = []
    survey = mount = taught = None
    views: list[SurveyView] = []
    try:
        views, skipped, cam, edge = views_from_inputs(
            survey_inputs, survey_camera or camera, layout, max_views=max_views, keep_images=True
        )
        survey = survey_layout(views, cam, layout, limits=limits, skipped=skipped, edge_offset=edge)
    except InputError as exc:
        failures.append(StepFailure("survey", str(exc)))
    surveyed = survey.layout if survey is not None else layout
    commissioned_layout, commissioned_robot = surveyed, robot
    if survey is None:
        return Commissioning(
            layout, robot, camera, None, None, None, layout, robot, ChargingOffset(), views, tuple(failures),
            ("mount", "teach"),
        )  # fmt: skip
    try:
        mount = calibrate_mount_of(frames_from_recording(drive, surveyed, camera=camera), surveyed, robot,
                                   scale_from=scale_from)  # fmt: skip
        commissioned_layout = mount.layout(surveyed)
        commissioned_robot = mount.robot(robot)
    except InputError as exc:
        failures.append(StepFailure("mount", str(exc)))
    if mount is None:
        return Commissioning(
            layout, robot, camera, survey, None, None, surveyed, robot, ChargingOffset(), views, tuple(failures),
            ("teach",),
        )  # fmt: skip
    offset = ChargingOffset()
    try:
        taught = teach_from_recording(
            teach_recording, commissioned_layout, commissioned_robot, camera=camera, method=teach_method,
            docked_at_start=docked_at_start,
        )  # fmt: skip
        offset = taught.offset
    except InputError as exc:
        failures.append(StepFailure("teach", str(exc)))
    return Commissioning(
        layout, robot, camera, survey, mount, taught, commissioned_layout, commissioned_robot, offset, views,
        tuple(failures),
    )  # fmt: skip


def summary_values(c: Commissioning) -> dict[str, object]:
    """Every calibrated value with its standard deviation, as plain numbers (millimetres and degrees)."""
    out: dict[str, object] = {"ready": c.ready, "verdict": c.verdict()}
    if c.survey is not None:
        out["markers"] = {
            role: {
                "x_mm": m.spec.x * 1e3, "y_mm": m.spec.y * 1e3, "z_mm": m.spec.z * 1e3,
                "roll_deg": math.degrees(m.spec.roll), "pitch_deg": math.degrees(m.spec.pitch),
                "yaw_deg": math.degrees(m.spec.yaw), "side_mm": m.side * 1e3,
                "sd": {k: (math.degrees(v) if k in ("roll", "pitch", "yaw") else v * 1e3) for k, v in m.sd.items()},
            }
            for role, m in c.survey.markers.items()
        }  # fmt: skip
        out["survey_rms_px"] = c.survey.rms_px
        out["survey_views"] = len(c.survey.used)
    if c.mount is not None:
        m, sd = c.mount.mount, c.mount.sd
        out["camera_mount"] = {
            **{f"{k}_mm": getattr(m, k) * 1e3 for k in ("x", "y", "z")},
            **{f"{k}_deg": math.degrees(getattr(m, k)) for k in ("roll", "pitch", "yaw")},
            "sd": {k: (sd[k] * 1e3 if k in ("x", "y", "z") else math.degrees(sd[k])) for k in ("x", "y", "z", "roll",
                                                                                                  "pitch", "yaw")},
        }  # fmt: skip
        out["odometry"] = to_mapping(c.robot.odometry)
        out["dock_lean_deg"] = [math.degrees(c.mount.dock_roll), math.degrees(c.mount.dock_pitch)]
        out["odometry_scale"] = c.mount.odometry_scale
        out["mount_rms_px"] = c.mount.rms_px
    if c.teach is not None:
        o = c.teach.offset
        out["charging_offset"] = {"x_mm": o.x * 1e3, "y_mm": o.y * 1e3, "yaw_deg": o.yaw_deg}
        out["charging_sd"] = {"x_mm": c.teach.sd[0] * 1e3, "y_mm": c.teach.sd[1] * 1e3,
                              "yaw_deg": math.degrees(c.teach.sd[2])}  # fmt: skip
    out["failures"] = [f"{f.step}: {f.reason}" for f in c.failures]
    return out
