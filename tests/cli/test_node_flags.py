"""The ROS nodes' command lines (monodock-ros, monodock-dock-ros, monodock-record-ros) pinned as they were
hand-written before the settings declarations derived them (issue 40, step 0): each flag's names, destination,
default, type, choices and action, the ``--help`` text byte for byte, and the options a command line gives.

cli.ros_nodes imports rclpy; the table is made in a child process with stand-ins for it
(``shared.RCLPY_STAND_INS``), so that no real rclpy is loaded here.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from shared import json_with_stand_ins

GOLDEN = Path(__file__).parents[1] / "data" / "settings" / "node_flags.json"

_SCRIPT = """
import dataclasses, json

from monodock.cli import ros_nodes, ros_record

def flags(parser):
    return [
        {
            "option_strings": a.option_strings,
            "dest": a.dest,
            "default": a.default,
            "type": getattr(a.type, "__name__", repr(a.type)),
            "choices": list(a.choices) if a.choices else None,
            "action": type(a).__name__,
            "help": a.help,
        }
        for a in parser._actions
    ]

argv = [
    "--model", "m", "--method", "board", "--max-stamp-age", "2", "--no-active", "--compressed",
    "--camera-mount-source", "robot", "--mount-tolerance-m", "0.02",
]
dock_argv = [
    "--layout", "l.yaml", "--odom-timeout", "3", "--no-autostart", "--no-stamped-cmd-vel", "--dock-id", "d",
    "--image-is-rectified", "--config", "c.yaml",
]
print(json.dumps({
    "monodock-ros": {
        "help": ros_nodes.detector_parser().format_help(),
        "flags": flags(ros_nodes.detector_parser()),
        "options": dataclasses.asdict(ros_nodes.detector_options(argv)),
    },
    "monodock-dock-ros": {
        "help": ros_nodes.dock_parser().format_help(),
        "flags": flags(ros_nodes.dock_parser()),
        "options": dataclasses.asdict(ros_nodes.dock_options(dock_argv)),
    },
    "monodock-record-ros": {
        "help": ros_record.parser().format_help(),
        "flags": flags(ros_record.parser()),
        "options": repr(ros_record.record_options(
            ["/nonexistent/bag", "--topics", "odom,/cmd_vel:geometry_msgs/msg/Twist", "--all", "--duration", "2"]
        )),
    },
}, default=repr))
"""


def tables() -> dict[str, Any]:
    """Each node's flags, --help and parsed options as JSON values."""
    out: dict[str, Any] = json_with_stand_ins(_SCRIPT)
    return out


def test_the_node_flags_and_their_help_are_as_before() -> None:
    assert tables() == json.loads(GOLDEN.read_text(encoding="utf-8"))
