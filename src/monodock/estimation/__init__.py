"""From markers to a DockPose: SolvePnP baselines, the planar fit, the papers' regression at run time, the fused
method, bundles, the Estimator."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.estimation.bundle import Bundle, load_bundle
    from monodock.estimation.corner_noise import CornerNoise
    from monodock.estimation.estimator import Estimator, FrameEstimates
    from monodock.estimation.factory import make_estimator
    from monodock.estimation.fused import FusionTables
    from monodock.estimation.methods import METHOD_NAMES, MethodSetup, PoseMethod, build_methods
    from monodock.estimation.pnp import PoseEstimate

__all__ = [
    "METHOD_NAMES",
    "Bundle",
    "CornerNoise",
    "Estimator",
    "FrameEstimates",
    "FusionTables",
    "MethodSetup",
    "PoseEstimate",
    "PoseMethod",
    "build_methods",
    "load_bundle",
    "make_estimator",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
