"""Making an Estimator from what a user has: a model bundle, or the calibration files, or both.

One factory for the command line, the ROS 2 nodes and scripts. With a bundle, its camera, dock layout and mounts
are used (a camera or robot given beside it overrides the bundle's, a layout must match it) and the method is
the papers' regression unless another is asked for; without one, a PnP method (board by default) on the three
calibration files.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.bundle import Bundle, load_bundle
from monodock.estimation.consistency import GEOMETRIC, ScaleCheck, camera_disagreement
from monodock.estimation.estimator import Estimator
from monodock.estimation.methods import METHOD_NAMES, NEEDS_BUNDLE, MethodSetup, build_methods
from monodock.estimation.regression import RegressionEstimator

__all__ = [
    "REFINEMENTS",
    "bundle_calibration",
    "make_estimator",
]

REFINEMENTS = ("none", "subpix", "contour")

PathLike = str | os.PathLike[str]

# Warnings about the files given (held by the command line until the command has not refused its input).
_log = logging.getLogger("monodock.input")


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
    warn_camera: bool = True,
) -> tuple[CameraModel, DockLayout, RobotConfig]:
    """The bundle's camera, layout and mounts; a camera or robot given overrides the bundle's (with a warning when
    it is not the bundle's camera, unless ``warn_camera`` is False), a layout must match."""
    dock = _bundle_layout(bundle, layout)
    cam = _camera(camera) if camera is not None else bundle.camera()
    if camera is not None and warn_camera:
        said = camera_disagreement(bundle.camera(), cam, str(bundle.path), _source(camera))
        if said is not None:
            _log.warning(said)
    mounts = _robot(robot) if robot is not None else bundle.robot()
    return cam, dock, mounts


def _source(camera: CameraModel | PathLike) -> str:
    return "given" if isinstance(camera, CameraModel) else str(camera)


def make_estimator(
    *,
    method: str | None = None,
    methods: Sequence[str] | None = None,
    bundle: Bundle | PathLike | None = None,
    camera: CameraModel | PathLike | None = None,
    layout: DockLayout | PathLike | None = None,
    robot: RobotConfig | PathLike | None = None,
    refinement: str = "subpix",
    check_scale: bool = False,
    warn_camera: bool = True,
) -> Estimator:
    """The Estimator for ``method`` (its ``method`` attribute), or for several ``methods`` at once, from a bundle
    or the calibration. The one way to build an estimator: the command line, the ROS 2 nodes, dock-sim, the demo
    and the evaluation all come here (the methods themselves from ``estimation.methods``).

    Args:
        method: "regression" (the papers'; needs a bundle, the default with one), "pnp" (marker 2 alone),
            "board" (all visible markers; the default without a bundle) or "fused" (with a bundle the regression
            where it helps; without one the refined corners' planar fit alone).
        methods: several of those, run in this order on each frame (the first is the ``method``); not with
            ``method``.
        bundle: a loaded Bundle or its folder.
        camera, layout, robot: objects or their files; with a bundle, camera and robot override the bundle's and
            layout must match it; without one, all three are needed.
        refinement: OpenCV's ArUco corner refinement ("none", "subpix", "contour").
        check_scale: with a bundle and a geometric method, watch the method's depths against the regression's
            (with the bundle's own camera) over the first frames and warn once when a calibration scales them
            (``consistency.ScaleCheck``); costs one regression per frame while it watches.
        warn_camera: warn when the camera given is not the bundle's (False: the caller has said so once already,
            as dock-sim does before its worker processes build their estimators).

    Raises:
        InputError: an unknown method or refinement, a method that needs a bundle without one, missing
            calibration, a layout other than the bundle's, or a bad file (one line saying which).
    """
    if method is not None and methods is not None:
        raise InputError("give method or methods, not both")
    names = tuple(methods) if methods is not None else ((method,) if method is not None else ())
    if methods is not None and not names:
        raise InputError("no method asked for")
    unknown = [m for m in names if m not in METHOD_NAMES]
    if unknown:
        raise InputError(f"unknown method '{unknown[0]}' (from {', '.join(METHOD_NAMES)})")
    if refinement not in REFINEMENTS:
        raise InputError(f"unknown corner refinement '{refinement}' (from {', '.join(REFINEMENTS)})")
    if bundle is None:
        learnt = [m for m in names if m in NEEDS_BUNDLE]
        if learnt:
            raise InputError(f"the {learnt[0]} method needs a model bundle")
        missing = [k for k, v in (("camera", camera), ("layout", layout), ("robot", robot)) if v is None]
        if missing:
            raise InputError(f"without a model bundle, give the {', '.join(missing)} (the PnP methods need them)")
        assert camera is not None
        assert layout is not None
        assert robot is not None
        cam, dock, mounts = _camera(camera), _layout(layout), _robot(robot)
        setup = MethodSetup(cam, dock, mounts)
        built = build_methods(names or ("board",), setup)
        return Estimator(cam, dock, mounts, built, refinement=refinement)
    loaded = bundle if isinstance(bundle, Bundle) else load_bundle(Path(bundle))
    cam, dock, mounts = bundle_calibration(loaded, camera=camera, layout=layout, robot=robot, warn_camera=warn_camera)
    names = names or ("regression",)
    check = None
    if check_scale and names[0] in GEOMETRIC and loaded.camera().size == cam.size:
        check = ScaleCheck(
            RegressionEstimator(loaded, loaded.camera(), mounts).estimate,
            cam,
            dock,
            mounts,
            given_camera=_source(camera) if camera is not None else "",
            bundle_camera=loaded.camera(),
        )
    built = build_methods(names, MethodSetup(cam, dock, mounts, loaded))
    return Estimator(cam, dock, mounts, built, refinement=refinement, check=check)
