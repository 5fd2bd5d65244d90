"""The command lines of the ROS 2 nodes (``monodock-ros``, ``monodock-dock-ros``): flags in, typed options out.

The nodes themselves live in ``monodock.ros`` and take typed options; the flags are derived from the options'
settings declarations (``cli.options.add_flags``): a new setting is a new flag. ROS arguments (``--ros-args ...``)
pass through to rclpy. This module needs rclpy, as the node modules do.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rclpy.utilities import remove_ros_args  # type: ignore[import-not-found, unused-ignore]  # noqa: TID253

from monodock.cli.options import add_estimator_options, add_flags
from monodock.cli.parser import Parser as _Parser
from monodock.errors import MonodockError
from monodock.ros.detector import DetectorOptions, non_ros_arguments, run_detector
from monodock.ros.dock_node import run_dock
from monodock.ros.dock_options import DockOptions
from monodock.ros.parameters import check_params_files

__all__ = ["detector_main", "detector_parser", "dock_main", "dock_parser"]


# The flags of add_estimator_options (shared with the other commands that estimate).
_ESTIMATOR_FLAGS = ("model", "method", "camera", "layout", "robot", "refinement")
# The flags' order in --help since before the settings were declared; a new setting's flag follows these.
_DETECTOR_ORDER = (
    "image_topic",
    "compressed",
    "camera_info_topic",
    "pose_topic",
    "pose_covariance_topic",
    "frame_id",
    "max_stamp_age",
    "diagnostics_period",
    "image_is_rectified",
    "camera_mount_source",
    "mount_tolerance_m",
    "mount_tolerance_deg",
    "dock_frame",
    "active",
    "debug_image_topic",
    "lifecycle",
)
_DOCK_ORDER = (
    "image_topic",
    "compressed",
    "camera_info_topic",
    "odom_topic",
    "cmd_vel_topic",
    "battery_topic",
    "contact_topic",
    "rear_range_topic",
    "pose_topic",
    "pose_covariance_topic",
    "frame_id",
    "config",
    "odom_timeout",
    "sensor_timeout",
    "dock_id",
    "autostart_node",
    "enable_stamped_cmd_vel",
)
# The docking node's own words for two flags it shares with the detector.
_DOCK_HELPS = {"image_topic": "", "compressed": "the image topic is sensor_msgs/CompressedImage"}


def detector_parser() -> argparse.ArgumentParser:
    """``monodock-ros``'s flags: each sets the default of the node's ROS parameter of the same name."""
    p = _Parser(
        prog="monodock-ros",
        description="node monodock_detector: camera images in, detected_dock_pose and /diagnostics out",
        epilog="ROS parameters override these flags: --ros-args -p name:=value, --params-file FILE (an example: "
        "config/monodock_detector.yaml)",
    )
    add_estimator_options(
        p,
        camera_help="camera file (default: the model's, else from camera_info)",
        robot_help="robot YAML (camera mount)",
    )
    add_flags(p, DetectorOptions, first=_DETECTOR_ORDER, skip=_ESTIMATOR_FLAGS)
    return p


def dock_parser() -> argparse.ArgumentParser:
    """``monodock-dock-ros``'s flags: each sets the default of the node's parameter of the same name."""
    p = _Parser(
        prog="monodock-dock-ros",
        description="dock and undock on request (Nav2's dock_robot and undock_robot actions; ~/dock, ~/undock, "
        "~/cancel): cmd_vel out, odom and image in; a lifecycle node",
        epilog="ROS parameters (--ros-args -p name:=value, --params-file FILE) override these flags; the docking "
        "config's keys (docs/docking.yaml) are parameters too, e.g. -p planner.standoff:=1.2",
    )
    add_estimator_options(
        p,
        camera_help="camera file (default: the bundle's, else from camera_info)",
        robot_help="robot YAML (mounts, front_offset, limits)",
    )
    add_flags(p, DockOptions, first=_DOCK_ORDER, skip=_ESTIMATOR_FLAGS, helps=_DOCK_HELPS)
    return p


def detector_options(argv: Sequence[str]) -> DetectorOptions:
    """The detector's options from its flags (ROS arguments removed first)."""
    args = detector_parser().parse_args(list(argv))
    return DetectorOptions(**vars(args))


def dock_options(argv: Sequence[str]) -> DockOptions:
    """The docking node's options from its flags (ROS arguments removed first)."""
    args = dock_parser().parse_args(list(argv))
    return DockOptions(**vars(args))


def _argv(prog: str, argv: Sequence[str] | None) -> list[str]:
    return list(sys.argv if argv is None else [prog, *argv])


def detector_main(argv: Sequence[str] | None = None) -> int:
    """``monodock-ros``: run the detector node until shut down."""
    raw = _argv("monodock-ros", argv)
    try:
        flags = non_ros_arguments(raw)[1:]
        check_params_files(raw)
    except MonodockError as exc:
        print(f"monodock-ros: error: {exc}", file=sys.stderr)
        return 2
    return run_detector(detector_options(flags), raw)


def dock_main(argv: Sequence[str] | None = None) -> int:
    """``monodock-dock-ros``: run the docking node until shut down; 2 on bad options."""
    raw = _argv("monodock-dock-ros", argv)
    try:
        check_params_files(raw)
    except MonodockError as exc:
        print(f"monodock-dock-ros: error: {exc}", file=sys.stderr)
        return 2
    return run_dock(dock_options(remove_ros_args(raw)[1:]), raw)
