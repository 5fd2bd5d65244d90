"""The pose methods by name: one small protocol, one table of builders, one way to build them.

A method turns one frame's marker detection into a DockPose in base_link (a ``PoseEstimate``). Every caller
builds its methods here: the Estimator on images (``make_estimator``, the command line, the ROS 2 nodes), the
held-out evaluation on dataset rows, dock-sim and the robustness sweep. So what the simulator measures is what
the robot runs. rosbags' back ends are the model: a ``Protocol`` and a lookup table from name to builder.

A frame reaches a method as a ``MethodFrame``: OpenCV's detection, and what the learnt methods need beyond it,
each made once per frame and only when a method asks (the bias-free corners from the image, or as a dataset
stores them; the papers' raw features as a dataset stores them), plus the answers of the methods run before it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.fused import FusedEstimator, FusionTables
from monodock.estimation.pnp import PoseEstimate, estimate_board, estimate_single_marker
from monodock.estimation.regression import RegressionEstimator
from monodock.perception.detect import Detection
from monodock.perception.edge_offset import clipped_roles, offset_detection
from monodock.perception.refine import refine_detection

if TYPE_CHECKING:
    from monodock.estimation.bundle import Bundle

__all__ = [
    "BUILDERS",
    "GEOMETRY_TABLES",
    "METHOD_NAMES",
    "NEEDS_BUNDLE",
    "USES_BUNDLE",
    "MethodFrame",
    "MethodSetup",
    "PoseMethod",
    "build_methods",
    "run_methods",
]


@dataclass
class MethodFrame:
    """One frame as the methods see it.

    Args:
        detection: OpenCV's markers.
        camera: the calibrated camera the corners are refined through.
        modules: the markers' cells across, border included (``DockLayout.modules``).
        gray: the mono8 image, from which ``refined`` is made on first use; None when ``refined_corners`` is
            given.
        refined_corners: the bias-free corners when known already (a dataset stores them).
        raw: the papers' raw features (FEATURE_NAMES order) as a dataset stores them; None: each method computes
            them from the detection through its own camera.
        earlier: the answers of the methods run before this one on the frame, by name.
        edge_offset: the layout's edge offset, px (``DockLayout.edge_offset``): the geometric methods' corners,
            OpenCV's and the refined ones, are corrected by it; the regression learnt from its own.
    """

    detection: Detection
    camera: CameraModel
    modules: int
    gray: NDArray[np.uint8] | None = None
    refined_corners: Detection | None = None
    raw: NDArray[np.float64] | None = None
    earlier: dict[str, PoseEstimate] = field(default_factory=dict)
    edge_offset: float = 0.0

    @property
    def refined(self) -> Detection:
        """The detection with bias-free corners (``perception.refine``, then the edge offset), made once.

        Markers with clipped pixels keep the refiner's own correction: it measured their edges' shift already.
        """
        if self.refined_corners is None:
            if self.gray is None:
                raise ValueError("a MethodFrame needs the image or the refined corners")
            refined = refine_detection(self.gray, self.detection, self.camera, modules=self.modules)
            if self.edge_offset:
                clipped = clipped_roles(self.gray, refined, modules=self.modules)
                refined = offset_detection(refined, self.edge_offset, skip=clipped)
            self.refined_corners = refined
        return self.refined_corners

    @functools.cached_property
    def geometric(self) -> Detection:
        """OpenCV's detection with the edge offset taken out of its corners (what pnp and board fit)."""
        return offset_detection(self.detection, self.edge_offset) if self.edge_offset else self.detection


def run_methods(methods: Mapping[str, PoseMethod], frame: MethodFrame) -> dict[str, PoseEstimate]:
    """Every method on the frame, in order, each seeing the answers of those before it (``frame.earlier``)."""
    for name, method in methods.items():
        frame.earlier[name] = method.estimate(frame)
    return frame.earlier


class PoseMethod(Protocol):
    """A way from one frame to a DockPose: its ``name`` and ``estimate``."""

    @property
    def name(self) -> str:
        """The method's name, as the command line and the results say it."""
        ...

    def estimate(self, frame: MethodFrame) -> PoseEstimate:
        """The frame's DockPose in base_link, or an invalid estimate with the reason."""
        ...


