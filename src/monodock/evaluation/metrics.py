"""Errors of DockPose estimates against truth, summarised by depth band as the papers tabulate them."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.pose import DockPose, wrap_angle

__all__ = ["BandRow", "band_table", "method_tables", "pose_errors"]


def pose_errors(truth: Sequence[DockPose], estimates: Sequence[DockPose | None]) -> NDArray[np.float64]:
    """Signed errors (estimate - truth) as rows (dx m, dy m, dyaw rad); NaN rows where there is no estimate."""
    out = np.full((len(truth), 3), np.nan)
    for i, (t, e) in enumerate(zip(truth, estimates, strict=True)):
        if e is not None:
            out[i] = (e.x - t.x, e.y - t.y, wrap_angle(e.yaw - t.yaw))
    return out


@dataclass(frozen=True)
class BandRow:
    """One depth band of one method: counts, and mean absolute / 95th percentile errors."""

    method: str
    band: str
    frames: int
    valid: int
    depth_bias_cm: float
    depth_mae_cm: float
    depth_p95_cm: float
    lateral_mae_cm: float
    lateral_p95_cm: float
    yaw_mae_deg: float
    yaw_p95_deg: float


def _stats(values: NDArray[np.float64]) -> tuple[float, float]:
    v = np.abs(values[np.isfinite(values)])
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(np.percentile(v, 95))


def band_table(
    method: str,
    depth: NDArray[np.float64],
    errors: NDArray[np.float64],
    edges: Sequence[float] = tuple(np.round(np.arange(0.25, 2.51, 0.25), 2)),
) -> list[BandRow]:
    """Per-band and overall rows for one method; ``depth`` in metres decides each frame's band."""
    rows = []
    bands = [(lo, hi, f"{lo * 100:.0f}-{hi * 100:.0f} cm") for lo, hi in itertools.pairwise(edges)]
    bands.append((-math.inf, math.inf, "all"))
    last = edges[-1]
    for lo, hi, name in bands:
        # Bands are [lo, hi); the last one also takes its upper edge, so 250 cm lands in 225-250.
        m = (depth >= lo) & ((depth < hi) | ((hi == last) & (depth <= hi)))
        if not m.any():
            continue
        e = errors[m]
        ok = np.isfinite(e[:, 0])
        dx, dy, dyaw = _stats(e[ok, 0] * 100), _stats(e[ok, 1] * 100), _stats(np.degrees(e[ok, 2]))
        bias = float(np.mean(e[ok, 0])) * 100 if ok.any() else math.nan
        rows.append(BandRow(method, name, int(m.sum()), int(ok.sum()), bias, *dx, *dy, *dyaw))
    return rows


def method_tables(depth: NDArray[np.float64], errors: Mapping[str, NDArray[np.float64]]) -> list[BandRow]:
    """Rows of every method, band by band, with the overall row last for each."""
    rows: list[BandRow] = []
    for method, e in errors.items():
        rows += band_table(method, depth, e)
    return rows
