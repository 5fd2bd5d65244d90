"""What both ROS 2 nodes run: the estimator, from a model bundle or the calibration files, and the camera topic."""

from __future__ import annotations

from dataclasses import dataclass

from monodock.core.camera import CameraModel
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import make_estimator

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
    """

    model: str | None = None
    method: str | None = None
    camera: str | None = None
    layout: str | None = None
    robot: str | None = None
    refinement: str = "subpix"
    image_topic: str = "/camera/image_raw"
    compressed: bool = False

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

    def estimator(self, camera: CameraModel | None = None) -> Estimator:
        """The Estimator of these options; ``camera`` (from camera_info) stands in for a missing camera file."""
        return make_estimator(
            method=self.method,
            bundle=self.model,
            camera=camera if camera is not None else self.camera,
            layout=self.layout,
            robot=self.robot,
            refinement=self.refinement,
        )
