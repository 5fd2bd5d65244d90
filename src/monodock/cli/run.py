"""``monodock run``: live estimation from a camera, stream, video or recording, one row per frame as it comes."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from monodock.cli.options import SubParsers, add_command, add_estimator_options, build_estimator, int_in
from monodock.core.atomic import check_writable
from monodock.errors import InputError, MonodockError
from monodock.estimation.estimator import Estimator, FrameEstimates
from monodock.estimation.methods import METHOD_NAMES
from monodock.estimation.overlay import draw_overlay
from monodock.io.frames import FrameSource, open_frames
from monodock.io.live import Draw, LiveStats, run_live
from monodock.io.nav2 import UNSTAMPED_BAG, PoseStampedBagWriter

__all__ = ["add_parser", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``run``."""
    r = add_command(subparsers, "run", run)
    r.add_argument(
        "--source",
        required=True,
        help="camera index (0, 1 ...), video file, rtsp:// or http:// URL, "
        "or recording (rosbag2 folder, .mcap, .db3, .bag)",
    )
    add_estimator_options(
        r,
        methods=METHOD_NAMES,
        camera_help="camera file: ROS camera_info YAML or OpenCV FileStorage",
        robot_help="robot YAML (camera and LiDAR mounts, front_offset)",
    )
    r.add_argument("--out", default="-", help="rows to write: FILE.csv, FILE.jsonl, or - for stdout (default)")
    r.add_argument("--format", choices=("csv", "jsonl"), help="row format (default: from --out's suffix, else csv)")
    r.add_argument("--bag", metavar="OUT_BAG", help="also write the valid poses as a Nav2 detected_dock_pose rosbag2")
    r.add_argument("--overlay-video", metavar="OUT.mp4", help="also write the overlay of every frame to a video")
    r.add_argument("--show", action="store_true", help="show the overlay in a window ('q' stops)")
    r.add_argument(
        "--realtime",
        action="store_true",
        help="play a video or recording at its own rate (drops frames "
        "it cannot keep up with); default: as fast as possible",
    )
    r.add_argument("--max-frames", type=int_in(1, 10**12), metavar="N", help="stop after N frames, 1-10^12")
    r.add_argument("--image-topic", help="a recording's image topic, when it has several")
    r.add_argument(
        "--skip-bad",
        action="store_true",
        help="an unreadable image file gives an invalid row, not an error (a camera's, video's or recording's "
        "bad frame always does)",
    )
    r.add_argument("--force", action="store_true", help="overwrite existing outputs")


def _output_format(args: argparse.Namespace) -> str:
    if args.format:
        return str(args.format)
    return "jsonl" if str(args.out).lower().endswith((".jsonl", ".ndjson", ".json")) else "csv"


def _draw(estimator: Estimator) -> Draw:
    """The overlay of a frame: its detection and the method's estimate, at the frame's own size."""

    def draw(image: NDArray[np.uint8], result: FrameEstimates) -> NDArray[np.uint8]:
        assert result.detection is not None
        return draw_overlay(
            image,
            result.detection,
            estimator.layout,
            estimator.camera,
            estimator.robot,
            result.estimates[estimator.method],
            scale=1.0,
        )

    return draw


def _say(text: str) -> None:
    print(f"monodock run: {text}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """live estimation from a camera, stream, video or recording: one row per frame as it comes"""
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be at least 1, got {args.max_frames}")
    # Rows go to stdout or --out as they are made (io.live.run_live).
    to_stdout = args.out == "-"
    inputs = (args.source, args.model, args.camera, args.layout, args.robot)
    if not to_stdout:
        # Rows are streamed into --out, not swapped in: a FIFO or /dev/null is fine there.
        check_writable(args.out, force=args.force, inputs=inputs, stream=True)
    for path in (args.bag, args.overlay_video):
        if path:
            check_writable(path, force=args.force, inputs=inputs)
    estimator = build_estimator(args)
    created = not to_stdout and not os.path.lexists(args.out)
    try:
        stats, source, bag = _run(args, estimator, to_stdout=to_stdout)
    except MonodockError:
        # A refusal (an unreadable image file) leaves no half-written --out behind; rows streamed into a file the
        # user already had (a FIFO, a file replaced with --force) stay.
        if created:
            Path(args.out).unlink(missing_ok=True)
        raise
    where = "" if to_stdout else f" -> {args.out}"
    if bag is not None:
        where += f"; {bag.written} poses -> {args.bag}"
        if bag.written_with_covariance:
            where += f" ({bag.written_with_covariance} with covariance)"
    summary = f"{estimator.method} on {source.name}: {stats.summary()}{where}"
    print(summary, file=sys.stderr if to_stdout else sys.stdout)
    return 0


def _run(
    args: argparse.Namespace, estimator: Estimator, *, to_stdout: bool
) -> tuple[LiveStats, FrameSource, PoseStampedBagWriter | None]:
    with contextlib.ExitStack() as stack:
        source = stack.enter_context(
            open_frames(
                args.source, skip_bad=True, image_topic=args.image_topic, size=estimator.camera.size, on_warning=_say
            )
        )
        # Image files are read like estimate reads them: an unreadable one is refused unless --skip-bad; a live
        # source's (camera, stream, video, recording) bad frame is a row with the reason.
        source.skip_bad = args.skip_bad or source.kind != "files"
        bag = stack.enter_context(PoseStampedBagWriter(args.bag, force=args.force)) if args.bag else None
        if to_stdout:
            sink: IO[str] = sys.stdout
        else:
            # Streamed into the named file itself, so that it can be followed (tail -f) during the run;
            # it was checked above not to replace anything without --force.
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            sink = stack.enter_context(open(args.out, "w", encoding="utf-8", newline=""))
        stats = run_live(
            source,
            estimator,
            estimator.method,
            sink=sink,
            output_format=_output_format(args),
            bag=bag,
            draw=_draw(estimator),
            overlay_video=args.overlay_video,
            force=args.force,
            show=args.show,
            realtime=args.realtime,
            max_frames=args.max_frames,
            on_message=_say,
        )
        if bag is not None and bag.written == 0 and stats.valid > 0:
            raise InputError(UNSTAMPED_BAG)  # inside the block: the empty bag is not kept
    return stats, source, bag
