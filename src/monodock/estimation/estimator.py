"""Per-frame estimation: detect the markers once, then run each requested method on the detection."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.consistency import ScaleCheck
from monodock.estimation.fused import FusedEstimator
from monodock.estimation.pnp import PoseEstimate, estimate_board, estimate_single_marker
from monodock.perception.detect import Detection, MarkerDetector, as_gray
from monodock.perception.refine import refine_detection
from monodock.perception.synthetic import synthetic_view

__all__ = ["METHODS", "Estimator", "FrameEstimates"]

Method = Callable[[Detection, CameraModel, DockLayout, RobotConfig], PoseEstimate]

# The geometric methods; the regression of the papers joins them with its model bundle.
METHODS: dict[str, Method] = {"pnp": estimate_single_marker, "board": estimate_board}


@dataclass(frozen=True)
class FrameEstimates:
    """One frame's detection and every method's estimate."""

    name: str
    stamp: float
    detection: Detection | None
    estimates: dict[str, PoseEstimate]


class Estimator:
    """Detector plus the calibration every method shares (camera, layout, mounts).

    ``extra`` adds methods that need more than the calibration, e.g.
    ``{"regression": RegressionEstimator(...).estimate}``; ``fused`` the fused method, which also needs the
    image (for its refined corners) and reuses the regression's answer when both are asked for. ``check`` watches
    the geometric poses' scale against the regression's over the first frames (``consistency.ScaleCheck``).
    """

    def __init__(
        self,
        camera: CameraModel,
        layout: DockLayout,
        robot: RobotConfig,
        methods: Sequence[str] = ("board",),
        *,
        refinement: str = "subpix",
        extra: Mapping[str, Callable[[Detection], PoseEstimate]] | None = None,
        fused: FusedEstimator | None = None,
        check: ScaleCheck | None = None,
    ) -> None:
        self.extra = dict(extra or {})
        self.check = check
        self.fused = fused
        available: dict[str, object] = {**METHODS, **self.extra}
        if fused is not None:
            available["fused"] = fused
        unknown = [m for m in methods if m not in available]
        if unknown:
            raise InputError(f"unknown method '{unknown[0]}' (available: {', '.join(available)})")
        self.camera, self.layout, self.robot = camera, layout, robot
        self.methods = tuple(methods)
        self.detector = MarkerDetector(layout, refinement=refinement)
        self.modules = layout.modules

    def check_image(self, image: NDArray[np.generic], name: str) -> None:
        """InputError when the image's size is not the calibrated camera's."""
        h, w = image.shape[:2]
        if (w, h) != self.camera.size:
            raise InputError(
                f"{name}: image is {w}x{h} but the camera file is for {self.camera.width}x{self.camera.height}"
            )

    def estimate(self, name: str, stamp: float, image: NDArray[np.generic]) -> FrameEstimates:
        """Detection and the estimates of every method for one image."""
        self.check_image(image, name)
        gray = as_gray(image)
        det = self.detector.detect(gray)
        ests: dict[str, PoseEstimate] = {}
        for m in self.methods:
            if m == "fused" and self.fused is not None:
                refined = refine_detection(gray, det, self.camera, modules=self.modules)
                ests[m] = self.fused.estimate(det, refined, ests.get("regression"))
            elif m in self.extra:
                ests[m] = self.extra[m](det)
            else:
                ests[m] = METHODS[m](det, self.camera, self.layout, self.robot)
        if self.check is not None and not self.check.done:
            self.check.add(det, ests)
        return FrameEstimates(name, stamp, det, ests)

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
