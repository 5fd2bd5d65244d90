"""The detection model of the dock designer: how many pixels per code cell ArUco needs to decode a dock marker.

A marker's pixels per cell is √(projected area of its quad) / cells across (its black border included: 6 for a
DICT_4X4, 7 for DICT_5X5, 8 for DICT_6X6), through the real lens. The thresholds are measured against the
simulator by ``python bench/detection_range.py --frames 1000 --seed 0`` (docs/benchmarks.md, section "detection
model"): without blur both dictionaries decode 50 % of markers at ~2.0 px a cell, 90 % at ~2.5 and 99 % at
3.2-3.4 (logistic fit), and the odd marker is still missed up to 4.75-5 px a cell, so the designer budgets 5 px a
cell ("always"); under heavy motion blur (a 6 px streak) it budgets the 99 % figure of the fit, 8.68 px a cell for
4x4 and 7.05 for 5x5. Only the two measured families are offered.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.planar import planar_model

__all__ = ["DETECTION_SOURCE", "MEASURED", "DetectionModel", "pixels_per_cell"]

DETECTION_SOURCE = (
    "docs/benchmarks.md, 'detection model': python bench/detection_range.py --frames 1000 --seed 0 "
    "(default camera, 10 cm markers, 1-8 m, yaw ±60°, default nuisances and 6 px motion blur)"
)
# px/cell at 50 / 90 / 99 % detection (logistic fit), by dictionary family and blur (docs/benchmarks.md).
MEASURED: dict[tuple[str, bool], tuple[float, float, float]] = {
    ("DICT_4X4", False): (2.03, 2.52, 3.19),
    ("DICT_4X4", True): (4.87, 6.42, 8.68),
    ("DICT_5X5", False): (1.93, 2.54, 3.41),
    ("DICT_5X5", True): (4.16, 5.35, 7.05),
}
# Without blur the bins still miss the odd marker up to 4.75-5 px a cell: "always" is 5.
ALWAYS_PX_PER_CELL = 5.0
# A marker counts as in view when its four corners are this far inside the image (the simulator's rule).
MARGIN_PX = 3.0


def family(dictionary: str) -> str:
    """DICT_4X4_50 -> DICT_4X4."""
    return "_".join(dictionary.split("_")[:2])


@dataclass(frozen=True)
class DetectionModel:
    """The px/cell a marker needs to be counted as detectable.

    Attributes:
        dictionary: the family it was measured on (DICT_4X4, DICT_5X5).
        blur: whether it budgets for heavy (6 px) motion blur.
        px_per_cell: the budget: 5 without blur, the 99 % fit with blur.
    """

    dictionary: str
    blur: bool
    px_per_cell: float

    @classmethod
    def budget(cls, dictionary: str, *, blur: bool) -> DetectionModel:
        """The designer's budget for a dictionary (any DICT_4X4_* or DICT_5X5_*).

        Raises:
            InputError: a dictionary family the detection model was not measured on.
        """
        fam = family(dictionary)
        if (fam, blur) not in MEASURED:
            raise InputError(f"no detection model measured for {dictionary} (only DICT_4X4_* and DICT_5X5_*)")
        need = MEASURED[(fam, True)][2] if blur else ALWAYS_PX_PER_CELL
        return cls(fam, blur, need)

    def detectable(self, px_per_cell: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which markers (their px/cell; 0 out of view) are budgeted as decoded."""
        return np.asarray(px_per_cell >= self.px_per_cell, dtype=bool)


def pixels_per_cell(
    pose: DockPose, camera: CameraModel, layout: DockLayout, robot: RobotConfig, roles: Sequence[str] | None = None
) -> NDArray[np.float64]:
    """Each marker's √(projected area) / cells across at a pose, shape (R,), ``roles`` order (default: all);
    0 for a marker not fully in the image (``MARGIN_PX`` inside its border) or behind the camera."""
    use = tuple(roles) if roles is not None else layout.roles
    P = planar_model(camera, layout, robot).optical_points(pose, use).reshape(len(use), 4, 3)
    out = np.zeros(len(use))
    field = camera.in_view_field(P.reshape(-1, 3)).reshape(len(use), 4).all(axis=1) & (P[:, :, 2] > 0).all(axis=1)
    if not field.any():
        return out
    px = camera.project(P[field].reshape(-1, 3)).reshape(-1, 4, 2)
    lo, hi_u, hi_v = -0.5 + MARGIN_PX, camera.width - 0.5 - MARGIN_PX, camera.height - 0.5 - MARGIN_PX
    inside = (
        (px[:, :, 0].min(axis=1) >= lo)
        & (px[:, :, 1].min(axis=1) >= lo)
        & (px[:, :, 0].max(axis=1) <= hi_u)
        & (px[:, :, 1].max(axis=1) <= hi_v)
    )
    x, y = px[:, :, 0], px[:, :, 1]
    area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
    values = np.where(inside, np.sqrt(area) / layout.modules, 0.0)
    out[np.flatnonzero(field)] = values
    return out
