"""``monodock design``: the dock a start envelope needs (markers, sizes, dictionary, spacing, a far-field marker),
with its predicted detection and accuracy, checked in the simulator, and its printable kit."""

from __future__ import annotations

import argparse
import math
import re
import shlex
import sys
from pathlib import Path

from monodock.cli.options import SubParsers, add_command, add_seed, float_in, int_in
from monodock.core.atomic import atomic_directory, check_writable, write_bytes_atomic
from monodock.core.camera import CameraModel
from monodock.core.robot import RobotConfig
from monodock.design import Envelope, Tolerance, check_in_sim, check_poses, design
from monodock.errors import InputError
from monodock.report.design import KIT_PAPERS, check_summary, design_report
from monodock.report.dock_kit import dock_kit_pdf, misfit

__all__ = ["add_parser", "parse_tolerance", "run"]

_TOL = re.compile(r"^\s*([0-9.eE+-]+)\s*(mm|cm|m)\s*,\s*([0-9.eE+-]+)\s*(deg|°)\s*$")
_UNIT = {"mm": 0.001, "cm": 0.01, "m": 1.0}
# The largest charger face the design may propose, each in (0, 10] m: the flag, its default, what it bounds.
_FACE_LIMITS = (("--max-width", 1.0, "charger face width"), ("--max-height", 1.2, "charger face height from the floor"))


def parse_tolerance(text: str) -> tuple[float, float]:
    """'1cm,1deg' -> (0.01 m, 1° in rad): the final pose accuracy wanted (σ of x and y, σ of yaw)."""
    m = _TOL.match(text)
    if m is None:
        raise argparse.ArgumentTypeError(f"expected a length and an angle like 1cm,1deg, got {text!r}")
    try:
        xy, yaw = float(m.group(1)) * _UNIT[m.group(2)], math.radians(float(m.group(3)))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a length and an angle like 1cm,1deg, got {text!r}") from None
    if not (0 < xy <= 1.0 and 0 < yaw <= math.radians(45) and math.isfinite(xy) and math.isfinite(yaw)):
        raise argparse.ArgumentTypeError(f"tolerance must be 0-1 m and 0-45 deg, got {text!r}")
    return xy, yaw


def add_parser(subparsers: SubParsers) -> None:
    """Add ``design``."""
    p = add_command(subparsers, "design", run)
    p.add_argument("--camera", required=True, help="camera YAML (ROS camera_info / OpenCV calibration)")
    p.add_argument("--robot", help="robot YAML: the camera mount (default: the papers' robot)")
    p.add_argument(
        "--max-distance",
        type=float_in(0.5, 20.0, low_open=True),
        default=5.0,
        help="farthest start, base_link to the face centre, m (0.5-20, default 5)",
    )
    p.add_argument(
        "--max-bearing",
        type=float_in(0.0, 90.0, high_open=True),
        default=60.0,
        help="widest start off the dock's axis, degrees (0-90, 90 itself excluded; default 60)",
    )
    p.add_argument(
        "--tolerance",
        type=parse_tolerance,
        default=(0.01, math.radians(1.0)),
        metavar="LEN,ANGLE",
        help="final pose accuracy wanted: the bound's σ of x and y, and of yaw, near the dock, e.g. 5mm,0.5deg "
        "(default 1cm,1deg)",
    )
    for flag, default, what in _FACE_LIMITS:
        text = f"{what}, m (0-10, default {default})"
        p.add_argument(flag, type=float_in(0.0, 10.0, low_open=True), default=default, help=text)
    p.add_argument(
        "--blur",
        action="store_true",
        help="budget for heavy (6 px) motion blur: the 99 %% threshold measured under blur (about 7-9 px a cell) "
        "instead of 5 px a cell without; the simulator check renders with that blur",
    )
    p.add_argument(
        "--check-poses",
        type=int_in(0, 500),
        default=16,
        help="envelope poses rendered in the simulator to check the prediction (0-500, default 16; 0: none)",
    )
    add_seed(p)
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write (a new one, or replaced with --force)")
    p.add_argument("--force", action="store_true", help="replace an existing DIR")


def run(args: argparse.Namespace) -> int:
    """design a dock for a start envelope: markers, sizes, dictionary, spacing, far marker; report and kit

    Propose the smallest charger face whose markers a robot facing it detects from every start 0.5 m to --max-distance
    from the face centre within ±--max-bearing of its axis (the detection model of bench/detection_range.py), with the
    papers' three markers all in view near the dock and the near-field Cramér–Rao bound within --tolerance. Writes
    DIR/layout.yaml, report.html with the maps, design.json, and the printable kit in DIR/kit/; the prediction is
    checked in the simulator (docs/design.md)."""
    # Load, design (or say in one line why nothing fits), check in the simulator, write DIR in one rename.
    check_writable(args.out, force=args.force, inputs=(args.camera, args.robot))
    camera = CameraModel.load(args.camera)
    robot = RobotConfig.load(args.robot) if args.robot else RobotConfig.default()
    envelope = Envelope(args.max_distance, math.radians(args.max_bearing))
    tolerance = Tolerance(*args.tolerance)
    d = design(camera, robot, envelope, tolerance, max_width=args.max_width, max_height=args.max_height, blur=args.blur)
    paper = next((p for p in KIT_PAPERS if misfit(d.layout, p) is None), None)
    if paper is None:
        raise InputError("the proposed far marker does not fit on A0 paper")
    poses = check_poses(envelope, args.check_poses, args.seed)
    checks = check_in_sim(d.layout, camera, robot, poses, blur=args.blur, face=d.face, seed=args.seed)
    kit = dock_kit_pdf(d.layout, paper)
    command = "monodock " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else "monodock design"
    with atomic_directory(args.out, force=args.force) as tmp:
        d.layout.save(tmp / "layout.yaml")
        (tmp / "kit").mkdir()
        write_bytes_atomic(tmp / "kit" / f"dock_kit_{paper.name.lower()}.pdf", kit)
        d.layout.save(tmp / "kit" / "layout.yaml")
        design_report(tmp, d, checks, kit_paper=paper.name, command=command)
    out = Path(args.out)
    names = ", ".join(f"{m.role} {d.layout.side(m.role) * 100:.0f} cm" for m in d.layout.markers)
    print(
        f"design: {d.layout.dictionary}, {names}; face {d.face[0] * 100:.0f} x {d.face[1] * 100:.0f} cm; near-field "
        f"σ {d.near_sigma[0] * 100:.2f} cm, {math.degrees(d.near_sigma[2]):.2f} deg -> {out / 'layout.yaml'}"
    )
    if checks:
        s = check_summary(checks)
        print(
            f"simulator check, {len(checks)} poses: predicted markers all decoded at "
            f"{s['all_predicted_detected'] * 100:.0f} %, error within 3σ at {s['within_3_sigma'] * 100:.0f} % "
            f"-> {out / 'report.html'}"
        )
    print(f"print {out / 'kit'} on {paper.name} at 100 % / actual size")
    return 0