@dataclass
class MethodSetup:
    """What the methods are built from: the calibration, and for the learnt methods a model bundle.

    ``tables`` replaces the bundle's fusion tables (the robustness sweep's tables learnt on another calibration);
    without a bundle the fused method is geometry alone: the refined corners' planar fit, with no regression and
    ``tables`` (default ``GEOMETRY_TABLES``), for a robot that has no LiDAR to train a bundle with.
    """

    camera: CameraModel
    layout: DockLayout
    robot: RobotConfig
    bundle: Bundle | None = None
    tables: FusionTables | None = None

    @functools.cached_property
    def regression(self) -> RegressionEstimator:
        """The papers' regression on this calibration, one for every method built from this setup."""
        if self.bundle is None:
            raise InputError("the regression method needs a model bundle")
        return RegressionEstimator(self.bundle, self.camera, self.robot)


@dataclass(frozen=True)
class GeometricMethod:
    """A PnP method on the calibration alone: ``pnp`` (marker 2, IPPE_SQUARE; on a dock with extra markers, the
    largest seen when marker 2 is not) or ``board`` (every marker seen)."""

    name: str
    solve: Callable[[Detection, CameraModel, DockLayout, RobotConfig], PoseEstimate]
    camera: CameraModel
    layout: DockLayout
    robot: RobotConfig

    def estimate(self, frame: MethodFrame) -> PoseEstimate:
        return self.solve(frame.geometric, self.camera, self.layout, self.robot)


@dataclass(frozen=True)
class RegressionMethod:
    """The papers' regression: the marker sides' raw features through the bundle's per-segment models."""

    regression: RegressionEstimator
    name: str = "regression"

    def estimate(self, frame: MethodFrame) -> PoseEstimate:
        if frame.raw is None:
            return self.regression.estimate(frame.detection)
        return self.regression.estimate_raw(frame.raw, frame.detection.roles_seen)


@dataclass(frozen=True)
class FusedMethod:
    """The fused method: the bias-free corners' planar fit, with the regression where it helps; it reuses the
    regression's answer when that method ran before it on the frame."""

    fused: FusedEstimator
    name: str = "fused"

    def estimate(self, frame: MethodFrame) -> PoseEstimate:
        return self.fused.estimate(frame.detection, frame.refined, frame.earlier.get("regression"), raw=frame.raw)


def _fused(setup: MethodSetup) -> PoseMethod:
    if setup.bundle is None:
        tables = setup.tables if setup.tables is not None else GEOMETRY_TABLES
        return FusedMethod(FusedEstimator(setup.camera, setup.layout, setup.robot, tables))
    tables = setup.tables if setup.tables is not None else setup.bundle.fusion_tables()
    return FusedMethod(FusedEstimator(setup.camera, setup.layout, setup.robot, tables, setup.regression))


# The fused method's tables without a bundle: the refined corners' noise model (sigma_px = 0.22 / sqrt(the
# marker's side in px), about what training learns on the simulator's default frames), nothing else learnt.
GEOMETRY_TABLES = FusionTables(0.22)

# The methods by name, in the order the command line lists them.
BUILDERS: dict[str, Callable[[MethodSetup], PoseMethod]] = {
    "regression": lambda s: RegressionMethod(s.regression),
    "pnp": lambda s: GeometricMethod("pnp", estimate_single_marker, s.camera, s.layout, s.robot),
    "board": lambda s: GeometricMethod("board", estimate_board, s.camera, s.layout, s.robot),
    "fused": _fused,
}
METHOD_NAMES = tuple(BUILDERS)
# The methods that cannot run without a bundle, and those that use one when there is one (fused: geometry alone
# without; dock-sim trains a bundle for those).
NEEDS_BUNDLE = frozenset({"regression"})
USES_BUNDLE = frozenset({"regression", "fused"})


def build_methods(names: Sequence[str], setup: MethodSetup) -> dict[str, PoseMethod]:
    """The methods ``names``, in that order, built from ``setup`` (one regression shared by those that use it).

    Raises:
        InputError: an unknown name, or a learnt method without a bundle (one line).
    """
    unknown = [n for n in names if n not in BUILDERS]
    if unknown:
        raise InputError(f"unknown method '{unknown[0]}' (from {', '.join(METHOD_NAMES)})")
    return {n: BUILDERS[n](setup) for n in names}
