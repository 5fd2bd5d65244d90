"""A 2D LiDAR scan with sensor_msgs/LaserScan semantics: what a recording and the simulator both give."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["LaserScan"]


@dataclass(frozen=True)
class LaserScan:
    """One scan, as sensor_msgs/LaserScan: counter-clockwise beams from angle_min, ranges in metres.

    A range of NaN is an erroneous or dropped return, +inf is no return within range_max (REP 117).
    """

    stamp: float
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: NDArray[np.float32]

    def angles(self) -> NDArray[np.float64]:
        """Beam angles in the laser frame, radians."""
        return np.asarray(self.angle_min + self.angle_increment * np.arange(self.ranges.size), dtype=np.float64)

    def points(self) -> NDArray[np.float64]:
        """(x, y) in the laser frame of the valid returns, shape (N, 2)."""
        r = self.ranges.astype(np.float64)
        ok = np.isfinite(r) & (r >= self.range_min) & (r <= self.range_max)
        a = self.angles()[ok]
        return np.stack([r[ok] * np.cos(a), r[ok] * np.sin(a)], axis=1)
