"""``monodock show``: one image's overlay PNG: the detected markers, their ids and the board estimate's dock axes."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from monodock.cli.options import SubParsers, add_calibration, add_command, load_calibration
from monodock.core.atomic import check_writable, write_bytes_atomic
from monodock.estimation.estimator import Estimator
from monodock.estimation.overlay import estimates_png
from monodock.io.frames import read_image

__all__ = ["add_parser", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``show``."""
    w = add_command(subparsers, "show", run)
    w.add_argument("image")
    w.add_argument("--out", required=True, help="PNG to write")
    w.add_argument("--force", action="store_true")
    add_calibration(w, required=True)


def run(args: argparse.Namespace) -> int:
    """overlay PNG: detected markers, ids and the board estimate's dock axes"""
    camera, layout, robot = load_calibration(args)
    check_writable(args.out, force=args.force, inputs=(args.image, args.camera, args.layout, args.robot))
    image = read_image(args.image)
    estimator = Estimator(camera, layout, robot, ("board",))
    result = estimator.estimate(Path(args.image).name, math.nan, image)
    write_bytes_atomic(args.out, estimates_png(image, result, estimator), force=args.force)
    e = result.estimates["board"]
    print(f"board: {e.pose if e.pose else e.reason} -> {args.out}")
    return 0
