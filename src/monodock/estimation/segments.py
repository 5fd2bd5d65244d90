"""The depth segments of the papers' angle models: 5 cm wide over 25-250 cm (Sensors 2025 §4.3, Table 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.errors import ConfigError

__all__ = ["SegmentTable"]


@dataclass(frozen=True)
class SegmentTable:
    """The depth segments of the angle models: ``count`` segments of ``width_m`` from ``start_m`` (metres)."""

    start_m: float = 0.25
    width_m: float = 0.05
    count: int = 45

    def __post_init__(self) -> None:
        if not (self.count >= 1 and self.width_m > 0 and math.isfinite(self.start_m) and math.isfinite(self.width_m)):
            raise ConfigError(f"segment table needs count >= 1 and width > 0, got {self.count} x {self.width_m} m")

    @property
    def end_m(self) -> float:
        """The far edge of the last segment, metres."""
        return self.start_m + self.count * self.width_m

    def index(self, depth_m: float) -> int | None:
        """The segment of a depth in metres; None outside [start, end]. The far edge belongs to the last segment."""
        # Scalar twin of ``indices`` (it runs on every frame at run time); the same rounding and edges.
        if not math.isfinite(depth_m):
            return None
        pos = round((depth_m - self.start_m) / self.width_m, 9)
        k = self.count - 1 if pos == self.count else math.floor(pos)
        return k if 0 <= k < self.count else None

    def indices(self, depth_m: NDArray[np.float64]) -> NDArray[np.int64]:
        """The segment of each depth in metres, -1 where it falls outside the table (NaN included)."""
        d = np.asarray(depth_m, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            # Rounded so that 0.30 m, which is 0.2999... in binary, starts segment 1 as a reader expects.
            pos = np.round((d - self.start_m) / self.width_m, 9)
            k = np.floor(pos)
            k = np.where(pos == self.count, self.count - 1, k)
            ok = np.isfinite(k) & (k >= 0) & (k < self.count)
        return np.where(ok, k, -1).astype(np.int64)

    def bounds(self, i: int) -> tuple[float, float]:
        """The (near, far) depth of segment ``i`` in metres."""
        if not 0 <= i < self.count:
            raise IndexError(f"segment {i} outside 0..{self.count - 1}")
        lo = self.start_m + i * self.width_m
        return lo, lo + self.width_m

    def label(self, i: int) -> str:
        """Segment ``i`` as a range in centimetres, e.g. '25–30 cm'."""
        lo, hi = self.bounds(i)
        return f"{lo * 100:g}–{hi * 100:g} cm"
