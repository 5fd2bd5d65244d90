"""``monodock teach``: the charging pose from a back-off off the contacts, as a docking config's ``charging_offset``."""

from __future__ import annotations

import argparse
from pathlib import Path

from monodock.calibrate.teach import taught_config_text, teach_from_recording
from monodock.cli.options import SubParsers, add_command, add_recording_inputs, recording_inputs
from monodock.core.atomic import check_writable, write_text_atomic
from monodock.dock.config import load_docking_config

__all__ = ["add_parser", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``teach``."""
    p = add_command(subparsers, "teach", run)
    add_recording_inputs(
        p,
        of="the back-off",
        layout="the dock's layout YAML (commissioned)",
        robot="the robot YAML (commissioned: mount and odometry)",
    )
    p.add_argument("--out", required=True, help="docking config YAML to write")
    p.add_argument("--config", help="a docking config to start from: the output is it with the charging_offset")
    p.add_argument("--method", choices=("fused", "board"), default="fused", help="the estimator (default fused)")
    p.add_argument(
        "--docked-at-start",
        action="store_true",
        help="the recording has no battery state and starts with the robot on the contacts",
    )
    p.add_argument("--force", action="store_true", help="overwrite --out")


def run(args: argparse.Namespace) -> int:
    """teach the charging pose: a recording of the robot backing off the charger's contacts

    Drive or push the robot onto the contacts until it charges, then back off about a metre straight while recording
    (images, camera_info, nav_msgs/Odometry, sensor_msgs/BatteryState). Writes a docking config with the charging_offset
    that dock-sim (--config) and the docking node (config:=) read."""
    check_writable(
        args.out, force=args.force, inputs=(args.recording, args.layout, args.robot, args.camera, args.config)
    )
    base = load_docking_config(args.config) if args.config else None
    layout, robot, camera = recording_inputs(args)
    taught = teach_from_recording(
        args.recording, layout, robot, camera=camera, method=args.method, docked_at_start=args.docked_at_start
    )
    print(taught.summary())
    write_text_atomic(Path(args.out), taught_config_text(taught, base, Path(args.recording).name), force=args.force)
    print(f"-> {args.out}")
    return 0
