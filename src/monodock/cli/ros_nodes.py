"""The command lines of the ROS 2 nodes (``monodock-ros``, ``monodock-dock-ros``): flags in, typed options out.

The nodes themselves live in ``monodock.ros`` and take typed options; ROS arguments (``--ros-args ...``) pass
through to rclpy. This module needs rclpy, as the node modules do.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rclpy.utilities import remove_ros_args  # type: ignore[import-not-found, unused-ignore]  # noqa: TID253

from monodock.cli.options import add_estimator_options
from monodock.cli.parser import Parser as _Parser
from monodock.errors import MonodockError
from monodock.ros.detector import DetectorOptions, non_ros_arguments, run_detector
from monodock.ros.dock_node import DockOptions, run_dock
from monodock.ros.parameters import check_params_files

__all__ = ["detector_main", "detector_parser", "dock_main", "dock_parser"]


def detector_parser() -> argparse.ArgumentParser:
    """``monodock-ros``'s flags: each sets the default of the node's ROS parameter of the same name."""
    d = DetectorOptions()
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
    p.add_argument("--image-topic", default=d.image_topic, help="sensor_msgs/Image (default: %(default)s)")
    p.add_argument("--compressed", action="store_true", help="subscribe to IMAGE_TOPIC/compressed (CompressedImage)")
    p.add_argument("--camera-info-topic", default=d.camera_info_topic, help="default: %(default)s")
    p.add_argument("--pose-topic", default=d.pose_topic, help="default: %(default)s")
    p.add_argument(
        "--pose-covariance-topic",
        default=d.pose_covariance_topic,
        help="PoseWithCovarianceStamped of the estimates that have a covariance (default: %(default)s)",
    )
    p.add_argument("--frame-id", default=d.frame_id, help="default: %(default)s")
    p.add_argument(
        "--max-stamp-age",
        type=float,
        default=d.max_stamp_age,
        help="skip images older than this by the node's clock, s; 0: no limit (default: %(default)s)",
    )
    p.add_argument(
        "--diagnostics-period", type=float, default=d.diagnostics_period, help="/diagnostics period, s (%(default)s)"
    )
    _add_camera_source(p, d)
    p.add_argument("--dock-frame", default=d.dock_frame, help="broadcast each pose on /tf as FRAME_ID -> this frame")
    p.add_argument(
        "--active",
        action=argparse.BooleanOptionalAction,
        default=d.active,
        help="estimate from the start; --no-active: only after ~/start or ~/toggle (Nav2's detector_service_name)",
    )
    p.add_argument("--debug-image-topic", default=d.debug_image_topic, help="default: %(default)s")
    p.add_argument(
        "--lifecycle",
        action="store_true",
        help="a managed (lifecycle) node: unconfigured at start, estimating only while active",
    )
    return p


def _add_camera_source(p: argparse.ArgumentParser, d: DetectorOptions | DockOptions) -> None:
    """The flags of where the camera model and its mount come from, the same in both nodes."""
    p.add_argument(
        "--image-is-rectified", action="store_true", help="rectified images: the camera is camera_info's P, undistorted"
    )
    p.add_argument(
        "--camera-mount-source",
        choices=("tf", "robot"),
        default=d.camera_mount_source,
        help="tf: base_link -> the images' frame from /tf_static when there, else the robot file's (default: "
        "%(default)s)",
    )
    p.add_argument("--mount-tolerance-m", type=float, default=d.mount_tolerance_m, help="default: %(default)s")
    p.add_argument("--mount-tolerance-deg", type=float, default=d.mount_tolerance_deg, help="default: %(default)s")


def dock_parser() -> argparse.ArgumentParser:
    """``monodock-dock-ros``'s flags: each sets the default of the node's parameter of the same name."""
    d = DockOptions()
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
    p.add_argument("--image-topic", default=d.image_topic)
    p.add_argument("--compressed", action="store_true", help="the image topic is sensor_msgs/CompressedImage")
    p.add_argument("--camera-info-topic", default=d.camera_info_topic)
    p.add_argument("--odom-topic", default=d.odom_topic)
    p.add_argument("--cmd-vel-topic", default=d.cmd_vel_topic)
    p.add_argument("--battery-topic", default=d.battery_topic, help="BatteryState; empty: no charging signal")
    p.add_argument("--contact-topic", default=d.contact_topic, help="std_msgs/Bool contact switch; empty: none")
    p.add_argument("--rear-range-topic", default=d.rear_range_topic, help="sensor_msgs/Range behind; empty: none")
    p.add_argument("--pose-topic", default=d.pose_topic)
    p.add_argument("--pose-covariance-topic", default=d.pose_covariance_topic)
    p.add_argument("--frame-id", default=d.frame_id)
    p.add_argument("--config", default=d.config, help="docking config YAML (docs/docking.md), read before parameters")
    p.add_argument("--odom-timeout", type=float, default=d.odom_timeout, help="odometry older than this: stop, s")
    p.add_argument("--sensor-timeout", type=float, default=d.sensor_timeout, help="other sensors' age limit, s")
    p.add_argument("--dock-id", default=d.dock_id, help="the one dock's name without a dock database (%(default)s)")
    p.add_argument(
        "--autostart",
        dest="autostart_node",
        action=argparse.BooleanOptionalAction,
        default=d.autostart_node,
        help="configure and activate at start (default); --no-autostart: wait for nav2_lifecycle_manager",
    )
    p.add_argument(
        "--stamped-cmd-vel",
        dest="enable_stamped_cmd_vel",
        action=argparse.BooleanOptionalAction,
        default=d.enable_stamped_cmd_vel,
        help="cmd_vel as TwistStamped (default, as Kilted); --no-stamped-cmd-vel: Twist",
    )
    _add_camera_source(p, d)
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
