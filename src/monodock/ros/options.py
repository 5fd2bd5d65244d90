"""What both ROS 2 nodes run: the estimator, from a model bundle or the calibration files, and the camera topic;
and the ROS parameters that set them (derived from the declarations: ``ros.parameters.parameters_of``)."""

from __future__ import annotations

from dataclasses import dataclass

from monodock.core.camera import CameraModel
from monodock.core.robot import RobotConfig
from monodock.core.settings import setting
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import REFINEMENTS, make_estimator
from monodock.estimation.methods import METHOD_NAMES

__all__ = ["EstimatorOptions"]


@dataclass(frozen=True)
class EstimatorOptions:
    """The estimator of a node (``estimation.factory.make_estimator``'s arguments) and where its images come from.

    Attributes:
        model: a model bundle folder (regression by default; it carries the camera, layout and mounts).
        method: regression, pnp, board or fused (None: regression with a bundle, board without).
        camera, layout, robot: calibration files (with a bundle: camera and robot override it).
        refinement: OpenCV's ArUco corner refinement.
        image_topic: sensor_msgs/Image, or CompressedImage with ``compressed`` (or a topic ending in /compressed).
        image_is_rectified: the images are rectified (image_proc's image_rect): the camera from camera_info is its
            projection matrix P with no distortion.
        camera_mount_source: "tf": base_link -> the images' frame from /tf_static when it is there (monodock.ros.tf),
            else the robot file's; "robot": the robot file's, checked against /tf_static.
        mount_tolerance_m, mount_tolerance_deg: /tf_static and the robot file disagree beyond these: a warning.
    """

    model: str | None = setting(
        None, help="model bundle folder (it carries the camera, layout and mounts); empty: PnP on the files"
    )
    method: str | None = setting(
        None,
        choices=METHOD_NAMES,
        help="regression, pnp, board or fused; empty: regression with a model, board without",
    )
    camera: str | None = setting(
        None, help="camera file (ROS camera_info YAML or OpenCV); empty: the model's, else camera_info's"
    )
    layout: str | None = setting(
        None, help="dock layout YAML (needed without a model; with one, it must match the model's)"
    )
    robot: str | None = setting(
        None, help="robot YAML with the camera mount (needed without a model; overrides the model's)"
    )
    refinement: str = setting("subpix", choices=REFINEMENTS, help="OpenCV's ArUco corner refinement")
    image_topic: str = setting(
        "image",
        help="sensor_msgs/Image topic; with compressed, its /compressed sub-topic is subscribed",
        cli_help="sensor_msgs/Image (default: %(default)s)",
    )
    compressed: bool = setting(
        False,
        help="subscribe to image_topic/compressed (sensor_msgs/CompressedImage)",
        cli_help="subscribe to IMAGE_TOPIC/compressed (CompressedImage)",
    )
    image_is_rectified: bool = setting(
        False,
        help="the images are rectified (image_rect): the camera from camera_info is its P, with no distortion",
        cli_help="rectified images: the camera is camera_info's P, undistorted",
    )
    camera_mount_source: str = setting(
        "tf",
        choices=("tf", "robot"),
        help="tf: base_link -> the images' frame from /tf_static when it is there, else the robot file's; "
        "robot: the robot file's (checked against /tf_static)",
        cli_help="tf: base_link -> the images' frame from /tf_static when there, else the robot file's "
        "(default: %(default)s)",
    )
    mount_tolerance_m: float = setting(
        0.01,
        positive=True,
        help="warn once when /tf_static and the robot file place the camera further apart than this, m",
        cli_help="default: %(default)s",
    )
    mount_tolerance_deg: float = setting(
        0.5,
        positive=True,
        help="warn once when /tf_static and the robot file turn the camera apart by more than this, degrees",
        cli_help="default: %(default)s",
    )

    @property
    def image_is_compressed(self) -> bool:
        """Whether the image topic carries sensor_msgs/CompressedImage."""
        return self.compressed or self.image_topic.rstrip("/").endswith("/compressed")

    @property
    def subscribed_image_topic(self) -> str:
        """The image topic subscribed: image_transport's ``<image_topic>/compressed`` with ``compressed``."""
        topic = self.image_topic.rstrip("/")
        if self.compressed and not topic.endswith("/compressed"):
            return f"{topic}/compressed"
        return self.image_topic

    def estimator(self, camera: CameraModel | None = None, robot: RobotConfig | None = None) -> Estimator:
        """The Estimator of these options; ``camera`` (from camera_info) stands in for a missing camera file,
        ``robot`` (the robot file's with the camera mount from /tf_static) for the robot file."""
        return make_estimator(
            method=self.method,
            bundle=self.model,
            camera=camera if camera is not None else self.camera,
            layout=self.layout,
            robot=robot if robot is not None else self.robot,
            refinement=self.refinement,
        )
