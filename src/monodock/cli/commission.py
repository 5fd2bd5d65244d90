"""``monodock commission``: survey the dock, calibrate the camera mount, teach the charging pose; one report."""

from __future__ import annotations

import argparse

from monodock.calibrate.commission import commission
from monodock.calibrate.survey import surveyed_layout_text
from monodock.calibrate.teach import taught_config_text
from monodock.cli.calibrate_dock import add_survey_limits, survey_limits
from monodock.cli.options import SubParsers, add_command
from monodock.core.atomic import atomic_directory, check_writable
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.report.commission import write_commission_report

__all__ = ["add_parser", "run"]

FILES = {
    "layout.yaml": "the dock's layout: surveyed, stood up on the floor",
    "robot.yaml": "the robot: its camera mount and odometry calibrated",
    "docking.yaml": "the docking config: the taught charging_offset",
    "report.html": "this report (report.md and summary.json beside it)",
}


def add_parser(subparsers: SubParsers) -> None:
    """Add ``commission``."""
    p = add_command(subparsers, "commission", run)
    p.add_argument("--survey", nargs="+", required=True, metavar="IMAGES", help="the survey's photographs (10-40)")
    p.add_argument("--drive", required=True, help="recording of a minute's drive before the dock (with odometry)")
    p.add_argument("--teach", required=True, help="recording of the back-off from the contacts (with battery state)")
    p.add_argument("--camera", required=True, help="the robot camera's file (camera_info YAML or OpenCV)")
    p.add_argument("--survey-camera", help="the survey photos' camera, when not the robot's")
    p.add_argument("--layout", required=True, help="the nominal layout YAML")
    p.add_argument("--robot", required=True, help="the nominal robot YAML")
    p.add_argument("--out", required=True, help="folder to write")
    p.add_argument("--scale-from", choices=("print", "odometry"), default="print",
                   help="the ruler of lengths: the printed markers (default) or the wheels")  # fmt: skip
    add_survey_limits(
        p,
        views="survey views used",
        position="refuse a survey whose marker positions are more uncertain",
        tilt="refuse a survey whose marker tilts are more uncertain",
    )
    p.add_argument("--docked-at-start", action="store_true",
                   help="the teach recording has no battery state and starts on the contacts")  # fmt: skip
    p.add_argument("--force", action="store_true", help="replace --out")


def run(args: argparse.Namespace) -> int:
    """commission a new robot and dock: survey, camera mount, charging pose; one report with a verdict

    Runs calibrate layout on the survey photos, calibrate mount on the drive and teach on the back-off, each with what
    the step before it found, and writes the commissioned layout, robot file and docking config with an HTML report:
    every value with its uncertainty, the residuals, the survey's views with the fitted markers, the drive's path, and a
    verdict (ready to dock, or what to redo)."""
    inputs = [*args.survey, args.drive, args.teach, args.camera, args.survey_camera, args.layout, args.robot]
    check_writable(args.out, force=args.force, inputs=inputs)
    camera = CameraModel.load(args.camera)
    survey_camera = CameraModel.load(args.survey_camera) if args.survey_camera else None
    nominal_layout, nominal_robot = DockLayout.load(args.layout), RobotConfig.load(args.robot)
    limits = survey_limits(args)
    result = commission(
        args.survey, args.drive, args.teach, camera, nominal_layout, nominal_robot, scale_from=args.scale_from,
        max_views=args.max_views, limits=limits, survey_camera=survey_camera, docked_at_start=args.docked_at_start,
    )  # fmt: skip
    with atomic_directory(args.out, force=args.force) as tmp:
        if result.survey is not None:
            (tmp / "layout.yaml").write_text(surveyed_layout_text(result.survey, result.layout), encoding="utf-8")
        result.robot.save(tmp / "robot.yaml")
        if result.teach is not None:
            (tmp / "docking.yaml").write_text(taught_config_text(result.teach, None, args.teach), encoding="utf-8")
        written = {k: v for k, v in FILES.items() if (tmp / k).exists() or k == "report.html"}
        write_commission_report(result, tmp, written)
    if result.survey is not None:
        print(result.survey.summary())
    if result.mount is not None:
        print(result.mount.summary())
    if result.teach is not None:
        print(result.teach.summary())
    for line in result.verdict():
        print(line)
    print(f"-> {args.out}/report.html")
    if not result.ready:  # exit 2: the files and the report are written, the robot is not ready
        raise InputError(f"not ready: {result.verdict()[0]} (the report says more: {args.out}/report.html)")
    return 0
