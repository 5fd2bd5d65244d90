"""``monodock calibrate layout`` and ``monodock calibrate mount``: the dock surveyed from photographs, the camera
mount from a short drive (``monodock.calibrate.survey``, ``monodock.calibrate.mount``)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from monodock.calibrate.mount import calibrate_mount_of, frames_from_recording
from monodock.calibrate.survey import SurveyLimits, survey_layout, surveyed_layout_text
from monodock.calibrate.survey_views import views_from_inputs
from monodock.cli.options import SubParsers, add_command, add_recording_inputs, float_in, int_in, recording_inputs
from monodock.core.atomic import check_writable, write_text_atomic
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError

__all__ = [
    "add_layout_parser",
    "add_mount_parser",
    "add_survey_limits",
    "run_layout",
    "run_mount",
    "survey_limits",
]

# How uncertain a surveyed marker may be (one standard deviation) before the survey refuses it: the flag, its unit,
# the most it may be set to, its default.
_SD_LIMITS = (("--max-position-sd", "mm", 100.0, 0.3), ("--max-angle-sd", "degrees", 45.0, 0.15))


def add_survey_limits(p: argparse.ArgumentParser, *, views: str, position: str, tilt: str) -> None:
    """``--max-views`` and the survey's limits, ``--max-position-sd`` and ``--max-angle-sd`` (``survey_limits``), for
    ``calibrate layout`` and ``commission``; ``views``, ``position``, ``tilt``: each help's words before its range."""
    p.add_argument("--max-views", type=int_in(6, 1000), default=40, help=f"{views}, 6-1000 (default 40)")
    for (flag, unit, most, default), what in zip(_SD_LIMITS, (position, tilt), strict=True):
        text = f"{what}, {unit}, in (0, {most:g}] (default {default:g})"
        p.add_argument(flag, type=float_in(0.0, most, low_open=True), default=default, help=text)


def survey_limits(args: argparse.Namespace) -> SurveyLimits:
    """The SurveyLimits of ``add_survey_limits``' options; a printed side is held to the position's limit."""
    return SurveyLimits(args.max_position_sd / 1e3, math.radians(args.max_angle_sd), args.max_position_sd / 1e3)


def add_layout_parser(calibrate_subparsers: SubParsers) -> None:
    """Add ``layout`` to the ``monodock calibrate`` sub-commands."""
    p = add_command(calibrate_subparsers, "layout", run_layout)
    p.add_argument("images", nargs="+", metavar="IMAGES", help="image files, folders of images, videos or recordings")
    p.add_argument("--camera", help="camera file of the views (default: a recording's CameraInfo)")
    p.add_argument("--layout", required=True, help="the nominal layout YAML (dictionary, ids, where you put them)")
    p.add_argument("--robot", help="robot YAML: the views are its camera on the floor, with this mount")
    p.add_argument("--out", required=True, help="the surveyed layout YAML to write")
    add_survey_limits(
        p,
        views="views used",
        position="refuse when a marker's position is more uncertain than this",
        tilt="refuse when a marker's tilt is more uncertain than this",
    )
    p.add_argument("--force", action="store_true", help="overwrite --out")


def run_layout(args: argparse.Namespace) -> int:
    """survey the dock from 10-40 photographs: every marker's pose and printed side

    Bundle adjustment over every refined marker corner of the views (photos, a video, frames of a recording; any
    calibrated camera): each marker's x, y, z, roll, pitch, yaw and side, with its standard deviation. The nominal
    layout gives the dictionary, the ids and the start. With --robot the views are the robot's own camera on the floor:
    the heights and the dock's up are measured."""
    check_writable(args.out, force=args.force, inputs=[*args.images, args.camera, args.layout, args.robot])
    nominal = DockLayout.load(args.layout)
    robot = RobotConfig.load(args.robot) if args.robot else None
    camera = CameraModel.load(args.camera) if args.camera else None
    views, skipped, camera, offset = views_from_inputs(args.images, camera, nominal, max_views=args.max_views)
    limits = survey_limits(args)
    survey = survey_layout(views, camera, nominal, robot=robot, limits=limits, skipped=skipped, edge_offset=offset)
    print(survey.summary())
    write_text_atomic(Path(args.out), surveyed_layout_text(survey), force=args.force)
    print(f"-> {args.out}")
    return 0


def add_mount_parser(calibrate_subparsers: SubParsers) -> None:
    """Add ``mount`` to the ``monodock calibrate`` sub-commands."""
    p = add_command(calibrate_subparsers, "mount", run_mount)
    add_recording_inputs(
        p,
        of="the drive",
        layout="the dock's layout YAML (surveyed: calibrate layout)",
        robot="the nominal robot YAML (its camera mount is the start)",
    )
    p.add_argument("--out", required=True, help="the robot YAML to write, with the calibrated camera mount")
    p.add_argument(
        "--layout-out", help="also write the layout as the drive measured it (stood up on the floor, scaled)"
    )
    p.add_argument(
        "--scale-from",
        choices=("print", "odometry"),
        default="print",
        help="the ruler: the printed markers (default; the odometry's distance error is reported) or the wheels "
        "(the layout and the mount scaled to them)",
    )
    p.add_argument("--image-topic", help="the recording's image topic, when it has several")
    p.add_argument("--force", action="store_true", help="overwrite the outputs")


def run_mount(args: argparse.Namespace) -> int:
    """the camera mount from a minute's drive before the dock (images, camera_info, nav_msgs/Odometry)

    Hand-eye calibration for planar motion: the camera mount (x, y, z, roll, pitch, yaw) that makes what the camera sees
    of the dock agree with the wheel odometry, each with its standard deviation; also the dock's lean against the floor
    and the odometry's errors. z is measured against the layout's heights (a drive on a flat floor cannot tell a
    camera's height)."""
    outputs = [o for o in (args.out, args.layout_out) if o]
    if len({str(Path(o).resolve()) for o in outputs}) < len(outputs):
        raise InputError("--out and --layout-out must be different files")
    for o in outputs:
        check_writable(o, force=args.force, inputs=(args.recording, args.layout, args.robot, args.camera))
    layout, nominal, camera = recording_inputs(args)
    drive = frames_from_recording(args.recording, layout, camera=camera, image_topic=args.image_topic)
    result = calibrate_mount_of(drive, layout, nominal, scale_from=args.scale_from)
    print(result.summary())
    result.robot(nominal).save(args.out, force=args.force)
    written = [args.out]
    if args.layout_out:
        DockLayout.save(result.layout(layout), args.layout_out, force=args.force)
        written.append(args.layout_out)
    for u in result.unexcited:
        print(f"warning: the drive did not excite {u}", file=sys.stderr)
    print("-> " + ", ".join(written))
    return 0
