"""The command line of ``monodock-record-ros`` (node ``monodock_recorder``): record a ROS 2 graph to MCAP.

Checks everything it can (the output path, the topic names) before loading rclpy, so that bad input costs one
line and exit code 2, not a DDS participant. ROS arguments (``--ros-args ...``) pass through to rclpy.
Also runs as ``python -m monodock.cli.ros_record`` (what ``monodock.ros.recorder.RecorderProcess`` starts).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from monodock.cli.options import add_flags
from monodock.cli.parser import Parser
from monodock.core.atomic import check_writable
from monodock.errors import InputError
from monodock.ros.recorder import RecorderOptions, run_recorder

__all__ = ["main", "parser", "record_options"]

PROG = "monodock-record-ros"


def parser() -> argparse.ArgumentParser:
    """``monodock-record-ros``'s flags, one per setting of RecorderOptions (``settings.to_argv`` the inverse)."""
    p = Parser(
        prog=PROG,
        description="Record ROS 2 topics to a rosbag2 (MCAP) until Ctrl-C, SIGTERM or --duration.",
        epilog="Relative topic names resolve in the recorder's namespace. ROS arguments follow --ros-args.",
    )
    add_flags(p, RecorderOptions)
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
