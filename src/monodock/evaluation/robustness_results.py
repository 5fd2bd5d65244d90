"""The robustness sweep's results: the axes swept, per method its curve along each, the headline, the
occlusion numbers and summary.json (``RobustnessSummary``). Types only; ``evaluation.robustness`` renders the
frames and runs the methods. The file is written by ``core.records``.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from monodock.core.config import json_text
from monodock.core.records import file_key, to_record

__all__ = [
    "GOOD_ENOUGH",
    "METHODS",
    "STALE",
    "STATS",
    "Axis",
    "AxisKind",
    "AxisResult",
    "HeadlineRow",
    "LevelStats",
    "MethodCurve",
    "OcclusionStats",
    "RobustnessSettings",
    "RobustnessSummary",
    "WorstLevel",
    "headline",
]

METHODS = ("regression", "pnp", "board", "fused")
STALE = "fused (stale tables)"
# The bound the headline checks: within it a method is good enough to dock on (depth cm, lateral cm, yaw deg).
GOOD_ENOUGH = (1.0, 1.0, 1.0)


class AxisKind(enum.StrEnum):
    """What an axis changes: the pixels (IMAGE), or the files the methods are given (CALIBRATION)."""

    IMAGE = "image"
    CALIBRATION = "calibration"


@dataclass(frozen=True)
class Axis:
    """One nuisance swept on its own: its levels (in ``unit``) and the default level."""

    key: str
    title: str
    unit: str
    levels: tuple[float, ...]
    default: float
    kind: AxisKind


@dataclass(frozen=True)
class LevelStats:
    """One method at one level: valid rate, MAE (cm, cm, deg) over its valid frames, mean depth error (% of depth)."""

    valid_rate: float
    depth_mae_cm: float
    lateral_mae_cm: float
    yaw_mae_deg: float
    depth_bias_pct: float


STATS = tuple(f.name for f in dataclasses.fields(LevelStats))


@dataclass(frozen=True)
class MethodCurve:
    """One method along one axis: each statistic of ``LevelStats`` per level, in the axis's order."""

    valid_rate: tuple[float, ...]
    depth_mae_cm: tuple[float, ...]
    lateral_mae_cm: tuple[float, ...]
    yaw_mae_deg: tuple[float, ...]
    depth_bias_pct: tuple[float, ...]

    @classmethod
    def of(cls, levels: Sequence[LevelStats]) -> MethodCurve:
        return cls(*(tuple(getattr(s, k) for s in levels) for k in STATS))

    def stat(self, name: str) -> tuple[float, ...]:
        """One statistic by name (one of STATS)."""
        values: tuple[float, ...] = getattr(self, name)
        return values


@dataclass(frozen=True)
class AxisResult:
    """One axis swept: per method its curve over the axis's levels, on ``frames`` test frames per level."""

    axis: Axis
    frames: int
    methods: Mapping[str, MethodCurve]

    def to_dict(self) -> dict[str, Any]:
        a = self.axis
        return {
            "title": a.title,
            "unit": a.unit,
            "kind": a.kind,
            "default": a.default,
            "levels": list(a.levels),
            "frames": self.frames,
            "methods": to_record(self.methods),
        }


@dataclass(frozen=True)
class OcclusionStats:
    """Per occlusion level: the share of the marker the simulator finds hidden and how often ArUco found it.

    Attributes:
        occluded_marker: per marker ("m1", "m2", "m3"), the frames in which it was the occluded one.
    """

    levels: tuple[float, ...]
    hidden_measured_pct: tuple[float, ...]
    occluded_marker_detected_pct: tuple[float, ...]
    occluded_marker: Mapping[str, int]


@dataclass(frozen=True)
class WorstLevel:
    """A method's worst level on an axis: the largest MAE of each component and the lowest valid rate."""

    depth_mae_cm: float
    lateral_mae_cm: float
    yaw_mae_deg: float
    valid_rate: float


@dataclass(frozen=True)
class HeadlineRow:
    """One axis of the headline: per method its worst level; whether fused and board stay within GOOD_ENOUGH."""

    axis: str
    worst: Mapping[str, WorstLevel] = field(metadata=file_key(""))  # each method's block beside "axis" in the file
    fused_within: bool
    board_within: bool


@dataclass(frozen=True)
class RobustnessSettings:
    """What a robustness run was, as the report and summary.json show it (text for people)."""

    bundle: str
    test_frames: int = field(metadata=file_key("test frames"))
    seed: int
    pose_distribution: str = field(metadata=file_key("pose distribution"))
    test_frame_rendering: str = field(metadata=file_key("test frame rendering"))
    calibration_set: str = field(metadata=file_key("calibration set"))
    processes: int
    runtime: str


def _worst(values: Iterable[float]) -> float:
    """The largest value; infinite when a level has no estimate at all (NaN)."""
    vals = list(values)
    return max((math.inf if not math.isfinite(v) else v) for v in vals) if vals else math.nan


def _within(curve: MethodCurve) -> bool:
    return all(
        _worst(curve.stat(k)) <= bound
        for k, bound in zip(("depth_mae_cm", "lateral_mae_cm", "yaw_mae_deg"), GOOD_ENOUGH, strict=True)
    )


def headline(axes: Mapping[str, AxisResult]) -> tuple[HeadlineRow, ...]:
    """Per axis the worst level's MAE per method, and whether fused stays within GOOD_ENOUGH where board does not."""
    rows = []
    for key, a in axes.items():
        worst = {
            m: WorstLevel(_worst(c.depth_mae_cm), _worst(c.lateral_mae_cm), _worst(c.yaw_mae_deg), min(c.valid_rate))
            for m in (*METHODS, STALE)
            if (c := a.methods.get(m)) is not None
        }
        rows.append(HeadlineRow(key, worst, _within(a.methods["fused"]), _within(a.methods["board"])))
    return tuple(rows)


@dataclass(frozen=True)
class RobustnessSummary:
    """The robustness run's summary.json: settings, the headline, every axis's curves and the occlusion numbers."""

    settings: RobustnessSettings
    runtime_s: float
    headline: tuple[HeadlineRow, ...]
    axes: Mapping[str, AxisResult]
    occlusion: OcclusionStats | None

    def to_dict(self) -> dict[str, Any]:
        return {
            "settings": to_record(self.settings),
            "runtime_s": self.runtime_s,
            "good_enough": {"depth_cm": GOOD_ENOUGH[0], "lateral_cm": GOOD_ENOUGH[1], "yaw_deg": GOOD_ENOUGH[2]},
            "headline": to_record(self.headline),
            "axes": {k: a.to_dict() for k, a in self.axes.items()},
            "occlusion": to_record(self.occlusion) if self.occlusion is not None else {},
        }

    def to_json(self) -> str:
        """summary.json's text."""
        return json_text(self.to_dict())
