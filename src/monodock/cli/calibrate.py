"""``monodock calibrate``: camera intrinsics from a checkerboard; the LiDAR mount (camera-LiDAR extrinsics); the
dock's layout from photographs (``layout``); the camera mount from a drive (``mount``)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from monodock.calibrate.extrinsics import (
    FACE_GATE_M,
    DockView,
    ExtrinsicsResult,
    extrinsics_from_pairs,
    extrinsics_from_recording,
    extrinsics_from_target_views,
    face_half_width,
    face_points,
    read_pairs_csv,
    target_views_from_recording,
    tf_line,
    write_result_yaml,
)
from monodock.calibrate.intrinsics import (
    DEFAULT_MAX_BLUR_PX,
    calibrate_intrinsics,
    parse_board,
    select_frames,
    summary,
)
from monodock.calibrate.target import DiamondTarget, read_target_views
from monodock.cli.calibrate_dock import add_layout_parser, add_mount_parser
from monodock.cli.options import SubParsers, add_command, add_pairing_tolerance
from monodock.core import transforms
from monodock.core.atomic import check_writable, resolved, write_bytes_atomic, write_text_atomic
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.projection import project_to_image, scan_in_base
from monodock.core.robot import RobotConfig
from monodock.errors import ConfigError, InputError
from monodock.io.frames import open_frames, read_image
from monodock.recording.read import is_recording
from monodock.report.calibration import coverage_png, overlay_png

__all__ = ["add_parser", "run_extrinsics", "run_intrinsics"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``calibrate`` with its four sub-commands."""
    # A group with no run function of its own (add_command): its help is written here.
    cal = subparsers.add_parser(
        "calibrate",
        help="camera intrinsics; camera-LiDAR extrinsics; the dock's layout from photos; the camera mount from a drive",
    )
    cal_sub = cal.add_subparsers(dest="calibrate_command", required=True, metavar="WHAT")
    _add_intrinsics(cal_sub)
    _add_extrinsics(cal_sub)
    add_layout_parser(cal_sub)
    add_mount_parser(cal_sub)


def _add_intrinsics(calibrate_subparsers: SubParsers) -> None:
    """Add ``intrinsics`` to the ``monodock calibrate`` sub-commands."""
    p = add_command(calibrate_subparsers, "intrinsics", run_intrinsics)
    p.add_argument("images", nargs="+", metavar="IMAGES", help="image files, folders of images, videos or recordings")
    p.add_argument("--board", default="8x6", help="inner corners per row x per column (default: 8x6, 9x7 squares)")
    p.add_argument("--square", type=float, default=0.025, help="square side, metres, in (0, 10] (default: 0.025)")
    p.add_argument("--out", required=True, help="camera_info YAML to write")
    p.add_argument("--coverage", help="coverage heat map PNG (default: <out stem>_coverage.png next to --out)")
    p.add_argument(
        "--max-views", type=int, default=25, help="views picked from a video or recording, 1-1000 (default: 25)"
    )
    p.add_argument(
        "--max-blur",
        type=float,
        default=DEFAULT_MAX_BLUR_PX,
        help=f"reject views whose edges are wider than this, px, in (0, 100] (default: {DEFAULT_MAX_BLUR_PX:g})",
    )
    p.add_argument("--min-views", type=int, default=5, help="fewest usable views, 1-1000 (default: 5)")
    p.add_argument("--name", default="camera", help="camera_name in the YAML (default: camera)")
    p.add_argument("--force", action="store_true", help="replace existing output files")


def _input_views(args: argparse.Namespace, board: tuple[int, int]) -> Iterable[tuple[str, NDArray[np.generic]]]:
    """(name, image) of every still image, and of the frames picked from each video or recording."""
    for item in args.images:
        p = Path(item)
        with open_frames([p]) as source:
            frames = ((f.name, f.image) for f in source if f.image is not None)
            if source.kind in ("video", "recording"):
                named = ((f"{p.name}#{n}", img) for n, img in frames)
                yield from select_frames(named, board, max_views=args.max_views, max_blur_px=args.max_blur)
            else:
                yield from frames


