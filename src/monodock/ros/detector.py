"""A ROS 2 node (``monodock-ros``, node ``monodock_detector``): camera images in, ``detected_dock_pose`` out.

Subscribes to ``image`` (sensor_msgs/Image; image_transport's ``image/compressed``, CompressedImage, with
``compressed``) and ``camera_info``, runs the estimator of ``monodock run`` (a bundle's regression or fused method,
or PnP on calibration files) on each image, and publishes a geometry_msgs/PoseStamped in base_link with the
image's stamp for every valid estimate on ``detected_dock_pose``, and, when the method gives the estimate's
covariance, the same pose as geometry_msgs/PoseWithCovarianceStamped on ``detected_dock_pose_with_covariance``
(the 6x6 convention of monodock.io.nav2). Every ``diagnostics_period`` it publishes a diagnostic_msgs/
DiagnosticArray on ``/diagnostics``: images in and poses out per second, the latency from image stamp to
publication, the markers in the last frame, frames dropped and images refused, and why there is no estimate.

Settings are ROS parameters (``PARAMETERS``): the command line's flags set their defaults, ``--ros-args -p k:=v``
and ``--params-file`` (config/monodock_detector.yaml) override them; a bad value is one line and exit code 2.
The camera comes from the camera file or the bundle, else from the first calibrated camera_info; a camera_info that
disagrees with the camera in use is reported once.

Bad input never stops the node: an image with an unknown encoding or a size that does not fit, a camera_info
without a valid calibration, a stamp older than ``max_stamp_age`` or not after the last image's is skipped, with
one warning per kind of fault (repeated at most every ``WARNING_PERIOD`` seconds). The executor's thread only
checks each image and leaves it in a one-frame mailbox; a worker thread estimates whatever is there. An image that
arrives while the mailbox is full replaces the one waiting (counted as dropped), so a node that falls behind skips
to the newest frame, with bounded memory and latency, instead of working through a queue of old ones.

Images are decoded with numpy and OpenCV (monodock.recording.messages), without cv_bridge. It needs rclpy
(monodock.ros._rclpy says how to get it); nothing outside ros and its command line imports it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.settings import setting
from monodock.errors import InputError, MonodockError
from monodock.estimation.estimator import Estimator
from monodock.estimation.overlay import draw_overlay
from monodock.io.nav2 import DOCK_POSE_COVARIANCE_TOPIC, DOCK_POSE_TOPIC, pose_covariance_6x6
from monodock.recording import messages as m
from monodock.ros._rclpy import Node, rclpy
from monodock.ros.lifecycle import ManagerBond, autostart, autostart_setting, bond_heartbeat_setting
from monodock.ros.options import EstimatorOptions
from monodock.ros.parameters import Parameter, declare_settings, parameters_of
from monodock.ros.shutdown import ShutdownFlag, spin
from monodock.ros.tf import CameraMountFromTF, set_transform

__all__ = [
    "CALIBRATION_GRACE",
    "MISMATCH_TOLERANCE",
    "NODE_NAME",
    "PARAMETERS",
    "WARNING_PERIOD",
    "DetectorOptions",
    "DockPoseNode",
    "camera_mismatch",
    "non_ros_arguments",
    "run_detector",
]

NODE_NAME = "monodock_detector"
# Why an image is not estimated, when nothing is wrong (/diagnostics' no_estimate_reason, level OK).
IDLE_STOPPED = "stopped (~/start or ~/toggle starts detection)"
IDLE_UNWATCHED = "idle: nothing subscribes to the poses, the dock frame or the debug image"
WARNING_PERIOD = 10.0  # s between two warnings of one kind of fault
MISMATCH_TOLERANCE = 0.01  # camera_info and the camera in use disagree beyond 1 %
# A camera publishes each image just before its camera_info: images without a calibration are a fault only once
# they have come for this long.
CALIBRATION_GRACE = 1.0  # s


@dataclass(frozen=True)
class DetectorOptions(EstimatorOptions):
    """What the detector node runs: the estimator (a bundle, or the calibration files), its topics and limits.

    Attributes:
        camera_info_topic: sensor_msgs/CameraInfo; the camera when no file gives one, else checked against it.
        pose_topic, pose_covariance_topic: where the estimates go.
        frame_id: the frame of the published poses.
        max_stamp_age: images older than this by the node's clock are skipped, s; 0: no limit.
        diagnostics_period: s between two /diagnostics messages.
        dock_frame: broadcast each pose on /tf as ``frame_id`` -> this frame; "": no broadcast.
        active: estimate from the start; False: only after ``~/start`` (or ``~/toggle``, Nav2's
            ``detector_service_name``).
        debug_image_topic: sensor_msgs/Image of each estimated frame with the markers, corners, dock axes, pose
            and sigma drawn; drawn only while something subscribes.
        lifecycle: a managed node (``managed_detector``): it estimates only while active.
        autostart_node, bond_heartbeat_period: a managed node's (``monodock.ros.lifecycle``): configure and activate
            at start; the bond to nav2_lifecycle_manager while active.
    """

    camera_info_topic: str = setting(
        "camera_info",
        help="sensor_msgs/CameraInfo: the camera when no file gives it, else checked",
        cli_help="default: %(default)s",
    )
    pose_topic: str = setting(
        DOCK_POSE_TOPIC,
        help="geometry_msgs/PoseStamped of each valid estimate, stamped with its image's stamp",
        cli_help="default: %(default)s",
    )
    pose_covariance_topic: str = setting(
        DOCK_POSE_COVARIANCE_TOPIC,
        help="PoseWithCovarianceStamped of each estimate that has a covariance (fused)",
        cli_help="PoseWithCovarianceStamped of the estimates that have a covariance (default: %(default)s)",
    )
    frame_id: str = setting(
        "base_link", live=True, help="frame of the published poses: the robot's base", cli_help="default: %(default)s"
    )
    max_stamp_age: float = setting(
        1.0,
        live=True,
        range=(0.0, 3600.0),
        help="images older than this by the node's clock are skipped, s (0: no limit)",
        cli_help="skip images older than this by the node's clock, s; 0: no limit (default: %(default)s)",
    )
    diagnostics_period: float = setting(
        1.0,
        range=(0.1, 60.0),
        help="seconds between two /diagnostics messages",
        cli_help="/diagnostics period, s (%(default)s)",
    )
    dock_frame: str = setting(
        "",
        help="broadcast each pose on /tf as frame_id -> this frame (for RViz); empty: none",
        cli_help="broadcast each pose on /tf as FRAME_ID -> this frame",
    )
    active: bool = setting(
        True,
        help="estimate from the start; false: only after ~/start or ~/toggle (Nav2's detector_service_name)",
        cli_help="estimate from the start; --no-active: only after ~/start or ~/toggle (Nav2's detector_service_name)",
    )
    debug_image_topic: str = setting(
        "~/debug_image",
        help="the image with markers, corners, dock axes and the pose drawn (while subscribed)",
        cli_help="default: %(default)s",
    )
    # The command line's alone (the node's class depends on it): not a ROS parameter.
    lifecycle: bool = setting(
        False, ros=False, help="a managed (lifecycle) node: unconfigured at start, estimating only while active"
    )
    # A managed node's (--lifecycle); the plain node has no lifecycle and ignores them.
    autostart_node: bool = autostart_setting(False, flag="")
    bond_heartbeat_period: float = bond_heartbeat_setting(flag="")


# One per DetectorOptions setting (``lifecycle`` aside), of the same name; read-only ones are read once, at start-up.
PARAMETERS: dict[str, Parameter] = parameters_of(DetectorOptions)


def camera_mismatch(used: CameraModel, info: CameraModel, tolerance: float = MISMATCH_TOLERANCE) -> str | None:
    """How a camera_info's camera disagrees with the one in use, or None when it agrees.

    They disagree when the image size differs, when fx, fy, cx or cy differs by more than ``tolerance`` of its
    value, or when their distortion moves the image's corners and edge midpoints apart by more than ``tolerance``
    of the point's distance from the principal point (both through the same K, so only the lens model counts).
    """
    if used.size != info.size:
        return f"image size {info.width}x{info.height}, not {used.width}x{used.height}"
    for name, a, b in zip(("fx", "fy", "cx", "cy"), _intrinsics(used), _intrinsics(info), strict=True):
        if abs(b - a) > tolerance * abs(a):
            return f"{name} {b:.2f}, not {a:.2f}"
    w, h = used.width, used.height
    pixels = np.array(
        [[x, y] for x in (0.0, w / 2, w - 1.0) for y in (0.0, h / 2, h - 1.0) if (x, y) != (w / 2, h / 2)]
    )
    rays = np.column_stack([used.normalize(pixels), np.ones(len(pixels))])
    lens = CameraModel(info.width, info.height, used.K, info.D, info.distortion_model)
    moved = np.linalg.norm(lens.project(rays) - used.project(rays), axis=1)
    reach = np.linalg.norm(pixels - (used.cx, used.cy), axis=1)
    if np.any(moved > tolerance * reach):
        return f"its distortion moves the image's edge by up to {float(moved.max()):.1f} px"
    return None


def _intrinsics(camera: CameraModel) -> tuple[float, float, float, float]:
    return camera.fx, camera.fy, camera.cx, camera.cy


class _Warnings:
    """One warning per kind of fault, repeated at most every ``period`` seconds with the count in between."""

    def __init__(self, logger: Any, period: float = WARNING_PERIOD) -> None:
        self._logger, self._period = logger, period
        self._last: dict[str, float] = {}
        self._since: dict[str, int] = {}
        self._lock = threading.Lock()

    def warn(self, kind: str, text: str) -> None:
        now = time.monotonic()
        with self._lock:
            last = self._last.get(kind)
            if last is not None and now - last < self._period:
                self._since[kind] = self._since.get(kind, 0) + 1
                return
            self._last[kind] = now
            more = self._since.pop(kind, 0)
        self._logger.warning(text + (f" ({more} more since the last such warning)" if more else ""))


@dataclass
class _Period:
    """What happened since the last /diagnostics message."""

    start: float
    images: int = 0
    poses: int = 0
    dropped: int = 0
    refused: int = 0
    idle: int = 0  # images not estimated: stopped, or nothing subscribes
    latencies: list[float] = field(default_factory=list)
    processing: list[float] = field(default_factory=list)  # wall seconds to decode and estimate each image


class DockPoseNode(Node):  # type: ignore[misc, unused-ignore]
    """Estimates the dock's pose in each image and publishes the valid ones on ``detected_dock_pose``."""

    def __init__(self, options: DetectorOptions) -> None:
        super().__init__(NODE_NAME)
        from diagnostic_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            DiagnosticArray,
            DiagnosticStatus,
            KeyValue,
        )
        from geometry_msgs.msg import (  # type: ignore[import-not-found, unused-ignore]
            Point,
            Pose,
            PoseStamped,
            PoseWithCovariance,
            PoseWithCovarianceStamped,
            Quaternion,
        )
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image  # type: ignore[import-not-found, unused-ignore]
        from std_srvs.srv import Trigger  # type: ignore[import-not-found, unused-ignore]

        self._msg = {
            "PoseStamped": PoseStamped,
            "Pose": Pose,
            "Point": Point,
            "Quaternion": Quaternion,
            "PoseWithCovarianceStamped": PoseWithCovarianceStamped,
            "PoseWithCovariance": PoseWithCovariance,
            "DiagnosticArray": DiagnosticArray,
            "DiagnosticStatus": DiagnosticStatus,
            "KeyValue": KeyValue,
            "Image": Image,
        }
        self.options = declare_settings(self, options)
        o = self.options
        self.frame_id, self.max_stamp_age = o.frame_id, o.max_stamp_age
        self.add_post_set_parameters_callback(self._on_parameters)
        self._warnings = _Warnings(self.get_logger())
        self.estimator: Estimator | None = None
        self.method = ""
        self.camera: CameraModel | None = None  # the camera in use; the estimator is built for it
        self.camera_source = "first camera_info"
        _check_options(o)
        if o.model or o.camera:
            self.estimator = o.estimator()
            self.method, self.camera = self.estimator.method, self.estimator.camera
            self.camera_source = "camera file" if o.camera else "model bundle"
            self.estimator.warm_up()
            self._file_robot = self.estimator.robot
        else:  # a bad layout or robot file fails now, at start-up, rather than at the first camera_info
            self._file_robot = o.estimator(CameraModel.default()).robot
        tolerance = (o.mount_tolerance_m, o.mount_tolerance_deg)
        self.mount = CameraMountFromTF(self, o.frame_id, source=o.camera_mount_source, tolerance=tolerance)
        self._mismatch_reported = False
        self.msgtype = m.COMPRESSED_IMAGE if o.image_is_compressed else m.IMAGE
        self._lock = threading.Lock()  # the counters below, shared by both threads
        self._period = _Period(time.monotonic())
        self.dropped_total = self.refused_total = 0
        self.markers: int | None = None  # in the last frame estimated
        self.reason = "no image yet"  # why the last image gave no pose ("" when it gave one)
        self._last_stamp: float | None = None
        self._uncalibrated_since: float | None = None
        self._ready = threading.Condition()  # guards the mailbox
        self._pending: Any = None
        self._stopping = False
        self.failure: BaseException | None = None
        self.publisher = self.create_publisher(PoseStamped, o.pose_topic, 10)
        self.covariance_publisher = self.create_publisher(PoseWithCovarianceStamped, o.pose_covariance_topic, 10)
        self.debug_publisher = self.create_publisher(Image, o.debug_image_topic, rclpy.qos.qos_profile_sensor_data)
        self.tf_publisher = self._tf_publisher() if o.dock_frame else None
        self.active = o.active
        self.create_service(Trigger, "~/start", lambda _request, response: self._switch(response, True))
        self.create_service(Trigger, "~/stop", lambda _request, response: self._switch(response, False))
        self.create_service(Trigger, "~/toggle", lambda _request, response: self._switch(response, not self.active))
        self.diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # Sensor-data QoS (best effort, the last few) matches reliable and best-effort publishers alike.
        sensor = rclpy.qos.qos_profile_sensor_data
        self.create_subscription(CameraInfo, o.camera_info_topic, self._on_camera_info, sensor)
        image_type = CompressedImage if o.image_is_compressed else Image
        self.create_subscription(image_type, o.subscribed_image_topic, self._on_image, sensor)
        self.create_timer(o.diagnostics_period, self._publish_diagnostics)
        self._worker = threading.Thread(target=self._work, name="monodock_detector estimation", daemon=True)
        self._worker.start()

    def _tf_publisher(self) -> Any:
        """/tf for the dock frame, or None without tf2_msgs (built when monodock is installed)."""
        try:
            from tf2_msgs.msg import TFMessage  # type: ignore[import-not-found, unused-ignore]
        except ImportError as exc:
            self.get_logger().warning(f"no dock frame on /tf: {exc} (tf2_msgs is built when monodock is installed)")
            return None
        from geometry_msgs.msg import TransformStamped  # type: ignore[import-not-found, unused-ignore]

        self._msg.update(TFMessage=TFMessage, TransformStamped=TransformStamped)
        return self.create_publisher(TFMessage, "/tf", 100)

    # --- parameters that change live, and on-demand detection ---------------------------------------

    def _on_parameters(self, parameters: list[Any]) -> None:
        for p in parameters:
            if p.name == "frame_id":
                self.frame_id = self.mount.base_frame = str(p.value)
            elif p.name == "max_stamp_age":
                self.max_stamp_age = float(p.value)

    def _switch(self, response: Any, on: bool) -> Any:
        """~/start, ~/stop and ~/toggle (Nav2's ``detector_service_name`` calls one Trigger to start detection and
        again to stop it): estimate from the next image on, or estimate nothing."""
        was, self.active = self.active, on
        if on and not was:
            self._last_stamp = None  # images went by unchecked while stopped
        response.success = True
        response.message = (
            ("detection started" if on else "detection stopped")
            if was != on
            else ("detection already " + ("running" if on else "stopped"))
        )
        self.get_logger().info(response.message)
        return response

    def _idle(self) -> str:
        """Why this image need not be estimated ("" when it must): stopped, or nothing subscribes to the output."""
        if not self.active:
            return IDLE_STOPPED
        wanted = (self.publisher, self.covariance_publisher, self.debug_publisher, self.tf_publisher)
        if any(p is not None and p.get_subscription_count() > 0 for p in wanted):
            return ""
        return IDLE_UNWATCHED

    # --- the executor's thread: check, then leave the newest image in the mailbox --------------------

    def _on_camera_info(self, msg: Any) -> None:
        try:
            camera = m.camera_from_msg(msg, rectified=self.options.image_is_rectified)
        except m.DecodeError as exc:
            self._warnings.warn("camera_info", f"camera_info skipped: {exc}")
            return
        if camera is None:
            self._warnings.warn("uncalibrated", "camera_info skipped: it has no calibration (K is all zero)")
            return
        if self.camera is None:
            self.camera = camera  # the worker builds the estimator for it
            self.get_logger().info(f"camera {camera.width}x{camera.height} from camera_info")
            return
        if self._mismatch_reported:
            return
        why = camera_mismatch(self.camera, camera)
        if why is not None:
            self._mismatch_reported = True
            self.get_logger().warning(
                f"camera_info on {self.options.camera_info_topic} disagrees with the camera in use, from the "
                f"{self.camera_source} ({why}); estimating with the camera in use (reported once)"
            )

    def _on_image(self, msg: Any) -> None:
        stamp = m.header_stamp(msg)
        idle = self._idle()
        with self._lock:
            self._period.images += 1
            if idle:
                self._period.idle += 1
                self.reason = idle
        if idle:
            return
        fault = self._check_image(msg, stamp)
        if fault is not None:
            self._refuse(*fault)
            return
        self._last_stamp = stamp
        with self._ready:
            replaced = self._pending is not None
            # Whether to draw it is asked here: the worker calls no rclpy but publish (rclpy may be shutting down).
            self._pending = (msg, self.debug_publisher.get_subscription_count() > 0)
            self._ready.notify()
        if replaced:
            with self._lock:
                self._period.dropped += 1
                self.dropped_total += 1
                total = self.dropped_total
            self._warnings.warn(
                "falling behind",
                f"falling behind: images arrive faster than they are estimated; the newest replaces the one waiting "
                f"({total} dropped so far)",
            )

    def _check_image(self, msg: Any, stamp: float) -> tuple[str, str, str] | None:
        """(kind, warning, reason for /diagnostics) of an image that must be skipped, or None."""
        age = self._now() - stamp
        if self.max_stamp_age > 0 and age > self.max_stamp_age:
            text = f"its stamp is {age:.2f} s old (max_stamp_age {self.max_stamp_age:g} s)"
            return "stale", f"image skipped: {text}", "stale stamps"
        last = self._last_stamp
        if last is not None and stamp <= last:
            text = f"its stamp {stamp:.3f} is not after the last image's {last:.3f}"
            return "out of order", f"image skipped: {text}", "out-of-order stamps"
        if self.msgtype == m.IMAGE:
            try:
                m.check_raw_image(msg)
            except m.DecodeError as exc:
                return exc.kind, f"image skipped: {exc}", f"bad image: {exc}"
        if self.camera is None:
            topic = self.options.camera_info_topic
            return "calibration", f"image skipped: no camera calibration yet (waiting for {topic})", "no calibration"
        return None

    def _refuse(self, kind: str, warning: str, reason: str) -> None:
        with self._lock:
            self._period.refused += 1
            self.refused_total += 1
            self.reason = reason
        if kind == "calibration":
            now = time.monotonic()
            self._uncalibrated_since = self._uncalibrated_since or now
            if now - self._uncalibrated_since < CALIBRATION_GRACE:
                return
        self._warnings.warn(kind, warning)

    def _now(self) -> float:
        return float(self.get_clock().now().nanoseconds) * 1e-9

    # --- the worker thread: estimate the newest image --------------------------------------------------

    def _work(self) -> None:
        try:
            while True:
                with self._ready:
                    while self._pending is None and not self._stopping:
                        self._ready.wait()
                    if self._stopping:
                        return
                    (msg, draw), self._pending = self._pending, None
                self._estimate(msg, draw)
        except Exception as exc:  # a bug, not a bad message: stop the node loudly rather than go quiet
            if not rclpy.ok():
                return  # shutting down under an estimate: its publisher went away, nothing is wrong
            self.failure = exc
            rclpy.try_shutdown()

    def stop(self) -> None:
        """Stop the worker thread (the image it is estimating is finished first)."""
        with self._ready:
            self._stopping = True
            self._ready.notify()
        self._worker.join(timeout=10.0)

    def _estimator(self, frame_id: str) -> Estimator:
        """The estimator for an image in ``frame_id``: built at the first image after camera_info (here, off the
        executor's thread), and again when /tf_static gives that frame another camera mount."""
        robot = self.mount.robot(self._file_robot, frame_id)
        if self.estimator is None or self.estimator.robot != robot:
            self.estimator = self.options.estimator(self.camera, robot)
            self.method = self.estimator.method
            self.estimator.warm_up()
            self.get_logger().info(f"estimating with {self.method}")
        return self.estimator

    def _estimate(self, msg: Any, draw: bool = False) -> None:
        stamp = m.header_stamp(msg)
        started = time.perf_counter()
        try:
            image = m.decode_image(msg, self.msgtype)
            estimator = self._estimator(msg.header.frame_id)
            result = estimator.estimate(str(stamp), stamp, image)
        except m.DecodeError as exc:
            self._refuse(exc.kind, f"image skipped: {exc}", f"bad image: {exc}")
            return
        except MonodockError as exc:  # e.g. an image of another size than the camera's
            self._refuse("image", f"image skipped: {exc}", f"bad image: {exc}")
            return
        with self._lock:
            self._period.processing.append(time.perf_counter() - started)
        est = result.estimates[self.method]
        markers = len(result.detection.roles_seen) if result.detection is not None else 0
        if result.detection is not None and draw:
            self._publish_debug_image(msg, image, result.detection, est, estimator)
        if est.pose is None:
            with self._lock:
                self.markers, self.reason = markers, est.reason
            return
        self._publish(msg, est)
        latency = self._now() - stamp
        with self._lock:
            self.markers, self.reason = markers, ""
            self._period.poses += 1
            self._period.latencies.append(latency)

    def _publish(self, msg: Any, est: Any) -> None:
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
        if self.tf_publisher is not None:
            dock = transforms.planar(est.pose.x, est.pose.y, est.pose.yaw)
            t = set_transform(
                self._msg["TransformStamped"](), self.frame_id, self.options.dock_frame, dock, out.header.stamp
            )
            self.tf_publisher.publish(self._msg["TFMessage"](transforms=[t]))
        if est.covariance is None:
            return
        try:
            covariance = pose_covariance_6x6(est.covariance)
        except ValueError as exc:
            self._warnings.warn("covariance", f"covariance not published: {exc}")
            return
        with_cov = self._msg["PoseWithCovarianceStamped"]()
        with_cov.header = out.header
        with_cov.pose = self._msg["PoseWithCovariance"](pose=pose, covariance=covariance)
        self.covariance_publisher.publish(with_cov)

    def _publish_debug_image(self, msg: Any, image: Any, detection: Any, est: Any, estimator: Estimator) -> None:
        """The image as bgr8 with the markers, corners, dock axes and the pose (with sigma) drawn; its header is the
        image's (stamp and the camera's frame)."""
        picture = draw_overlay(image, detection, estimator.layout, estimator.camera, estimator.robot, est, scale=1.0)
        out = self._msg["Image"]()
        out.header = msg.header
        out.height, out.width = int(picture.shape[0]), int(picture.shape[1])
        out.encoding, out.is_bigendian, out.step = "bgr8", 0, int(picture.shape[1]) * 3
        out.data = np.ascontiguousarray(picture).tobytes()
        self.debug_publisher.publish(out)

    # --- /diagnostics -------------------------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        with self._lock:
            period, self._period = self._period, _Period(now)
            markers, reason = self.markers, self.reason
            dropped, refused = self.dropped_total, self.refused_total
        seconds = max(now - period.start, 1e-6)
        level, message = self._status(period, reason)
        status = self._msg["DiagnosticStatus"]()
        status.level = bytes([level])
        status.name = (
            f"{self.get_fully_qualified_name().lstrip('/')}: dock pose"  # ns/monodock_detector: several robots
        )
        status.message = message
        status.hardware_id = self.options.subscribed_image_topic
        values = {
            "images_in_hz": f"{period.images / seconds:.2f}",
            "poses_out_hz": f"{period.poses / seconds:.2f}",
            "latency_median_ms": _milliseconds(period.latencies, 50),
            "latency_p95_ms": _milliseconds(period.latencies, 95),
            "processing_median_ms": _milliseconds(period.processing, 50),
            "processing_p95_ms": _milliseconds(period.processing, 95),
            "markers_seen": "" if markers is None else str(markers),
            "frames_dropped": str(dropped),
            "images_refused": str(refused),
            "no_estimate_reason": reason,
            "method": self.method,
            "camera": self.camera_source if self.camera is not None else "waiting for camera_info",
        }
        status.values = [self._msg["KeyValue"](key=k, value=v) for k, v in values.items()]
        array = self._msg["DiagnosticArray"]()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diagnostics.publish(array)

    def _status(self, period: _Period, reason: str) -> tuple[int, str]:
        """(level, message): ERROR when nothing can be estimated, WARN when not every image gives a pose."""
        ok, warn, error = 0, 1, 2
        if period.images == 0:
            return warn, f"no images on {self.options.subscribed_image_topic}"
        if period.idle == period.images:
            return ok, reason
        if period.poses == 0:
            if self.camera is None or period.refused == period.images:
                return error, reason
            return warn, f"no estimate: {reason}"
        rates = f"{period.poses} poses from {period.images} images"
        if period.dropped or period.refused:
            return warn, f"{rates}; {period.dropped} dropped (falling behind), {period.refused} refused"
        return ok, rates


