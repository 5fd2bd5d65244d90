"""Making an Estimator from what a user has: a model bundle, or the calibration files, or both.

One factory for the command line, the ROS 2 nodes and scripts. With a bundle, its camera, dock layout and mounts
are used (a camera or robot given beside it overrides the bundle's, a layout must match it) and the method is
the papers' regression unless another is asked for; without one, a PnP method (board by default) on the three
calibration files.
"""

from __future__ import annotations

import os
from pathlib import Path

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.bundle import Bundle, load_bundle
from monodock.estimation.estimator import Estimator
from monodock.estimation.fused import FusedEstimator
from monodock.estimation.regression import RegressionEstimator

__all__ = ["METHOD_NAMES", "REFINEMENTS", "bundle_calibration", "make_estimator"]

METHOD_NAMES = ("regression", "pnp", "board", "fused")
REFINEMENTS = ("none", "subpix", "contour")

PathLike = str | os.PathLike[str]


def _camera(value: CameraModel | PathLike) -> CameraModel:
    return value if isinstance(value, CameraModel) else CameraModel.load(value)


def _layout(value: DockLayout | PathLike) -> DockLayout:
    return value if isinstance(value, DockLayout) else DockLayout.load(value)


def _robot(value: RobotConfig | PathLike) -> RobotConfig:
    return value if isinstance(value, RobotConfig) else RobotConfig.load(value)


def _describe(layout: DockLayout) -> str:
    ids = "/".join(str(m.id) for m in layout.markers)
    return f"{layout.dictionary}, ids {ids}, {layout.marker_size * 100:g} cm"


def _bundle_layout(bundle: Bundle, layout: DockLayout | PathLike | None) -> DockLayout:
    """The bundle's layout; one given beside it must be the same (the models learned that layout)."""
    own = bundle.layout()
    if layout is not None:
        given = _layout(layout)
        if given != own:
            where = layout if not isinstance(layout, DockLayout) else "the given layout"
            raise InputError(
                f"{bundle.path} was trained for another dock layout ({_describe(own)}) than {where} "
                f"({_describe(given)})"
            )
    return own


def bundle_calibration(
    bundle: Bundle,
    *,
    camera: CameraModel | PathLike | None = None,
    layout: DockLayout | PathLike | None = None,
    robot: RobotConfig | PathLike | None = None,
) -> tuple[CameraModel, DockLayout, RobotConfig]:
    """The bundle's camera, layout and mounts; a camera or robot given overrides the bundle's, a layout must match."""
    dock = _bundle_layout(bundle, layout)
    cam = _camera(camera) if camera is not None else bundle.camera()
    mounts = _robot(robot) if robot is not None else bundle.robot()
    return cam, dock, mounts


def make_estimator(
    *,
    method: str | None = None,
    bundle: Bundle | PathLike | None = None,
    camera: CameraModel | PathLike | None = None,
    layout: DockLayout | PathLike | None = None,
    robot: RobotConfig | PathLike | None = None,
    refinement: str = "subpix",
) -> Estimator:
    """The Estimator for ``method`` (its ``method`` attribute), from a bundle or the calibration.

    Args:
        method: "regression" (the papers'; needs a bundle, the default with one), "pnp" (marker 2 alone),
            "board" (all visible markers; the default without a bundle) or "fused" (needs a bundle).
        bundle: a loaded Bundle or its folder.
        camera, layout, robot: objects or their files; with a bundle, camera and robot override the bundle's and
            layout must match it; without one, all three are needed.
        refinement: OpenCV's ArUco corner refinement ("none", "subpix", "contour").

    Raises:
        InputError: an unknown method or refinement, a method that needs a bundle without one, missing
            calibration, a layout other than the bundle's, or a bad file (one line saying which).
    """
    if method is not None and method not in METHOD_NAMES:
        raise InputError(f"unknown method '{method}' (from {', '.join(METHOD_NAMES)})")
    if refinement not in REFINEMENTS:
        raise InputError(f"unknown corner refinement '{refinement}' (from {', '.join(REFINEMENTS)})")
    if bundle is None:
        if method in ("regression", "fused"):
            raise InputError(f"the {method} method needs a model bundle")
        missing = [k for k, v in (("camera", camera), ("layout", layout), ("robot", robot)) if v is None]
        if missing:
            raise InputError(f"without a model bundle, give the {', '.join(missing)} (the PnP methods need them)")
        assert camera is not None
        assert layout is not None
        assert robot is not None
        chosen = method or "board"
        return Estimator(_camera(camera), _layout(layout), _robot(robot), (chosen,), refinement=refinement)
    loaded = bundle if isinstance(bundle, Bundle) else load_bundle(Path(bundle))
    cam, dock, mounts = bundle_calibration(loaded, camera=camera, layout=layout, robot=robot)
    chosen = method or "regression"
    if chosen == "regression":
        regression = RegressionEstimator(loaded, cam, mounts)
        return Estimator(cam, dock, mounts, (chosen,), refinement=refinement, extra={chosen: regression.estimate})
    if chosen == "fused":
        fused = FusedEstimator(cam, dock, mounts, loaded.fusion_tables(), RegressionEstimator(loaded, cam, mounts))
        return Estimator(cam, dock, mounts, (chosen,), refinement=refinement, fused=fused)
    return Estimator(cam, dock, mounts, (chosen,), refinement=refinement)
