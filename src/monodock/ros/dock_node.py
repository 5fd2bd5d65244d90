"""The docking mission on a real robot through ROS 2 (``monodock-dock-ros``): cmd_vel out, odom and image in.

``Ros2Robot`` implements the controller's robot interface on top of an rclpy node: geometry_msgs/Twist on
``cmd_vel``, nav_msgs/Odometry from ``odom``, sensor_msgs/Image or CompressedImage from the camera, and an
optional std_msgs/Bool contact topic (the charger's "charging" or a bumper). Images are decoded with numpy and
OpenCV (monodock.recording.messages), without cv_bridge.

Like monodock.ros.detector, this module needs rclpy (monodock.ros._rclpy says how to get it).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from monodock.core.pose2d import Pose2D
from monodock.dock.controller import DockingConfig, DockingMission, blind_gap, make_perceive, run_mission
from monodock.dock.interface import CameraFrame, Odometry
from monodock.dock.planner import PlannerConfig
from monodock.dock.pose_filter import MeasurementNoise
from monodock.errors import MonodockError
from monodock.recording import messages as m
from monodock.ros._rclpy import Node, rclpy
from monodock.ros.options import EstimatorOptions

__all__ = ["DockOptions", "Ros2Robot", "run_dock"]


@dataclass(frozen=True)
class DockOptions(EstimatorOptions):
    """What the docking node runs: the estimator (a bundle, or the calibration files), its topics and Point A."""

    odom_topic: str = "/odom"
    cmd_vel_topic: str = "/cmd_vel"
    contact_topic: str | None = None
    standoff: float = 1.0


class Ros2Robot:
    """The robot interface over ROS 2 topics; ``sleep`` spins the node so callbacks run while it waits."""

    def __init__(self, node: Node, args: DockOptions) -> None:
        from geometry_msgs.msg import Twist  # type: ignore[import-not-found, unused-ignore]
        from nav_msgs.msg import Odometry as OdometryMsg  # type: ignore[import-not-found, unused-ignore]
        from sensor_msgs.msg import CompressedImage, Image  # type: ignore[import-not-found, unused-ignore]
        from std_msgs.msg import Bool  # type: ignore[import-not-found, unused-ignore]

        self.node = node
        self._twist = Twist
        self._odom: Odometry | None = None
        self._frame: CameraFrame | None = None
        self._contact: bool | None = None
        compressed = args.image_is_compressed
        self._msgtype = m.COMPRESSED_IMAGE if compressed else m.IMAGE
        self._cmd = node.create_publisher(Twist, args.cmd_vel_topic, 10)
        node.create_subscription(OdometryMsg, args.odom_topic, self._on_odom, 10)
        node.create_subscription(CompressedImage if compressed else Image, args.image_topic, self._on_image, 1)
        if args.contact_topic:
            node.create_subscription(Bool, args.contact_topic, self._on_contact, 10)

    def _on_odom(self, msg: Any) -> None:
        p, q, t = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        self._odom = Odometry(m.header_stamp(msg), Pose2D(p.x, p.y, yaw), t.linear.x, t.angular.z)

    def _on_image(self, msg: Any) -> None:
        try:
            self._frame = CameraFrame(m.header_stamp(msg), m.decode_image(msg, self._msgtype))
        except m.DecodeError as exc:
            self.node.get_logger().warning(f"image skipped: {exc}")

    def _on_contact(self, msg: Any) -> None:
        self._contact = bool(msg.data)

    def now(self) -> float:
        return float(self.node.get_clock().now().nanoseconds) * 1e-9

    def send_velocity(self, linear: float, angular: float) -> None:
        msg = self._twist()
        msg.linear.x, msg.angular.z = float(linear), float(angular)
        self._cmd.publish(msg)

    def odometry(self) -> Odometry:
        while self._odom is None:  # nothing to steer on before the first odometry message
            rclpy.spin_once(self.node, timeout_sec=0.1)
        return self._odom

    def latest_frame(self) -> CameraFrame | None:
        return self._frame

    def contact(self) -> bool | None:
        return self._contact

    def charging(self) -> bool | None:
        return None  # the charging topic comes with the long-running node (issue 17)

    def rear_range(self) -> float | None:
        return None

    def sleep(self, seconds: float) -> None:
        end = self.now() + seconds
        while (left := end - self.now()) > 0:
            rclpy.spin_once(self.node, timeout_sec=left)


def run_dock(args: DockOptions, argv: Sequence[str]) -> int:
    """Dock once and exit: 0 when docked, 1 when the mission failed, 2 on bad options; ``argv``: the ROS arguments."""
    rclpy.init(args=list(argv))
    node = Node("monodock_dock")
    robot: Ros2Robot | None = None
    try:
        estimator = args.estimator()
        method = estimator.method
        robot = Ros2Robot(node, args)
        config = DockingConfig(planner=PlannerConfig(args.standoff), measurement=MeasurementNoise.for_method(method))
        blind = blind_gap(estimator.camera, estimator.layout, estimator.robot)
        result = run_mission(robot, make_perceive(estimator, method), DockingMission(config, estimator.robot, blind))
    except MonodockError as exc:
        print(f"monodock-dock-ros: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        if robot is not None:
            robot.send_velocity(0.0, 0.0)  # whatever happened, the base stops
        node.destroy_node()
        rclpy.try_shutdown()
    for t, entry in result.log:
        print(f"{t:8.2f} {entry}")
    failure = f" [{result.failure.value}, Nav2 error code {result.failure.nav2_error_code}]" if result.failure else ""
    print(f"monodock-dock-ros: {result.state.value} {result.reason}{failure}".rstrip())
    return 0 if result.docked else 1