def _milliseconds(values: list[float], percentile: float) -> str:
    return f"{1e3 * float(np.percentile(values, percentile)):.1f}" if values else ""


# --- start-up checks -----------------------------------------------------------------------------------------


def _check_options(options: DetectorOptions) -> None:
    """InputError for options that cannot work, before anything is subscribed."""
    if options.model:
        return
    if options.method == "regression":
        raise InputError(f"the {options.method} method needs a model bundle (--model, or the parameter model)")
    missing = [k for k in ("layout", "robot") if not getattr(options, k)]
    if missing:
        flags = ", ".join(f"--{k} or {k}:=FILE" for k in missing)
        raise InputError(
            f"without a model bundle, give the {' and '.join(missing)} file{'s' if len(missing) > 1 else ''} "
            f"({flags}); the camera comes from --camera or camera_info"
        )


# --- running -----------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _rcl_arguments() -> Iterator[None]:
    """While rcl reads the ROS arguments: its complaint about bad ones becomes one InputError line (rcl's own log
    line on stderr is dropped then, and shown otherwise).

    Raises:
        InputError: the ROS arguments do not parse (an unknown option, a params file that is missing or not YAML).
    """
    from rclpy.impl.implementation_singleton import (  # type: ignore[import-not-found, unused-ignore]
        rclpy_implementation as impl,
    )

    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as said:
        os.dup2(said.fileno(), 2)
        try:
            yield
        except impl.UnknownROSArgsError as exc:
            raise InputError(f"unknown ROS arguments {exc}") from None
        except impl.RCLError as exc:
            text = str(exc).split(", at /")[0]
            for prefix in ("failed to initialize rcl: ", "Failed to parse ROS arguments: "):
                text = text.removeprefix(prefix)
            raise InputError(" ".join(text.split())) from None
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        said.seek(0)
        sys.stderr.write(said.read().decode(errors="replace"))


