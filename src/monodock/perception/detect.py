"""Finding the dock's three markers in an image with OpenCV's ArucoDetector."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.layout import ROLES, DockLayout
from monodock.errors import InputError

__all__ = ["REFINEMENTS", "Detection", "MarkerDetector", "MarkerObservation"]

REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
}


@dataclass(frozen=True)
class MarkerObservation:
    """One dock marker found in an image: its role, id and corners (ArUco order TL, TR, BR, BL), shape (4, 2)."""

    role: str
    marker_id: int
    corners: NDArray[np.float64]


@dataclass(frozen=True)
class Detection:
    """The dock markers found in one image, and the ids seen that the dock does not carry.

    ``unrefined`` lists the roles whose corners ``monodock.perception.refine`` could not refine and are still OpenCV's;
    ``recovered`` those the detector missed and ``monodock.perception.predicted`` found where the dock track
    predicted them (their code verified).
    """

    observations: dict[str, MarkerObservation]
    ignored_ids: tuple[int, ...]
    image_size: tuple[int, int]
    unrefined: tuple[str, ...] = ()
    recovered: tuple[str, ...] = ()

    def seen(self, role: str) -> bool:
        return role in self.observations

    @property
    def roles_seen(self) -> tuple[str, ...]:
        """The roles found: the papers' (left, center, right) first, then any others in the layout's order."""
        return tuple(r for r in ROLES if r in self.observations) + tuple(r for r in self.observations if r not in ROLES)


def as_gray(image: NDArray[np.generic]) -> NDArray[np.uint8]:
    """An 8-bit single-channel view of an image (mono8, BGR8, BGRA8, or 16-bit mono scaled down)."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise InputError("empty or invalid image")
    if image.dtype == np.uint16:
        img = np.asarray(image // 257, dtype=np.uint8)
    elif image.dtype == np.uint8:
        img = np.asarray(image, dtype=np.uint8)
    else:
        raise InputError(f"unsupported image type {image.dtype}; expected 8-bit or 16-bit pixels")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 3:
        img = np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), dtype=np.uint8)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = np.asarray(cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)
    if img.ndim != 2:
        raise InputError(f"unsupported image shape {image.shape}")
    return np.ascontiguousarray(img)


class MarkerDetector:
    """Detects the layout's markers; ignores other ids; refines corners to sub-pixel accuracy.

    Args:
        layout: the dock layout (dictionary and ids).
        refinement: corner refinement, one of ``REFINEMENTS`` (default ``subpix``, as the papers' pipeline).
        parameters: optional OpenCV DetectorParameters to start from.
    """

    def __init__(
        self,
        layout: DockLayout,
        *,
        refinement: str = "subpix",
        parameters: cv2.aruco.DetectorParameters | None = None,
    ) -> None:
        if refinement not in REFINEMENTS:
            raise ValueError(f"unknown corner refinement '{refinement}' (one of {', '.join(REFINEMENTS)})")
        self.layout = layout
        self.refinement = refinement
        params = _copy_parameters(parameters) if parameters is not None else cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = REFINEMENTS[refinement]
        if refinement == "subpix":
            # Tight convergence: the default 0.1 px stopping accuracy is coarser than the corners deserve.
            params.cornerRefinementMinAccuracy = 0.01
            params.cornerRefinementMaxIterations = 50
        self._detector = cv2.aruco.ArucoDetector(layout.aruco_dictionary(), params)

    def detect(self, image: NDArray[np.generic]) -> Detection:
        """The dock markers in an image (mono8 or BGR8)."""
        gray = as_gray(image)
        corners, ids, _ = self._detector.detectMarkers(gray)
        found: dict[str, MarkerObservation] = {}
        ignored: list[int] = []
        if ids is not None:
            for quad, marker_id in zip(corners, ids.ravel(), strict=True):
                role = self.layout.role_of(int(marker_id))
                if role is None:
                    ignored.append(int(marker_id))
                    continue
                c = np.asarray(quad, dtype=np.float64).reshape(4, 2)
                # The same id twice (a reflection, a spare sticker): keep the larger, the nearer one.
                if role in found and _area(found[role].corners) >= _area(c):
                    continue
                found[role] = MarkerObservation(role, int(marker_id), c)
        ordered = {r: found[r] for r in self.layout.roles if r in found}  # the layout's order, whatever OpenCV's
        return Detection(ordered, tuple(sorted(ignored)), (gray.shape[1], gray.shape[0]))


def _copy_parameters(p: cv2.aruco.DetectorParameters) -> cv2.aruco.DetectorParameters:
    """A copy, so that the caller's parameters are never changed behind their back."""
    out = cv2.aruco.DetectorParameters()
    for name in dir(p):
        if not name.startswith("_") and not callable(getattr(p, name)):
            setattr(out, name, getattr(p, name))
    return out


def _area(c: NDArray[np.float64]) -> float:
    x, y = c[:, 0], c[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
