"""Per-frame estimation: detect the markers once, then run each requested method on the detection."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.fused import FusedEstimator
from monodock.estimation.pnp import PoseEstimate, estimate_board, estimate_single_marker
from monodock.perception.detect import Detection, MarkerDetector, as_gray

__all__ = ["COVARIANCE_COLUMNS", "CSV_COLUMNS", "METHODS", "Estimator", "FrameEstimates", "estimates_csv"]

Method = Callable[[Detection, CameraModel, DockLayout, RobotConfig], PoseEstimate]

# The geometric methods; the regression of the papers joins them with its model bundle.
METHODS: dict[str, Method] = {"pnp": estimate_single_marker, "board": estimate_board}

COVARIANCE_COLUMNS = ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw")
_COVARIANCE_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))

CSV_COLUMNS = (
    "frame",
    "stamp",
    "method",
    "valid",
    "x_m",
    "y_m",
    "yaw_deg",
    "markers_seen",
    "reprojection_px",
    "tilt_deg",
    "reason",
    # The pose covariance (SI units: m^2, m rad, rad^2) when the method gives one (fused), else empty.
    *COVARIANCE_COLUMNS,
)


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
    image (for its refined corners) and reuses the regression's answer when both are asked for.
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
    ) -> None:
        self.extra = dict(extra or {})
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
                from monodock.perception.refine import refine_detection

                refined = refine_detection(gray, det, self.camera, modules=self.modules)
                ests[m] = self.fused.estimate(det, refined, ests.get("regression"))
            elif m in self.extra:
                ests[m] = self.extra[m](det)
            else:
                ests[m] = METHODS[m](det, self.camera, self.layout, self.robot)
        return FrameEstimates(name, stamp, det, ests)

    def warm_up(self) -> None:
        """Run the fused method's compiled kernels once, so that a live stream's first frames are not late.

        numba loads them from its on-disk cache (~0.3 s) or, on a machine's first run, compiles them (~20 s).
        Two synthetic views of the dock at 1 m, drawn by the simulator with this camera, layout and mount: one
        normally exposed, one over-exposed for the clipped-marker path (~2 s in all at 1280x720, most of it the
        renderer's first call). Nothing to do for the other methods.
        """
        if "fused" not in self.methods:
            return
        from monodock.core.pose import DockPose
        from monodock.sim import Nuisances, Simulator

        pose = DockPose(self.robot.camera_mount.x + 1.0, 0.0, 0.0)
        for exposure in (1.0, 1.6):
            nuisances = Nuisances.clean().updated(exposure=exposure, supersample=2)
            sim = Simulator(layout=self.layout, camera=self.camera, robot=self.robot, nuisances=nuisances)
            self.estimate("warm-up", 0.0, sim.render(pose))

    def failed(self, name: str, stamp: float, reason: str) -> FrameEstimates:
        """The invalid result of a frame that could not be read."""
        return FrameEstimates(name, stamp, None, {m: PoseEstimate(m, None, reason) for m in self.methods})


def estimates_csv(results: Iterable[FrameEstimates]) -> str:
    """The EST.csv text of DESIGN.md: a header and one row per frame and method."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)

    def num(v: float, fmt: str) -> str:
        return format(v, fmt) if math.isfinite(v) else ""

    for r in results:
        for method, e in r.estimates.items():
            p = e.pose
            w.writerow(
                [
                    r.name,
                    num(r.stamp, ".6f"),
                    method,
                    "true" if p is not None else "false",
                    num(p.x, ".5f") if p else "",
                    num(p.y, ".5f") if p else "",
                    num(p.yaw_deg, ".4f") if p else "",
                    " ".join(e.markers_seen)
                    if e.markers_seen
                    else (" ".join(r.detection.roles_seen) if r.detection else ""),
                    num(e.reprojection_px, ".4f"),
                    num(e.tilt_deg, ".3f"),
                    e.reason,
                    *(
                        [format(float(e.covariance[i, j]), ".6g") for i, j in _COVARIANCE_INDEX]
                        if p is not None and e.covariance is not None
                        else [""] * len(COVARIANCE_COLUMNS)
                    ),
                ]
            )
    return buf.getvalue()