def non_ros_arguments(argv: Sequence[str]) -> list[str]:
    """``argv`` without its ROS arguments (``--ros-args ... [--]``), as rclpy.utilities.remove_ros_args.

    Raises:
        InputError: the ROS arguments do not parse.
    """
    from rclpy.utilities import remove_ros_args  # type: ignore[import-not-found, unused-ignore]

    with _rcl_arguments():
        return list(remove_ros_args(list(argv)))


def managed_detector(options: DetectorOptions) -> DockPoseNode:
    """The detector as a lifecycle node, for nav2_lifecycle_manager and ``ros2 lifecycle set``: it starts
    unconfigured (``autostart_node``: it brings itself up) and estimates only while active (``activate`` is
    ``~/start``, ``deactivate`` is ``~/stop``); while active it keeps a bond with its lifecycle manager.

    Its files are read and checked when it is created, so a bad one still ends the process with one line at start-up,
    not at ``configure``.
    """
    from rclpy.lifecycle import (  # type: ignore[import-not-found, unused-ignore]
        LifecycleNodeMixin,
        TransitionCallbackReturn,
    )

    class ManagedDockPoseNode(LifecycleNodeMixin, DockPoseNode):  # type: ignore[misc, unused-ignore]
        def __init__(self) -> None:
            DockPoseNode.__init__(self, dataclasses.replace(options, active=False))
            LifecycleNodeMixin.__init__(self)
            self.bond = ManagerBond(self, self.options.bond_heartbeat_period)
            if self.options.autostart_node:
                autostart(self)

        def on_activate(self, _state: Any) -> Any:
            self._switch(_Reply(), True)
            self.bond.create()
            return TransitionCallbackReturn.SUCCESS

        def on_deactivate(self, _state: Any) -> Any:
            self._switch(_Reply(), False)
            self.bond.destroy()
            return TransitionCallbackReturn.SUCCESS

        def on_shutdown(self, _state: Any) -> Any:
            self.bond.destroy()
            return TransitionCallbackReturn.SUCCESS

    return ManagedDockPoseNode()


