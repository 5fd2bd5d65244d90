"""The papers' marker features (Fig. 4, 9): side lengths, corners and centres, as named columns.

Markers are numbered as in the papers: m1 left, m2 centre (the docking point), m3 right. Corners follow
ArUco order: tl, tr, br, bl. A marker not seen has NaN features and ``m{i}_seen`` = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.camera import CameraModel
from monodock.detect import Detection
from monodock.layout import ROLE_NUMBER, ROLES

__all__ = ["FEATURE_NAMES", "MarkerFeatures", "feature_vector", "lens_centre", "marker_features"]

CORNER_NAMES = ("tl", "tr", "br", "bl")
SIDE_NAMES = ("top", "bottom", "left", "right")


@dataclass(frozen=True)
class MarkerFeatures:
    """One marker's geometry in pixels: side lengths, corners (4, 2) and centre (2,)."""

    top: float
    bottom: float
    left: float
    right: float
    corners: NDArray[np.float64]
    centre: NDArray[np.float64]


def _centre(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """Intersection of the diagonals: the image of the marker's centre under perspective (mean is not)."""
    p, r = c[0], c[2] - c[0]
    q, s = c[1], c[3] - c[1]
    denom = r[0] * s[1] - r[1] * s[0]
    if abs(denom) < 1e-12:
        return np.asarray(c.mean(axis=0), dtype=np.float64)
    t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denom
    return np.asarray(p + t * r, dtype=np.float64)


def marker_features(corners: NDArray[np.float64]) -> MarkerFeatures:
    """Side lengths (top TL-TR, bottom BR-BL, left BL-TL, right TR-BR), corners and centre of a marker."""
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)

    def side(i: int, j: int) -> float:
        return float(np.linalg.norm(c[i] - c[j]))

    return MarkerFeatures(side(0, 1), side(2, 3), side(3, 0), side(1, 2), c, _centre(c))


def _names() -> tuple[str, ...]:
    names: list[str] = []
    for role in ROLES:
        m = f"m{ROLE_NUMBER[role]}"
        names.append(f"{m}_seen")
        names += [f"{m}_{s}" for s in SIDE_NAMES]
        names += [f"{m}_{c}_{a}" for c in CORNER_NAMES for a in ("u", "v")]
        names += [f"{m}_centre_u", f"{m}_centre_v"]
    names += ["m2_offset_u", "m2_offset_v"]
    return tuple(names)


FEATURE_NAMES: tuple[str, ...] = _names()


def lens_centre(corners: NDArray[np.float64], camera: CameraModel) -> NDArray[np.float64]:
    """The pixel of a marker's centre through the lens: diagonals intersected in undistorted coordinates.

    Lens distortion bends the diagonals, so intersecting them in raw pixels is off by a few tenths of a
    pixel away from the image centre; undistorting first makes it exact for exact corners.
    """
    n = camera.normalize(corners)
    c = _centre(n)
    return np.asarray(camera.project(np.array([[c[0], c[1], 1.0]]))[0], dtype=np.float64)


def feature_vector(detection: Detection, camera: CameraModel) -> NDArray[np.float64]:
    """Features of one image in the order of FEATURE_NAMES.

    ``m2_offset_u`` is the papers' P: marker 2's centre (through the lens, see lens_centre) minus the
    principal point, pixels (+ right); ``m2_offset_v`` the same downwards.
    """
    out = np.full(len(FEATURE_NAMES), np.nan)
    i = 0
    for role in ROLES:
        obs = detection.observations.get(role)
        out[i] = 1.0 if obs is not None else 0.0
        if obs is not None:
            f = marker_features(obs.corners)
            out[i + 1 : i + 5] = (f.top, f.bottom, f.left, f.right)
            out[i + 5 : i + 13] = f.corners.ravel()
            out[i + 13 : i + 15] = f.centre
        i += 15
    centre = detection.observations.get("center")
    if centre is not None:
        c = lens_centre(centre.corners, camera)
        out[i : i + 2] = (c[0] - camera.cx, c[1] - camera.cy)
    return out
