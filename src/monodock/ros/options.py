"""What both ROS 2 nodes run: the estimator, from a model bundle or the calibration files, and the camera topic;
and the ROS parameters that set them."""

from __future__ import annotations

from dataclasses import dataclass

from monodock.core.camera import CameraModel
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import METHOD_NAMES, REFINEMENTS, make_estimator
from monodock.ros.parameters import Parameter

__all__ = ["ESTIMATOR_PARAMETERS", "EstimatorOptions"]


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


# The parameters of EstimatorOptions' fields, of the same names, read once at start-up (a node adds its own and
# may describe one of these more closely).
ESTIMATOR_PARAMETERS: dict[str, Parameter] = {
    "model": Parameter("model bundle folder (it carries the camera, layout and mounts); empty: PnP on the files"),
    "method": Parameter(
        "regression, pnp, board or fused; empty: regression with a model, board without", choices=("", *METHOD_NAMES)
    ),
    "camera": Parameter("camera file (ROS camera_info YAML or OpenCV); empty: the model's, else camera_info's"),
    "layout": Parameter("dock layout YAML (needed without a model; with one, it must match the model's)"),
    "robot": Parameter("robot YAML with the camera mount (needed without a model; overrides the model's)"),
    "refinement": Parameter("OpenCV's ArUco corner refinement", choices=REFINEMENTS),
    "image_topic": Parameter("sensor_msgs/Image topic; with compressed, its /compressed sub-topic is subscribed"),
    "compressed": Parameter("subscribe to image_topic/compressed (sensor_msgs/CompressedImage)"),
}
