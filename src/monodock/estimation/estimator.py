"""Per-frame estimation: detect the markers once, then run each requested method on the detection."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.consistency import ScaleCheck
from monodock.estimation.methods import (
    METHOD_NAMES,
    NEEDS_BUNDLE,
    MethodFrame,
    MethodSetup,
    PoseMethod,
    build_methods,
    run_methods,
)
from monodock.estimation.pnp import PoseEstimate
from monodock.perception.detect import Detection, MarkerDetector, as_gray
from monodock.perception.predicted import PredictedMarkers, Prior
from monodock.perception.synthetic import synthetic_view

__all__ = ["Estimator", "FrameEstimates"]


@dataclass(frozen=True)
class FrameEstimates:
    """One frame's detection and every method's estimate."""

    name: str
    stamp: float
    detection: Detection | None
    estimates: dict[str, PoseEstimate]


class Estimator:
    """Detector plus the methods, all on one calibration (camera, layout, mounts).

    ``methods``: names of the methods that need nothing but the calibration ("pnp", "board"), or methods built
    by ``estimation.methods.build_methods`` (``make_estimator`` builds them from a bundle); they run in this
    order on each frame, each seeing the answers of those before it. ``check`` watches the geometric poses'
    scale against the regression's over the first frames (``consistency.ScaleCheck``).
    """

    def __init__(
        self,
        camera: CameraModel,
        layout: DockLayout,
        robot: RobotConfig,
        methods: Sequence[str] | Mapping[str, PoseMethod] = ("board",),
        *,
        refinement: str = "subpix",
        check: ScaleCheck | None = None,
    ) -> None:
        if isinstance(methods, Mapping):
            built = dict(methods)
        else:
            unknown = [m for m in methods if m not in METHOD_NAMES]
            if unknown:
                geometric = ", ".join(m for m in METHOD_NAMES if m not in NEEDS_BUNDLE)
                raise InputError(f"unknown method '{unknown[0]}' (available: {geometric})")
            learnt = [m for m in methods if m in NEEDS_BUNDLE]
            if learnt:
                raise InputError(f"the {learnt[0]} method needs a model bundle (make_estimator builds it)")
            built = build_methods(methods, MethodSetup(camera, layout, robot))
        self.check = check
        self.camera, self.layout, self.robot = camera, layout, robot
        self.pose_methods = built
        self.methods = tuple(built)
        self.detector = MarkerDetector(layout, refinement=refinement)
        self.modules = layout.modules
        self.predicted = PredictedMarkers(camera, layout, robot)

    def check_image(self, image: NDArray[np.generic], name: str) -> None:
        """InputError when the image's size is not the calibrated camera's."""
        h, w = image.shape[:2]
        if (w, h) != self.camera.size:
            raise InputError(
                f"{name}: image is {w}x{h} but the camera file is for {self.camera.width}x{self.camera.height}"
            )

    def estimate(
        self, name: str, stamp: float, image: NDArray[np.generic], *, prior: Prior | None = None
    ) -> FrameEstimates:
        """Detection and the estimates of every method for one image.

        ``prior``: the dock's predicted pose at the frame (a track's); the markers the detector missed are then
        looked for where it puts them and kept when their code reads (``perception.predicted``); the detector's
        own markers are unchanged.
        """
        self.check_image(image, name)
        gray = as_gray(image)
        detection = self.detector.detect(gray)
        if prior is not None:
            detection = self.predicted.fill(gray, detection, prior)
        return self.estimate_detection(name, stamp, gray, detection)

    def estimate_detection(
        self, name: str, stamp: float, gray: NDArray[np.uint8], detection: Detection
    ) -> FrameEstimates:
        """Every method's estimate from a detection already made on the (mono8) image."""
        frame = MethodFrame(detection, self.camera, self.modules, gray=gray, edge_offset=self.layout.edge_offset)
        estimates = run_methods(self.pose_methods, frame)
        if self.check is not None and not self.check.done:
            self.check.add(detection, estimates)
        return FrameEstimates(name, stamp, detection, estimates)

    @property
    def method(self) -> str:
        """The first of the methods: the one a single answer (``estimate_pose``, a row of ``monodock run``) gives."""
        return self.methods[0]

    def estimate_pose(self, image: NDArray[np.generic], *, stamp: float = math.nan, name: str = "") -> PoseEstimate:
        """The estimate of ``method`` for one image (the DockPose in base_link, or None with the reason)."""
        return self.estimate(name, stamp, image).estimates[self.method]

    def warm_up(self) -> None:
        """Run the fused method's compiled kernels once, so that a live stream's first frames are not late.

        numba loads them from its on-disk cache (~0.3 s) or, on a machine's first run, compiles them (~20 s).
        Two synthetic views of the dock 1 m ahead (``perception.synthetic``, this camera, layout and mount): one
        normally exposed, one over-exposed for the clipped-marker path. Nothing to do for the other methods.
        """
        if "fused" not in self.methods:
            return
        pose = DockPose(self.robot.camera_mount.x + 1.0, 0.0, 0.0)
        for exposure in (1.0, 1.6):
            self.estimate("warm-up", 0.0, synthetic_view(self.camera, self.layout, self.robot, pose, exposure=exposure))

    def failed(self, name: str, stamp: float, reason: str) -> FrameEstimates:
        """The invalid result of a frame that could not be read."""
        return FrameEstimates(name, stamp, None, {m: PoseEstimate(m, None, reason) for m in self.methods})
