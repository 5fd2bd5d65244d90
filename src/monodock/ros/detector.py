"""A ROS 2 node (``monodock-ros``): camera images in, ``detected_dock_pose`` for Nav2's docking server out.

Subscribes to a sensor_msgs/Image or CompressedImage topic (and camera_info when no camera file is given),
runs the estimator of ``monodock run`` (a bundle's regression, or PnP on calibration files) on each image, and
publishes a geometry_msgs/PoseStamped in base_link with the image's stamp for every valid estimate, and, when
the method gives the estimate's covariance, the same pose as geometry_msgs/PoseWithCovarianceStamped on
``detected_dock_pose_with_covariance`` (the 6x6 convention of monodock.io.nav2: x, y, yaw at rows and
columns 0, 1, 5; z, roll and pitch zero). Images are decoded with numpy and OpenCV
(monodock.recording.messages), without cv_bridge.

It needs rclpy (monodock.ros._rclpy says how to get it); nothing outside ros and its command line imports it.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from monodock.core.camera import CameraModel
from monodock.errors import InputError, MonodockError
from monodock.estimation.estimator import Estimator
from monodock.io.nav2 import DOCK_POSE_COVARIANCE_TOPIC, DOCK_POSE_TOPIC, pose_covariance_6x6
from monodock.recording import messages as m
from monodock.ros._rclpy import Node, rclpy
from monodock.ros.options import EstimatorOptions

__all__ = ["DetectorOptions", "DockPoseNode", "run_detector"]


@dataclass(frozen=True)
class DetectorOptions(EstimatorOptions):
    """What the detector node runs: the estimator (a bundle, or the calibration files) and its topics."""

    camera_info_topic: str = "/camera/camera_info"
    pose_topic: str = DOCK_POSE_TOPIC
    pose_covariance_topic: str = DOCK_POSE_COVARIANCE_TOPIC
    frame_id: str = "base_link"


class DockPoseNode(Node):  # type: ignore[misc, unused-ignore]
    """Estimates the dock's pose in each image and publishes the valid ones on ``detected_dock_pose``."""

    def __init__(self, args: DetectorOptions) -> None:
        super().__init__("monodock")
        from geometry_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            Point,
            Pose,
            PoseStamped,
            PoseWithCovariance,
            PoseWithCovarianceStamped,
            Quaternion,
        )
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image  # type: ignore[import-not-found, unused-ignore]

        self._msg = {
            "PoseStamped": PoseStamped,
            "Pose": Pose,
            "Point": Point,
            "Quaternion": Quaternion,
            "PoseWithCovarianceStamped": PoseWithCovarianceStamped,
            "PoseWithCovariance": PoseWithCovariance,
        }
        self.args = args
        self.frame_id: str = args.frame_id
        self.estimator: Estimator | None = None
        self.method = ""
        self._warned: set[str] = set()
        _check_options(args)
        if args.model or args.camera:
            self.estimator, self.method = _estimator(args)
            self.estimator.warm_up()
        else:  # the camera comes from camera_info; the layout and mounts from the files
            # Best-effort (sensor data) subscriptions match reliable and best-effort publishers alike.
            self.create_subscription(CameraInfo, args.camera_info_topic, self._on_camera_info, _sensor_qos())
        compressed = args.image_is_compressed
        self.msgtype = m.COMPRESSED_IMAGE if compressed else m.IMAGE
        self.create_subscription(
            CompressedImage if compressed else Image, args.image_topic, self._on_image, _sensor_qos()
        )
        self.publisher = self.create_publisher(PoseStamped, args.pose_topic, 10)
        self.covariance_publisher = self.create_publisher(PoseWithCovarianceStamped, args.pose_covariance_topic, 10)

    def _warn_once(self, text: str) -> None:
        if text not in self._warned:
            self._warned.add(text)
            self.get_logger().warning(text)

    def _on_camera_info(self, msg: Any) -> None:
        if self.estimator is not None:
            return
        camera = m.camera_from_msg(msg)
        if camera is None:
            self._warn_once("camera_info without a calibration (K is zero); waiting for a calibrated one")
            return
        self.estimator, self.method = _estimator(self.args, camera)
        self.estimator.warm_up()
        self.get_logger().info(f"camera {camera.width}x{camera.height} from camera_info; estimating with {self.method}")

    def _on_image(self, msg: Any) -> None:
        if self.estimator is None:
            self._warn_once("no camera calibration yet (waiting for camera_info)")
            return
        stamp = m.header_stamp(msg)
        try:
            image = m.decode_image(msg, self.msgtype)
            result = self.estimator.estimate(str(stamp), stamp, image)
        except (m.DecodeError, MonodockError) as exc:
            self._warn_once(f"image skipped: {exc}")
            return
        est = result.estimates[self.method]
        if est.pose is None:
            return
        half = 0.5 * est.pose.yaw
        pose = self._msg["Pose"](
            position=self._msg["Point"](x=float(est.pose.x), y=float(est.pose.y), z=0.0),
            orientation=self._msg["Quaternion"](x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
        )
        out = self._msg["PoseStamped"]()
        out.header.stamp = msg.header.stamp  # the image's stamp, as opennav_docking expects
        out.header.frame_id = self.frame_id
        out.pose = pose
        self.publisher.publish(out)
        if est.covariance is None:
            return
        try:
            covariance = pose_covariance_6x6(est.covariance)
        except ValueError as exc:
            self._warn_once(f"covariance not published: {exc}")
            return
        with_cov = self._msg["PoseWithCovarianceStamped"]()
        with_cov.header.stamp = msg.header.stamp
        with_cov.header.frame_id = self.frame_id
        with_cov.pose = self._msg["PoseWithCovariance"](pose=pose, covariance=covariance)
        self.covariance_publisher.publish(with_cov)


def _sensor_qos() -> Any:
    """Sensor-data QoS (best effort, keep the last few): a slow node drops frames instead of queueing them."""
    from rclpy.qos import qos_profile_sensor_data  # type: ignore[import-not-found, unused-ignore]

    return qos_profile_sensor_data


def _estimator(args: DetectorOptions, camera: CameraModel | None = None) -> tuple[Estimator, str]:
    """The Estimator of the options, or of camera_info's camera with the layout and robot files."""
    estimator = args.estimator(camera)
    return estimator, estimator.method


def _check_options(args: DetectorOptions) -> None:
    """InputError for options that cannot work, before anything is subscribed."""
    if args.model or args.camera:
        return
    if args.method == "regression":
        raise InputError("the regression needs --model BUNDLE")
    missing = [f"--{k}" for k in ("layout", "robot") if not getattr(args, k)]
    if missing:
        raise InputError(f"without --model, give {' '.join(missing)} (and --camera, or a camera_info topic)")


def run_detector(args: DetectorOptions, argv: Sequence[str]) -> int:
    """Run the node until shut down (Ctrl-C); ``argv`` carries the ROS arguments. User errors: one line, 2."""
    rclpy.init(args=list(argv))
    try:
        node = DockPoseNode(args)
    except MonodockError as exc:
        print(f"monodock-ros: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    from rclpy.executors import ExternalShutdownException  # type: ignore[import-not-found, unused-ignore]

    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C, or SIGTERM: a clean exit, no traceback
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