def run_intrinsics(args: argparse.Namespace) -> int:
    """camera intrinsics and distortion from checkerboard images, a video or a recording

    Calibrate fx, fy, cx, cy and plumb_bob distortion from views of a checkerboard; write ROS camera_info YAML and a PNG
    of how the corners covered the image."""
    board = parse_board(args.board)
    if not (math.isfinite(args.square) and args.square > 0):
        raise InputError(f"--square must be a positive length in metres, got {args.square}")
    if not (math.isfinite(args.max_blur) and args.max_blur > 0):
        raise InputError(f"--max-blur must be a positive number of pixels, got {args.max_blur}")
    if args.square > 10 or args.max_blur > 100:
        raise InputError(f"--square must be at most 10 m and --max-blur 100 px, got {args.square} and {args.max_blur}")
    if not (1 <= args.max_views <= 1000 and 1 <= args.min_views <= 1000):
        raise InputError(f"--max-views and --min-views must be 1-1000, got {args.max_views} and {args.min_views}")
    out = Path(args.out)
    cov = Path(args.coverage) if args.coverage else out.with_name(f"{out.stem}_coverage.png")
    if resolved(cov) == resolved(out):
        raise InputError(f"--coverage {cov} is the same file as --out")
    check_writable(out, force=args.force, inputs=args.images)
    check_writable(cov, force=args.force, inputs=args.images)
    result = calibrate_intrinsics(
        _input_views(args, board),
        board,
        args.square,
        max_blur_px=args.max_blur,
        min_views=args.min_views,
        name=args.name,
    )
    # What every loader would refuse is not written: the warnings say what the views lacked.
    try:
        result.camera.check_plausible("the calibration")
    except ConfigError as exc:
        lacking = "; ".join(result.warnings) or "take more views, nearer the image's edges and corners"
        raise InputError(f"{exc}; nothing written ({lacking})") from None
    result.camera.save(out, force=args.force)
    write_bytes_atomic(cov, coverage_png(result), force=args.force)
    print(summary(result))
    print(f"-> {out}, {cov}")
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def _add_extrinsics(calibrate_subparsers: SubParsers) -> None:
    """Add ``extrinsics`` to the ``monodock calibrate`` sub-commands."""
    p = add_command(calibrate_subparsers, "extrinsics", run_extrinsics)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--pairs", help="CSV of LiDAR point / pixel pairs: x,y,u,v (optional z), metres and pixels")
    src.add_argument("--recording", help="recording with camera images and LiDAR scans of the charger")
    src.add_argument(
        "--target-views",
        help="the diamond target seen edge-on: a recording (rosbag2 or ROS 1 bag; images paired with scans by "
        "stamp) or a folder of NNNN.png images and scans.npz; solves all six mount fields",
    )
    p.add_argument(
        "--target", help="with --target-views: the diamond target YAML (default: 0.5 m side, 16 cm markers, ids 20-23)"
    )
    p.add_argument("--robot", required=True, help="robot YAML: the camera mount, and the LiDAR mount as the prior")
    p.add_argument("--camera", help="camera file (needed with --pairs; default with --recording: its CameraInfo)")
    p.add_argument("--layout", help="dock layout YAML (needed with --recording)")
    p.add_argument("--out", required=True, help="result YAML: laser_mount in base_link, the laser in camera_optical")
    p.add_argument("--tf", help="also write the tf line 'x y z qx qy qz qw' (base_link -> laser) to this file")
    p.add_argument("--robot-out", help="also write the robot YAML with the calibrated laser mount")
    p.add_argument("--overlay", help="PNG: the LiDAR points projected on a camera frame with the calibrated mount")
    p.add_argument(
        "--image", help="with --pairs and --overlay: a frame the pairs were clicked in (points: magenta, clicks: blue)"
    )
    add_pairing_tolerance(p, "image/scan pairing tolerance, s, in (0, 10] (default 0.05)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")


