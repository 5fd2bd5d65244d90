"""The command line of ``monodock-record-ros`` (node ``monodock_recorder``): record a ROS 2 graph to MCAP.

Checks everything it can (the output path, the topic names) before loading rclpy, so that bad input costs one
line and exit code 2, not a DDS participant. ROS arguments (``--ros-args ...``) pass through to rclpy.
Also runs as ``python -m monodock.cli.ros_record`` (what ``monodock.ros.recorder.RecorderProcess`` starts).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence

from monodock.cli.parser import Parser
from monodock.core.atomic import check_writable
from monodock.errors import InputError
from monodock.recording.write import STORAGES
from monodock.ros.recorder import (
    DEFAULT_TOPICS,
    DISTROS,
    TIMESTAMPS,
    RecorderOptions,
    TopicSpec,
    parse_topic,
    run_recorder,
)

__all__ = ["main", "parser", "record_options"]

PROG = "monodock-record-ros"


def _topics(value: str) -> tuple[TopicSpec, ...]:
    try:
        return tuple(parse_topic(t) for t in value.split(",") if t.strip())
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _seconds(value: str) -> float:
    try:
        seconds = float(value)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise argparse.ArgumentTypeError(f"'{value}' is not a positive number of seconds")
    return seconds


def parser() -> argparse.ArgumentParser:
    """``monodock-record-ros``'s flags."""
    p = Parser(
        prog=PROG,
        description="Record ROS 2 topics to a rosbag2 (MCAP) until Ctrl-C, SIGTERM or --duration.",
        epilog="Relative topic names resolve in the recorder's namespace. ROS arguments follow --ros-args.",
    )
    p.add_argument("output", help="the bag folder to write (refused if it exists, unless --force)")
    p.add_argument(
        "--topics",
        type=_topics,
        default=tuple(TopicSpec(t) for t in DEFAULT_TOPICS),
        help="comma-separated topics, each NAME or NAME:pkg/msg/Type (default: a docking run's: "
        + ",".join(DEFAULT_TOPICS)
        + ")",
    )
    p.add_argument("--all", dest="all_topics", action="store_true", help="also record every other topic that appears")
    p.add_argument("--force", action="store_true", help="replace an existing output")
    p.add_argument("--storage", choices=tuple(STORAGES), default="mcap")
    p.add_argument("--distro", choices=tuple(DISTROS), default="kilted", help="whose message definitions to store")
    p.add_argument(
        "--timestamps",
        choices=TIMESTAMPS,
        default="receive",
        help="log time of a message: its receive time, or its header stamp (when it has a header)",
    )
    p.add_argument("--duration", type=_seconds, default=math.inf, help="stop after this many seconds")
    p.add_argument("--poll-period", type=_seconds, default=0.2, help="seconds between looks for new topics")
    return p


def _split_ros_args(argv: Sequence[str]) -> list[str]:
    """The words of a command line that are not ROS arguments (``--ros-args ... [--]`` taken out)."""
    ours: list[str] = []
    inside = False
    for word in argv:
        if word == "--ros-args":
            inside = True
        elif inside and word == "--":
            inside = False
        elif not inside:
            ours.append(word)
    return ours


def record_options(argv: Sequence[str]) -> RecorderOptions:
    """The recorder's options from its flags (ROS arguments taken out first), the output path checked.

    Raises:
        InputError: the output exists (without --force) or cannot be written.
    """
    args = parser().parse_args(_split_ros_args(argv))
    check_writable(args.output, force=args.force)
    return RecorderOptions(**vars(args))


def main(argv: Sequence[str] | None = None) -> int:
    """``monodock-record-ros``: record until stopped; 0 when the bag is written, 2 on bad input."""
    raw = list(sys.argv if argv is None else [PROG, *argv])
    try:
        options = record_options(raw[1:])
        return run_recorder(options, raw)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
