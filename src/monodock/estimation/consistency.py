"""A calibration that is wrong but plausible, told once: the bundle's camera against a given one, and the geometric
poses' scale against the papers' regression.

A camera whose focal length is 30 % off, or a marker size misprinted, is inside every plausible range, and the
geometric methods (pnp, board, fused) then put the dock 30 % too far without a word: their depth scales with the
focal length times the marker size. The papers' regression learned depth from the marker's image size with the
camera it was trained with, and needs neither number at run time, so over many frames the ratio of the two depths
shows a scale error that no single frame can. ``ScaleCheck`` watches that ratio for the first frames of a run and
warns once when it is off by more than the regression's own spread allows.

Warnings go to the ``monodock.input`` logger: the command line shows them once the command has not refused its
input (``cli.main``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

import numpy as np

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.estimation.pnp import PoseEstimate
from monodock.perception.detect import Detection

__all__ = ["GEOMETRIC", "ScaleCheck", "camera_disagreement"]

_log = logging.getLogger("monodock.input")

# The methods whose depth scales with the focal length and the marker size.
GEOMETRIC = ("board", "pnp", "fused")
# Cameras whose focal lengths or principal points differ by less than this (relative) are the same camera.
SAME_CAMERA = 0.01


def _describe(camera: CameraModel) -> str:
    return (
        f"fx {camera.fx:.1f}, fy {camera.fy:.1f}, cx {camera.K[2]:.1f}, cy {camera.K[5]:.1f} px, "
        f"{camera.width}x{camera.height}"
    )


def camera_disagreement(bundle_camera: CameraModel, given: CameraModel, bundle: str, source: str) -> str | None:
    """The warning when a camera given beside a bundle is not the camera the bundle was trained with, or None.

    The regression learned the marker's image size with the bundle's camera; another focal length moves every
    geometric depth in proportion (and the regression's features with it).
    """
    a, b = bundle_camera, given
    if a.size == b.size:
        scale = max(a.width, a.height)
        differs = [abs(p - q) / max(abs(p), 1e-9) for p, q in ((a.fx, b.fx), (a.fy, b.fy))]
        shift = [abs(p - q) / scale for p, q in ((a.K[2], b.K[2]), (a.K[5], b.K[5]))]
        if max(differs + shift) <= SAME_CAMERA:
            return None
    return (
        f"the camera {source} ({_describe(b)}) is not the one {bundle} was trained with ({_describe(a)}): "
        f"the focal length sets the scale of every geometric pose; check which camera file is right"
    )


class ScaleCheck:
    """The geometric methods' depths against the regression's over the first frames of a run; one warning.

    Args:
        regression: the regression's estimate of a detection, with the bundle's own camera (the one it learned).
        camera, layout: the calibration the geometric methods use (named in the warning).
        robot: the mounts (depth is measured from the camera).
        given_camera: where ``camera`` came from when it is not the bundle's (a file beside the bundle), else "".
        bundle_camera: the bundle's camera, to tell a focal length that explains the disagreement.
        min_frames: frames with both depths before the first decision.
        max_frames: frames after which the check stops (its cost, one regression per frame, ends with it).
        floor: the smallest scale error warned about (the regression's own bias is a few percent).
        sigmas: how many standard errors of the median the disagreement must exceed as well.
        warn: where the one warning goes.
    """

    def __init__(
        self,
        regression: Callable[[Detection], PoseEstimate],
        camera: CameraModel,
        layout: DockLayout,
        robot: RobotConfig,
        *,
        given_camera: str = "",
        bundle_camera: CameraModel | None = None,
        min_frames: int = 60,
        max_frames: int = 600,
        floor: float = 0.10,
        sigmas: float = 4.0,
        warn: Callable[[str], None] | None = None,
    ) -> None:
        self.regression = regression
        self.camera, self.layout, self.robot = camera, layout, robot
        self.given_camera, self.bundle_camera = given_camera, bundle_camera
        self.min_frames, self.max_frames = min_frames, max_frames
        self.floor, self.sigmas = floor, sigmas
        self.warn = warn or _log.warning
        self.ratios: dict[str, list[float]] = {}
        self.frames = 0
        self.warning: str | None = None

    @property
    def done(self) -> bool:
        """Whether the check has decided (warned, or watched ``max_frames`` frames without cause)."""
        return self.warning is not None or self.frames >= self.max_frames

    def add(self, detection: Detection, estimates: Mapping[str, PoseEstimate]) -> None:
        """One frame's detection and the estimates of the run's methods."""
        if self.done:
            return
        geometric = {m: e for m, e in estimates.items() if m in GEOMETRIC and e.pose is not None}
        if not geometric:
            return
        reference = self.regression(detection)
        if reference.pose is None:
            return
        mount = self.robot.camera_mount.x
        depth = reference.pose.x - mount
        if not depth > 0:
            return
        self.frames += 1
        for method, est in geometric.items():
            assert est.pose is not None
            d = est.pose.x - mount
            if d > 0:
                self.ratios.setdefault(method, []).append(math.log(d / depth))
        if (self.frames >= self.min_frames and self.frames % 20 == 0) or self.frames == self.max_frames:
            self._decide()

    def _decide(self) -> None:
        for method, values in self.ratios.items():
            r = np.asarray(values)
            if len(r) < self.min_frames:
                continue
            median = float(np.median(r))
            spread = 1.4826 * float(np.median(np.abs(r - median)))
            error = 1.2533 * spread / math.sqrt(len(r))  # the standard error of a median
            if abs(median) > max(math.log1p(self.floor), self.sigmas * error):
                self.warning = self._message(method, median, len(r))
                self.warn(self.warning)
                return

    def _message(self, method: str, median: float, frames: int) -> str:
        ratio = math.exp(median)
        what = (
            f"the camera's focal length (fx {self.camera.fx:.1f} px from {self.given_camera}"
            + (f"; the bundle's camera has {self.bundle_camera.fx:.1f} px" if self.bundle_camera else "")
            + ")"
        )
        if self.given_camera and self.bundle_camera is not None:
            explained = self.camera.fx / self.bundle_camera.fx
            if abs(math.log(explained / ratio)) < 0.05:
                return (
                    f"over {frames} frames the {method} depths are {ratio:.2f}x the regression's, which needs no "
                    f"focal length or marker size: check {what}"
                )
        else:
            what = f"the camera's focal length (fx {self.camera.fx:.1f} px)"
        return (
            f"over {frames} frames the {method} depths are {ratio:.2f}x the regression's, which needs no focal "
            f"length or marker size: check {what} and the layout's marker_size ({self.layout.marker_size:g} m)"
        )
