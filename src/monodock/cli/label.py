"""``monodock label``: LiDAR labels for a recording: detect, pair every image with a scan, write the dataset."""

from __future__ import annotations

import argparse
import sys

from monodock.cli.options import SubParsers, add_command, add_jobs, add_topics, jobs, positive_seconds
from monodock.core.atomic import check_writable
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import MonodockError
from monodock.learning.dataset import Dataset, label_error_table, label_errors, label_recording, write_dataset

__all__ = ["add_parser", "label", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``label``."""
    lb = add_command(subparsers, "label", run)
    lb.add_argument("recording", help="rosbag2 (directory, .mcap, .db3) or ROS 1 .bag")
    lb.add_argument("--layout", required=True, help="dock layout YAML")
    lb.add_argument("--out", required=True, help="dataset Parquet file to write")
    lb.add_argument("--camera", help="camera file, instead of the recording's CameraInfo")
    lb.add_argument("--robot", help="robot YAML, instead of the recording's /tf_static mounts")
    lb.add_argument("--force", action="store_true", help="overwrite an existing dataset")
    add_topics(lb)
    add_jobs(lb)


def label(args: argparse.Namespace, layout: DockLayout, camera: CameraModel | None) -> Dataset:
    """Label ``args.recording`` (label and evaluate share it); prints the reader's warnings and the counts."""
    if camera is None and getattr(args, "camera", None):
        camera = CameraModel.load(args.camera)
    robot = RobotConfig.load(args.robot) if getattr(args, "robot", None) else None
    ds, run_counts, warnings = label_recording(
        args.recording,
        layout,
        camera=camera,
        robot=robot,
        image_topic=args.image_topic,
        camera_info_topic=args.camera_info_topic,
        scan_topic=args.scan_topic,
        tolerance_s=args.tolerance,
        jobs=jobs(getattr(args, "jobs", None)),
    )
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    reasons = ", ".join(f"{n} {k}" for k, n in run_counts.invalid_labels.most_common())
    print(
        f"{run_counts.images} images: {run_counts.paired} paired with a scan within {args.tolerance * 1000:.0f} ms, "
        f"{run_counts.unpaired} unpaired, {run_counts.unreadable} unreadable, {run_counts.no_marker2} without "
        f"marker 2; {run_counts.labelled} labelled" + (f"; not labelled: {reasons}" if reasons else "")
    )
    return ds


def run(args: argparse.Namespace) -> int:
    """LiDAR labels for a recording: detect, pair with scans, write the dataset"""
    positive_seconds("--tolerance", args.tolerance)
    layout = DockLayout.load(args.layout)
    check_writable(args.out, force=args.force, inputs=(args.recording, args.layout, args.camera, args.robot))
    ds = label(args, layout, None)
    if len(ds) == 0:
        raise MonodockError(f"{args.recording}: no images")
    if not ds["label_valid"].any():
        # A dataset without one label trains nothing; the counts line above says why (unreadable images, no
        # marker 2, no scans), and writing it would look like success.
        raise MonodockError(f"{args.recording}: no image could be labelled; nothing written")
    write_dataset(args.out, ds, force=args.force)
    errs = label_errors(ds)
    if errs:
        print("label error against the recording's ground truth:")
        print(label_error_table(errs), end="")
    print(f"dataset: {len(ds)} rows -> {args.out}")
    return 0
