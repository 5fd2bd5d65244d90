"""How noisy a marker corner is, in pixels: the one corner-noise model of the fused method and of the bound.

A corner is where two fitted marker edges meet. An edge of L pixels offers about L independent samples of the
intensity step, so its fitted line's offset has a standard deviation ∝ 1/√L, and so has the corner:
σ = c·√((1/L₁ + 1/L₂)/2) for the corner's two edges of L₁ and L₂ pixels (c/√L on a square), never below
``floor_px``. ``c`` (px^1.5) lumps image noise, contrast, blur and the corner finder.

- The fused method (``estimation.fused``) weighs its planar fit with this model, ``c`` learned from the
  training rows' fit residuals and no floor: its bias-free corners follow the edge-fit law at every size.
- The Cramér–Rao bound (``estimation.crlb``, ``evaluation.what_if``) uses it for OpenCV's SUBPIX corners, which
  follow the law only on markers whose sides exceed ~31 px: on smaller ones a corner often slides ~0.7 px along
  an edge (onto an inner cell's edge), so corners whose harmonic-mean edge is below ``small_side_px`` get at
  least ``small_sigma_px``. Its defaults are measured on the simulator's default frames with
  ``bench/crlb_whatif.py --measure-c``.

The model ignores the angle between the edges (near 90° on upright markers) and any systematic corner bias.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.errors import InputError
from monodock.perception.features import side_lengths

__all__ = [
    "DEFAULT_CORNER_C",
    "DEFAULT_SMALL_SIDE_PX",
    "DEFAULT_SMALL_SIGMA_PX",
    "CornerNoise",
    "corner_sides_px",
]

# For OpenCV's SUBPIX corners on the simulator's default frames (noise, blur, exposure, vignetting, clutter),
# measured with `python bench/crlb_whatif.py --measure-c --frames 200 --seed 3`: per-axis σ ≈ 0.6/√L from 31 to
# 180 px (band values of c 0.54-0.67), and 0.46 px on corners with edges under 31 px.
DEFAULT_CORNER_C = 0.6
DEFAULT_SMALL_SIDE_PX = 31.0
DEFAULT_SMALL_SIGMA_PX = 0.46


def corner_sides_px(corners: ArrayLike) -> NDArray[np.float64]:
    """Lengths in pixels of each corner's two edges, shape (N, 2), for markers' corners stacked (N, 2), ArUco
    order per marker (corner k's edges run to corners k−1 and k+1 of its marker)."""
    quads = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
    return np.array([_edge_pairs(side_lengths(quad)) for quad in quads], dtype=np.float64).reshape(-1, 2)


def _edge_pairs(sides: Sequence[float]) -> list[tuple[float, float]]:
    """Each corner's (previous, next) edge of a marker's four sides (side k runs from corner k to corner k+1)."""
    return [(sides[k - 1], sides[k]) for k in range(4)]


@dataclass(frozen=True)
class CornerNoise:
    """Corner noise in pixels: σ = max(c·√((1/L₁ + 1/L₂)/2), floor_px), and at least ``small_sigma_px`` when
    the corner's edges (harmonic mean) are shorter than ``small_side_px`` (module doc).

    Attributes:
        c: px^1.5; σ of a corner of a square marker L px on a side is c/√L.
        floor_px: the smallest σ any corner gets (quantisation, calibration residue).
        small_side_px: edge length below which the detector's small-marker behaviour sets in (0: never).
        small_sigma_px: σ of corners on such small markers (0: the pure edge-fit model).
    """

    c: float = DEFAULT_CORNER_C
    floor_px: float = 0.02
    small_side_px: float = DEFAULT_SMALL_SIDE_PX
    small_sigma_px: float = DEFAULT_SMALL_SIGMA_PX

    def __post_init__(self) -> None:
        ok = self.c > 0 and math.isfinite(self.c) and self.floor_px >= 0
        if not (ok and self.small_side_px >= 0 and self.small_sigma_px >= 0):
            raise InputError(f"corner noise needs c > 0 and non-negative floor and small-marker terms, got {self}")

    @classmethod
    def edge_fit(cls, c: float) -> CornerNoise:
        """The pure edge-fit law σ = c·√((1/L₁ + 1/L₂)/2): no floor, no small-marker term (bias-free corners)."""
        return cls(c=c, floor_px=0.0, small_side_px=0.0, small_sigma_px=0.0)

    def sigma(self, corners: ArrayLike) -> NDArray[np.float64]:
        """Per-corner σ in pixels, shape (N,), of markers' corners stacked (N, 2), ArUco order per marker."""
        quads = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
        return self.sigma_of_sides([side_lengths(quad) for quad in quads])

    def sigma_of_sides(self, sides: Sequence[Sequence[float]]) -> NDArray[np.float64]:
        """Per-corner σ in pixels, shape (4M,), from each marker's four sides (``side_lengths``), in plain floats:
        the fused method calls it on every frame."""
        small = 1.0 / self.small_side_px if self.small_side_px > 0 else math.inf
        out = []
        for marker in sides:
            for before, after in _edge_pairs(marker):
                inverse = 0.5 * (1.0 / max(before, 1e-9) + 1.0 / max(after, 1e-9))
                s = max(self.c * math.sqrt(inverse), self.floor_px)
                out.append(max(s, self.small_sigma_px) if inverse > small else s)
        return np.array(out, dtype=np.float64)
