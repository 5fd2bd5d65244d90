"""Calibration: camera intrinsics from checkerboard views (``intrinsics``) and the LiDAR mount (``extrinsics``)."""

from __future__ import annotations

from monodock.calibrate.intrinsics import (
    IntrinsicsResult,
    ViewResult,
    calibrate_intrinsics,
    find_board,
    parse_board,
    select_frames,
)

__all__ = [
    "IntrinsicsResult",
    "ViewResult",
    "calibrate_intrinsics",
    "find_board",
    "parse_board",
    "select_frames",
]