def run_extrinsics(args: argparse.Namespace) -> int:
    """the LiDAR mount relative to the camera: from point/pixel pairs, or from a recording of the dock

    Calibrate the LiDAR mount in base_link, given the camera mount. With --pairs: SolvePnP on LiDAR points (laser frame)
    matched to pixels (CSV x,y,u,v). With --recording: the charger face the camera sees (board PnP) must hold the
    LiDAR's face points; solves x, y, yaw and keeps z, roll, pitch."""
    outputs = [o for o in (args.out, args.tf, args.robot_out, args.overlay) if o]
    if len({os.path.abspath(o) for o in outputs}) < len(outputs):
        raise InputError("--out, --tf, --robot-out and --overlay must be different files")
    inputs = (args.pairs, args.recording, args.target_views, args.target, args.robot, args.camera, args.layout)
    for o in outputs:
        check_writable(o, force=args.force, inputs=(*inputs, args.image))
    if not (args.tolerance > 0 and math.isfinite(args.tolerance)):
        raise InputError(f"--tolerance must be a positive number of seconds, got {args.tolerance}")
    robot = RobotConfig.load(args.robot)
    png: bytes | None = None
    if args.target_views:
        result, png = _target_form(args, robot)
    elif args.pairs:
        if not args.camera:
            raise InputError("--pairs needs --camera (the intrinsics the pixels were clicked in)")
        if args.overlay and not args.image:
            raise InputError("--overlay with --pairs needs --image (the camera frame to draw on)")
        camera = CameraModel.load(args.camera)
        points, pixels = read_pairs_csv(args.pairs)
        result = extrinsics_from_pairs(points, pixels, camera, robot.base_T_optical(), prior=robot.laser_mount)
        if args.overlay:
            image = read_image(args.image)
            calibrated = result.robot(robot)
            # Magenta: the LiDAR points under the calibrated mount; blue: the clicked pixels they should cover.
            projected = project_to_image(transforms.apply(calibrated.base_T_laser(), points), camera, calibrated)
            png = overlay_png(
                image,
                np.vstack([projected, pixels]),
                np.r_[np.ones(len(points), bool), np.zeros(len(pixels), bool)],
                camera,
                calibrated,
            )
    else:
        if not args.layout:
            raise InputError("--recording needs --layout (the charger's markers)")
        layout = DockLayout.load(args.layout)
        camera_arg = CameraModel.load(args.camera) if args.camera else None
        result, rv = extrinsics_from_recording(
            args.recording, layout, robot, camera=camera_arg, tolerance_s=args.tolerance
        )
        for w in rv.warnings:
            print(f"warning: {w}")
        if args.overlay and rv.overlay_frame is not None:
            image, scan, det = rv.overlay_frame
            calibrated = result.robot(robot)
            view = DockView("", rv.views[0].base_T_dock, scan.points())
            sel = face_points(view, calibrated.base_T_laser(), face_half_width(layout), FACE_GATE_M[-1])
            px = project_to_image(scan_in_base(scan, calibrated), rv.camera, calibrated)
            png = overlay_png(image, px, sel, rv.camera, calibrated, layout, det)
    print(result.summary())
    write_result_yaml(args.out, result, force=args.force)
    written = [args.out]
    if args.tf:
        write_text_atomic(args.tf, tf_line(result) + "\n", force=args.force)
        written.append(args.tf)
    if args.robot_out:
        result.robot(robot).save(args.robot_out, force=args.force)
        written.append(args.robot_out)
    if png is not None and args.overlay:
        write_bytes_atomic(args.overlay, png, force=args.force)
        written.append(args.overlay)
    print("wrote " + ", ".join(written))
    return 0


def _target_form(args: argparse.Namespace, robot: RobotConfig) -> tuple[ExtrinsicsResult, bytes | None]:
    """``--target-views``: the diamond target in a recording or a folder of views; the result and its overlay."""
    target = DiamondTarget.load(args.target) if args.target else DiamondTarget()
    recorded_camera = None
    if is_recording(args.target_views):
        views, recorded_camera, warnings = target_views_from_recording(args.target_views, tolerance_s=args.tolerance)
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
    else:
        views = read_target_views(args.target_views)
    if args.camera:
        camera = CameraModel.load(args.camera)
    elif recorded_camera is not None:
        camera = recorded_camera
    else:
        raise InputError("--target-views needs --camera (the intrinsics of the images) unless a recording has them")
    result = extrinsics_from_target_views(views, camera, robot.base_T_optical(), robot.laser_mount, target)
    png = None
    if args.overlay:
        # The papers' Fig. 8c on the first view: the scan through the calibrated mount must run across the target.
        calibrated = result.robot(robot)
        pixels = project_to_image(scan_in_base(views[0].scan, calibrated), camera, calibrated)
        png = overlay_png(views[0].image, pixels, np.zeros(len(pixels), dtype=bool), camera, calibrated)
    return result, png
