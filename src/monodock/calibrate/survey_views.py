"""The survey's views: each photograph's dock markers with bias-free corners (``survey_views``), read from image
files, a video or a recording (``views_from_inputs``), and what became of each input frame (``ViewNote``).

``calibrate.survey`` solves the dock's layout from them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.frame import Frame
from monodock.core.layout import DockLayout
from monodock.errors import InputError
from monodock.io.frames import open_frames
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.perception.edge_offset import (
    EdgeOffset,
    clipped_roles,
    detection_edge_offset,
    estimate_edge_offset,
    offset_corners,
)
from monodock.perception.marker_fit import fit_marker
from monodock.perception.refine import refine_detection
from monodock.recording.read import is_recording, open_recording

__all__ = ["SurveyView", "ViewNote", "survey_views", "views_from_inputs"]


@dataclass(frozen=True)
class SurveyView:
    """One view's usable markers: each role's corners (4, 2), px, ArUco order; its image; the roles with clipped
    pixels (the refiner took their edges' shift out already: the edge offset is not theirs); and the roles whose
    corners come from the photometric fit of the whole marker (``perception.marker_fit``: its own edge offset is
    out already)."""

    name: str
    corners: Mapping[str, NDArray[np.float64]]
    image: NDArray[np.uint8] | None = field(default=None, repr=False, compare=False)
    clipped: tuple[str, ...] = ()
    fitted: tuple[str, ...] = ()


@dataclass(frozen=True)
class ViewNote:
    """What became of one input view: used (with its RMS reprojection error) or skipped, and why."""

    name: str
    roles: tuple[str, ...]
    used: bool
    rms_px: float = math.nan
    reason: str = ""


def survey_views(
    frames: Iterable[Frame], camera: CameraModel, layout: DockLayout, *, keep_images: bool = False
) -> tuple[list[SurveyView], list[ViewNote], EdgeOffset | None]:
    """Each frame's dock markers with bias-free corners, free of the print's edge offset.

    A survey can afford what a robot's frame cannot: each unclipped marker's corners come from the photometric fit
    of its whole printed pattern (``perception.marker_fit``, ~10 ms a marker), which measures the marker's edge
    offset and takes it out. On real photographs of a printed board its corners are 0.17-0.30 px RMS from the
    truth where the per-frame refiner's, with the pooled offset, are 0.19-0.58 px (``bench/real_photos.py``).
    A marker the fit refuses, or one with clipped pixels (whose edges the fit's linear levels cannot model),
    keeps the refiner's corners, corrected by the pooled offset.

    Returns the views (a marker whose corners could not be refined is left out), a note per skipped frame, and
    the edge offset pooled over every unclipped marker's code runs (``perception.edge_offset``; None when the
    markers are too small to measure it, and then no correction): the layout's ``edge_offset``, which the
    per-frame methods apply to the refiner's corners.
    """
    detector = MarkerDetector(layout)
    views: list[SurveyView] = []
    skipped: list[ViewNote] = []
    runs: list[NDArray[np.float64]] = []
    for frame in frames:
        if frame.image is None:
            skipped.append(ViewNote(frame.name, (), False, reason=frame.error or "unreadable"))
            continue
        gray = as_gray(frame.image)
        if (gray.shape[1], gray.shape[0]) != camera.size:
            raise InputError(
                f"{frame.name} is {gray.shape[1]}x{gray.shape[0]} but the camera is {camera.width}x{camera.height}"
            )
        detection = refine_detection(gray, detector.detect(gray), camera, modules=layout.modules)
        corners = {r: o.corners for r, o in detection.observations.items() if r not in detection.unrefined}
        if not corners:
            skipped.append(ViewNote(frame.name, (), False, reason="no dock marker found"))
            continue
        runs += detection_edge_offset(gray, detection, camera, layout)
        clipped = clipped_roles(gray, detection, modules=layout.modules)
        fitted = []
        for role, refined in list(corners.items()):
            if role in clipped:
                continue
            fit = fit_marker(gray, refined, camera, layout.marker_bits(layout.marker(role).id))
            if fit is not None:
                corners[role] = fit.corners
                fitted.append(role)
        views.append(SurveyView(frame.name, corners, gray if keep_images else None, clipped, tuple(fitted)))
    offset = pooled_edge_offset(runs)
    if offset is not None:
        views = [corrected_view(v, offset.offset_px) for v in views]
    return views, skipped, offset


def pooled_edge_offset(runs: Sequence[NDArray[np.float64]]) -> EdgeOffset | None:
    """The edge offset of many markers' runs, or None when they are too few to tell it."""
    try:
        return estimate_edge_offset(runs)
    except InputError:
        return None


def corrected_view(view: SurveyView, offset_px: float) -> SurveyView:
    """The view with its refiner's corners (neither clipped nor fitted) corrected by the edge offset."""
    keep = (*view.clipped, *view.fitted)
    corners = {r: c if r in keep else offset_corners(c, offset_px) for r, c in view.corners.items()}
    return replace(view, corners=corners)


def views_from_inputs(
    images: Sequence[str],
    camera: CameraModel | None,
    nominal: DockLayout,
    *,
    max_views: int = 40,
    keep_images: bool = False,
) -> tuple[list[SurveyView], list[ViewNote], CameraModel, EdgeOffset | None]:
    """The views of the inputs (every frame of a video or recording; the views thinned evenly to ``max_views``),
    the skipped frames and the camera."""
    if camera is None:
        recordings = [i for i in images if is_recording(i)]
        if not recordings:
            raise InputError("give --camera (the calibration of the camera that took the views)")
        with open_recording(recordings[0]) as rec:
            camera = rec.camera()
        if camera is None:
            raise InputError(f"{recordings[0]} has no CameraInfo: give --camera")
    with open_frames(images, skip_bad=True) as source:
        views, skipped, offset = survey_views(source, camera, nominal, keep_images=keep_images)
    if len(views) > max_views:
        step = (len(views) - 1) / (max_views - 1)
        views = [views[round(k * step)] for k in range(max_views)]
    return views, skipped, camera, offset
