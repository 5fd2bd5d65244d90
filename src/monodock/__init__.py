"""monodock: dock a low-cost robot onto its charger with one camera and three ArUco markers.

The names a script needs, importable from here (each loads its module on first use, so ``import monodock``
stays cheap and loads nothing a robot does not run)::

    import cv2
    import monodock

    bundle = monodock.load_bundle("demo_report/bundle")
    estimator = monodock.make_estimator(bundle=bundle, method="fused")
    estimate = estimator.estimate_pose(cv2.imread("frame.png", cv2.IMREAD_UNCHANGED))
    print(estimate.pose)  # a DockPose in base_link, or None (estimate.reason says why)

The packages, in the order data flows through them: ``core`` (poses, camera, layout, robot), ``perception``
(markers in the image), ``estimation`` (the DockPose), ``dock`` (the docking mission), and around them
``recording``, ``io``, ``learning``, ``sim``, ``calibrate``, ``evaluation``, ``report``, ``ros`` and ``cli``
(docs/architecture.md draws them).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from monodock.errors import ConfigError, InputError, MonodockError

if TYPE_CHECKING:
    from monodock.core.camera import CameraModel
    from monodock.core.frame import Frame
    from monodock.core.layout import DockLayout, MarkerSpec
    from monodock.core.pose import DockPose
    from monodock.core.robot import Mount, RobotConfig
    from monodock.estimation.bundle import Bundle, load_bundle
    from monodock.estimation.estimator import Estimator, FrameEstimates
    from monodock.estimation.factory import make_estimator
    from monodock.estimation.pnp import PoseEstimate
    from monodock.io.frames import FrameSource, open_frames

__version__ = "0.1.0"

# Where each public name lives; loaded on first access (PEP 562).
_PUBLIC = {
    "Bundle": "monodock.estimation.bundle",
    "CameraModel": "monodock.core.camera",
    "DockLayout": "monodock.core.layout",
    "DockPose": "monodock.core.pose",
    "Estimator": "monodock.estimation.estimator",
    "Frame": "monodock.core.frame",
    "FrameEstimates": "monodock.estimation.estimator",
    "FrameSource": "monodock.io.frames",
    "MarkerSpec": "monodock.core.layout",
    "Mount": "monodock.core.robot",
    "PoseEstimate": "monodock.estimation.pnp",
    "RobotConfig": "monodock.core.robot",
    "load_bundle": "monodock.estimation.bundle",
    "make_estimator": "monodock.estimation.factory",
    "open_frames": "monodock.io.frames",
}

__all__ = [
    "Bundle",
    "CameraModel",
    "ConfigError",
    "DockLayout",
    "DockPose",
    "Estimator",
    "Frame",
    "FrameEstimates",
    "FrameSource",
    "InputError",
    "MarkerSpec",
    "MonodockError",
    "Mount",
    "PoseEstimate",
    "RobotConfig",
    "load_bundle",
    "make_estimator",
    "open_frames",
]


def __getattr__(name: str) -> Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'monodock' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted([*__all__, "__version__"])
