"""The checks at the door of the corner refiners (``refine``, ``edge_offset``, ``marker_fit``): an 8-bit mono image
of the camera's size, four finite corners, a marker's cells with their black border; each a one-line InputError
that names the bad value."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.errors import InputError

__all__ = ["black_cells", "check_corners", "check_gray"]


def check_gray(gray: NDArray[np.uint8], who: str, camera: CameraModel | None = None) -> NDArray[np.uint8]:
    """``gray`` as it is when it is an 8-bit single-channel image (of ``camera``'s size, when given); ``who`` (e.g.
    "refine") names the caller in the error."""
    if not isinstance(gray, np.ndarray) or gray.dtype != np.uint8 or gray.ndim != 2:
        shape = getattr(gray, "shape", None)
        dtype = getattr(gray, "dtype", type(gray).__name__)
        raise InputError(f"{who} needs an 8-bit single-channel image (as_gray), got {dtype} of shape {shape}")
    if camera is not None and (gray.shape[1], gray.shape[0]) != camera.size:
        raise InputError(
            f"image is {gray.shape[1]}x{gray.shape[0]} but camera '{camera.name}' is {camera.width}x{camera.height}"
        )
    return gray


def check_corners(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """A marker's corners as a (4, 2) float array of finite pixels."""
    c = np.asarray(corners, dtype=np.float64)
    if c.shape != (4, 2) or not np.isfinite(c).all():
        raise InputError(f"marker corners must be 4 finite (x, y) pixels, got an array of shape {c.shape}")
    return c


def black_cells(bits: NDArray[np.integer[Any]] | NDArray[np.bool_]) -> NDArray[np.float64]:
    """1 = black, from monodock's cells (0 black, 1 white), checked: square, 0/1 and a black border."""
    b = np.asarray(bits)
    if b.ndim != 2 or b.shape[0] != b.shape[1] or b.shape[0] < 3 or not np.isin(b, (0, 1)).all():
        raise InputError(f"marker cells must be a square array of 0 (black) and 1 (white), got shape {b.shape}")
    black = 1.0 - b.astype(np.float64)
    if not (black[0].all() and black[-1].all() and black[:, 0].all() and black[:, -1].all()):
        raise InputError("marker cells must include the black border (DockLayout.marker_bits: 0 black, 1 white)")
    return black