@dataclass
class _Reply:
    """A Trigger response's fields, for a switch that no service asked for."""

    success: bool = False
    message: str = ""


def run_detector(options: DetectorOptions, argv: Sequence[str]) -> int:
    """Run the node until shut down (Ctrl-C, SIGTERM); ``argv`` carries the ROS arguments. User errors: one line, 2.

    SIGINT and SIGTERM set a flag (ros/shutdown.py) from before rclpy starts: rclpy's own SIGTERM handling can leave
    ``rclpy.spin`` waiting forever on a context it has shut down, and did so in CI.
    """
    from rclpy.executors import SingleThreadedExecutor  # type: ignore[import-not-found, unused-ignore]
    from rclpy.signals import SignalHandlerOptions  # type: ignore[import-not-found, unused-ignore]

    stop = ShutdownFlag()
    node: DockPoseNode | None = None
    try:
        with _rcl_arguments():
            rclpy.init(args=list(argv), signal_handler_options=SignalHandlerOptions.NO)
        node = managed_detector(options) if options.lifecycle else DockPoseNode(options)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin(executor, stop)
    except MonodockError as exc:
        print(f"monodock-ros: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.stop()
            node.destroy_node()
        rclpy.try_shutdown()
    if node is not None and node.failure is not None:
        raise node.failure
    return 0
