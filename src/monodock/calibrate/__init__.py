"""Calibration: camera intrinsics from checkerboard views (``intrinsics``), the LiDAR mount (``extrinsics``), the
dock's survey from photographs (``survey``), the camera mount from a drive (``mount``), the taught charging pose
(``teach``) and the three chained (``commission``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.calibrate.commission import Commissioning
    from monodock.calibrate.intrinsics import IntrinsicsResult, calibrate_intrinsics
    from monodock.calibrate.mount import MountCalibration, calibrate_mount_of, frames_from_recording
    from monodock.calibrate.survey import LayoutSurvey, SurveyLimits, survey_layout
    from monodock.calibrate.teach import TaughtPose, teach_from_recording

__all__ = [
    "Commissioning",
    "IntrinsicsResult",
    "LayoutSurvey",
    "MountCalibration",
    "SurveyLimits",
    "TaughtPose",
    "calibrate_intrinsics",
    "calibrate_mount_of",
    "frames_from_recording",
    "survey_layout",
    "teach_from_recording",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
