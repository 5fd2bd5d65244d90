"""``monodock estimate``: the DockPose in images, folders, videos or recordings, as EST.csv (and a Nav2 bag)."""

from __future__ import annotations

import argparse
import csv
import io
import math
import os

from tqdm import tqdm

from monodock.cli.options import (
    SubParsers,
    add_calibration,
    add_command,
    add_model_and_method,
    add_refinement,
    build_estimator,
)
from monodock.core.atomic import check_writable, write_text_atomic
from monodock.errors import InputError
from monodock.estimation.estimator import Estimator, FrameEstimates
from monodock.io.frames import open_frames
from monodock.io.nav2 import UNSTAMPED_BAG, write_pose_bag
from monodock.io.rows import estimates_csv

__all__ = ["add_parser", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``estimate``."""
    e = add_command(subparsers, "estimate", run)
    e.add_argument("inputs", nargs="+", metavar="INPUT", help="image files, folders of images, videos, or recordings")
    add_model_and_method(e)
    e.add_argument("--out", required=True, help="EST.csv to write")
    e.add_argument("--bag", metavar="OUT_BAG", help="also write the valid poses as a Nav2 detected_dock_pose rosbag2")
    add_refinement(e)
    e.add_argument("--skip-bad", action="store_true", help="an unreadable image gives an invalid row, not an error")
    e.add_argument("--force", action="store_true", help="overwrite an existing output")
    add_calibration(e, required=False)


def _estimate_all(args: argparse.Namespace, estimator: Estimator) -> list[FrameEstimates]:
    """Every frame's estimates; with ``--skip-bad`` an unreadable or unusable frame is an invalid row."""
    results = []
    with open_frames(args.inputs, skip_bad=args.skip_bad) as frames:
        for f in tqdm(frames, desc="estimate", unit="frame", leave=False, disable=None):
            if f.image is None:
                results.append(estimator.failed(f.name, f.stamp, f.error))
                continue
            try:
                results.append(estimator.estimate(f.name, f.stamp, f.image))
            except InputError as exc:
                if not args.skip_bad:
                    raise
                results.append(estimator.failed(f.name, f.stamp, str(exc)))
    return results


def run(args: argparse.Namespace) -> int:
    """estimate the DockPose in images, folders, videos or recordings"""
    estimator = build_estimator(args)
    inputs = (*args.inputs, args.model, args.camera, args.layout, args.robot)
    check_writable(args.out, force=args.force, inputs=inputs)
    if args.bag:
        if os.path.abspath(args.bag) == os.path.abspath(args.out):
            raise InputError(f"--bag {args.bag} is the same path as --out")
        check_writable(args.bag, force=args.force, inputs=inputs)
    results = _estimate_all(args, estimator)
    valid_stamps = [r.stamp for r in results if any(e.valid for e in r.estimates.values())]
    if args.bag and valid_stamps and not any(math.isfinite(t) for t in valid_stamps):
        raise InputError(UNSTAMPED_BAG)
    text = estimates_csv(results)
    write_text_atomic(args.out, text, force=args.force)
    valid = sum(1 for r in results for e in r.estimates.values() if e.valid)
    print(f"{estimator.method}: {valid}/{len(results)} frames with an estimate -> {args.out}")
    if args.bag:
        n = write_pose_bag(args.bag, csv.DictReader(io.StringIO(text)), force=args.force)
        print(f"{n} PoseStamped on detected_dock_pose (base_link) -> {args.bag}")
    return 0
