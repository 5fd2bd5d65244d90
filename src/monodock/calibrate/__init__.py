"""Camera calibration: intrinsics from checkerboard views (``monodock calibrate intrinsics``)."""

from __future__ import annotations

from monodock.calibrate.intrinsics import (
    IntrinsicsResult,
    ViewResult,
    add_parser,
    calibrate_intrinsics,
    coverage_png,
    find_board,
    parse_board,
    select_frames,
)

__all__ = [
    "IntrinsicsResult",
    "ViewResult",
    "add_parser",
    "calibrate_intrinsics",
    "coverage_png",
    "find_board",
    "parse_board",
    "select_frames",
]
