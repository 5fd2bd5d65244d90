"""dock-sim's results: one run (``TrialResult``), the groups of runs, the dock filter's accuracy and
summary.json (``DockSimSummary``), and runs.csv. Types only; ``evaluation.dock_sim`` runs the dockings and
``summarize`` turns its runs into these. The files are written and read by ``core.records``.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from monodock.core.config import json_text
from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.records import file_key, from_record, to_record
from monodock.dock.states import FailureReason, State

__all__ = [
    "FILTER_BANDS_CM",
    "AbsStats",
    "DockSimSettings",
    "DockSimSummary",
    "FilterAccuracy",
    "FilterBand",
    "FilterBlock",
    "FilterFrame",
    "MethodRuns",
    "PoseMae",
    "RunGroup",
    "RunSpeed",
    "TrialResult",
    "filter_accuracy",
    "runs_csv",
]


@dataclass(frozen=True)
class FilterFrame:
    """One camera frame after the filter was seeded: DockPoses (x m, y m, yaw rad) in base_link at its exposure.

    Attributes:
        truth: the true DockPose.
        filtered: the filter's, after this frame was offered to it.
        raw: the frame's own estimate; None when the method had none (the filter coasted).
        nees: the filter's normalised estimation error squared against the truth (3 dof).
    """

    truth: tuple[float, float, float]
    filtered: tuple[float, float, float]
    raw: tuple[float, float, float] | None
    nees: float


@dataclass(frozen=True)
class TrialResult:
    """One docking run: where it started, how the robot saw it end, and how it really ended."""

    case: int
    trial: int
    method: str
    start: Pose2D
    classified_case: int | None
    state: State
    reason: str  # the mission's own words, with its numbers
    success: bool
    retries: int
    time_s: float
    lateral_cm: float  # base_link's distance from the approach axis at the end, + left
    longitudinal_cm: float  # the front edge's gap to the face at the end; negative: drove on this far into it
    heading_deg: float
    impact_speed: float | None
    frames: int
    wall_s: float
    render_s: float  # of wall_s: rendering the camera frames
    perceive_s: float  # of wall_s: detection and the method's estimate
    path: tuple[tuple[float, float, float], ...]  # true (x, y, heading) in the dock frame, every 0.2 s
    log: tuple[tuple[float, str], ...]
    filter_frames: tuple[FilterFrame, ...] = ()
    failure: FailureReason | None = None  # why the mission failed (None when it docked by its own estimate)
    planner: str = "monodock"
    point_a: tuple[float, float] | None = None  # the planned Point A (x, y) in the dock frame, by the truth's axes
    path_t: tuple[float, ...] = ()  # the time of each ``path`` sample, seconds since the start
    fault: str = "none"
    fault_triggered: bool = False  # whether the fault's moment came (e.g. a reverse leg for person-behind)
    charging: bool | None = None  # the mission's charging confirmation (None: it could not tell)
    reseats: int = 0
    recoveries: int = 0
    obstacle_waits: int = 0  # reverse legs stopped for something behind, until it cleared or the mission gave up
    collided: bool = False  # the footprint touched an obstacle (the simulator's truth)
    redock: str = ""  # with redock: "redocked", "undock failed: ..." or "redock failed: ..."; "" when not run
    variant: str = ""  # the summary's group (DockSimConfig.variant)
    cpu_s: float = 0.0  # CPU seconds of the worker process for the run (wall_s also counts waiting for a core)
    render_cpu_s: float = 0.0  # of cpu_s: rendering the camera frames
    perceive_cpu_s: float = 0.0  # of cpu_s: detection and the method's estimate
    posed_frames: int = 0  # frames the method gave a pose in
    predicted_frames: int = 0  # of those: frames whose pose used a marker the detector missed (predicted_markers)

    @property
    def recovered(self) -> bool:
        """Docked within the tolerances after something went wrong: a retry, a recovery, a re-seat or a wait for
        the space behind to clear."""
        return self.success and (self.retries > 0 or self.reseats > 0 or self.obstacle_waits > 0)

    @property
    def failed_cleanly(self) -> bool:
        """The mission gave up with its reason, stopped, and touched nothing."""
        return self.state is State.FAILED and self.failure is not None and not self.collided


@dataclass(frozen=True)
class AbsStats:
    """Mean, median, 95th percentile and maximum of absolute values (None when there were none)."""

    mean: float | None
    median: float | None
    p95: float | None
    max: float | None

    @classmethod
    def of(cls, values: Sequence[float | None]) -> AbsStats:
        """The statistics of the finite values' absolute values."""
        a = np.abs(np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64))
        if a.size == 0:
            return cls(None, None, None, None)
        return cls(float(a.mean()), float(np.median(a)), float(np.percentile(a, 95)), float(a.max()))


@dataclass(frozen=True)
class RunGroup:
    """A group of runs (one method overall, or one case of it): successes, final errors, time, retries.

    Attributes:
        failures: per failure, runs; a failed mission by its FailureReason ("markers-lost", "timeout", ...), a
            mission that docked by its own estimate but outside the tolerances by the truth as
            "docked outside the tolerances".
        case_agreement: the share of runs whose mission classified the start as the case it was drawn in.
    """

    runs: int
    successes: int
    success_rate: float | None
    final_lateral_cm: AbsStats
    final_longitudinal_cm: AbsStats
    final_heading_deg: AbsStats
    time_s: AbsStats
    retries_total: int = field(metadata=file_key("retries.total"))
    retries_max: int = field(metadata=file_key("retries.max"))
    impact_speed_mps: AbsStats
    case_agreement: float | None
    failures: Mapping[str, int]
    charging: int = 0  # runs the charger confirmed
    reseats_total: int = field(default=0, metadata=file_key("reseats"))
    recoveries_total: int = field(default=0, metadata=file_key("recoveries"))  # retries after the markers were lost
    collisions: int = 0  # runs whose footprint touched an obstacle
    faults_triggered: int = 0
    # Docked runs that undocked and docked again; of those, the ones docked again within the tolerances.
    redock_tried: int = field(default=0, metadata=file_key("redock.tried"))
    redocked: int = field(default=0, metadata=file_key("redock.redocked"))
    recovered: int = 0  # of the successes: those after a retry, recovery, re-seat or wait
    failed_cleanly: int = 0  # failed with a reason, stopped, nothing hit

    @classmethod
    def of(cls, results: Sequence[TrialResult]) -> RunGroup:
        runs = len(results)
        successes = sum(r.success for r in results)
        failures = Counter(
            (r.failure.value if r.state is State.FAILED and r.failure is not None else "docked outside the tolerances")
            for r in results
            if not r.success
        )
        return cls(
            runs=runs,
            successes=successes,
            success_rate=successes / runs if runs else None,
            final_lateral_cm=AbsStats.of([r.lateral_cm for r in results]),
            final_longitudinal_cm=AbsStats.of([r.longitudinal_cm for r in results]),
            final_heading_deg=AbsStats.of([r.heading_deg for r in results]),
            time_s=AbsStats.of([r.time_s for r in results]),
            retries_total=sum(r.retries for r in results),
            retries_max=max((r.retries for r in results), default=0),
            impact_speed_mps=AbsStats.of([r.impact_speed for r in results if r.impact_speed is not None]),
            case_agreement=sum(r.classified_case == r.case for r in results) / runs if runs else None,
            failures=dict(failures),
            charging=sum(r.charging is True for r in results),
            reseats_total=sum(r.reseats for r in results),
            recoveries_total=sum(r.recoveries for r in results),
            collisions=sum(r.collided for r in results),
            faults_triggered=sum(r.fault_triggered for r in results),
            redock_tried=sum(bool(r.redock) for r in results),
            redocked=sum(r.redock == "redocked" for r in results),
            recovered=sum(r.recovered for r in results),
            failed_cleanly=sum(r.failed_cleanly for r in results),
        )


@dataclass(frozen=True)
class MethodRuns:
    """One method's runs: every run together, per start region (``cases``, in the order of the config's cases),
    and per case the mission executed (``executed``; 0: it never planned, e.g. the dock was not found).

    The two differ: a start that first turns to face the dock changes its heading, and so its case. ``cases``
    says how the starts fared; ``executed`` how each case's manoeuvre fared.
    """

    overall: RunGroup
    cases: Mapping[int, RunGroup]
    executed: Mapping[int, RunGroup] = field(default_factory=dict)

    @classmethod
    def of(cls, results: Sequence[TrialResult], cases: Sequence[int]) -> MethodRuns:
        executed = sorted({r.classified_case or 0 for r in results})
        return cls(
            RunGroup.of(results),
            {c: RunGroup.of([r for r in results if r.case == c]) for c in cases},
            {c: RunGroup.of([r for r in results if (r.classified_case or 0) == c]) for c in executed},
        )


FILTER_BANDS_CM = tuple(range(25, 251, 25))  # camera depth band edges of the filter figures


@dataclass(frozen=True)
class PoseMae:
    """Mean absolute errors of DockPoses: depth (x) and lateral (y) in cm, yaw in degrees."""

    depth_cm: float
    lateral_cm: float
    yaw_deg: float

    @classmethod
    def of(cls, frames: Sequence[FilterFrame], which: str) -> PoseMae | None:
        """The errors of the frames' ``which`` ("filtered" or "raw") poses against their truth; None if none."""
        pairs = [(getattr(f, which), f.truth) for f in frames if getattr(f, which) is not None]
        if not pairs:
            return None
        err = np.array([[e[0] - t[0], e[1] - t[1], wrap_angle(e[2] - t[2])] for e, t in pairs])
        mae = np.abs(err).mean(axis=0)
        return cls(float(mae[0] * 100), float(mae[1] * 100), math.degrees(mae[2]))


@dataclass(frozen=True)
class FilterBlock:
    """The dock filter against single frames over a set of frames.

    Attributes:
        frames: frames that had an estimate (filtered and single-frame compare over these).
        filtered, single_frame: their MAE (None without frames).
        coasting_frames: frames without an estimate (the filter alone); coasting: its MAE there.
        nees_mean: the filter's mean normalised estimation error squared against the truth (3: consistent).
    """

    frames: int
    filtered: PoseMae | None
    single_frame: PoseMae | None
    coasting_frames: int
    coasting: PoseMae | None
    nees_mean: float | None

    @classmethod
    def of(cls, frames: Sequence[FilterFrame]) -> FilterBlock:
        seen = [f for f in frames if f.raw is not None]
        coasting = [f for f in frames if f.raw is None]
        nees = [f.nees for f in frames if math.isfinite(f.nees)]
        return cls(
            frames=len(seen),
            filtered=PoseMae.of(seen, "filtered"),
            single_frame=PoseMae.of(seen, "raw"),
            coasting_frames=len(coasting),
            coasting=PoseMae.of(coasting, "filtered"),
            nees_mean=float(np.mean(nees)) if nees else None,
        )


@dataclass(frozen=True)
class FilterBand:
    """One band of the true depth from the camera, [low, high) cm, and the filter's block there."""

    depth_cm: tuple[int, int]
    block: FilterBlock = field(metadata=file_key(""))  # its keys beside depth_cm in the file


@dataclass(frozen=True)
class FilterAccuracy:
    """The dock filter against single frames: by 25 cm band, pooled over 25-250 cm, and in the blind zone."""

    bands: tuple[FilterBand, ...]
    all: FilterBlock
    under_25cm: FilterBlock


def filter_accuracy(results: Sequence[TrialResult], camera_x: float) -> FilterAccuracy:
    """The dock filter against single frames, by 25 cm band of the true depth from the camera (25-250 cm).

    ``camera_x`` is the camera mount's x in base_link: the depth from the camera is DockPose.x minus it.
    Per band: MAE of depth (x), lateral (y) and yaw, filtered and single-frame, over the frames that had an
    estimate (like with like); frames without one (coasting) apart; and the filter's mean NEES against the
    truth (3 for a consistent covariance). ``all`` pools 25-250 cm; ``under_25cm`` is the blind zone.
    """
    frames = [f for r in results for f in r.filter_frames]

    def depth_cm(f: FilterFrame) -> float:
        return (f.truth[0] - camera_x) * 100

    edges = FILTER_BANDS_CM
    bands = tuple(
        FilterBand((lo, hi), FilterBlock.of([f for f in frames if lo <= depth_cm(f) < hi]))
        for lo, hi in itertools.pairwise(edges)
    )
    return FilterAccuracy(
        bands,
        FilterBlock.of([f for f in frames if edges[0] <= depth_cm(f) < edges[-1]]),
        FilterBlock.of([f for f in frames if depth_cm(f) < edges[0]]),
    )


@dataclass(frozen=True, kw_only=True)
class DockSimSettings:
    """What a dock-sim run was: starts, Point A, the success tolerances, the camera and the renderer."""

    trials_per_case: int
    seed: int
    distance_m: tuple[float, float]
    max_heading_deg: float
    standoff_m: float
    planner: str = "monodock"  # summaries written before the papers' planner have none
    tolerance_lateral_cm: float = field(metadata=file_key("tolerances.lateral_cm"))
    tolerance_longitudinal_cm: float = field(metadata=file_key("tolerances.longitudinal_cm"))
    tolerance_heading_deg: float = field(metadata=file_key("tolerances.heading_deg"))
    camera_rate_hz: float
    supersample: int


@dataclass(frozen=True)
class RunSpeed:
    """Means per run: wall seconds of one core, of which rendering and estimation, and camera frames."""

    runs: int
    wall_s_per_run: float | None
    render_s_per_run: float | None
    perceive_s_per_run: float | None
    frames_per_run: float | None

    @classmethod
    def of(cls, results: Sequence[TrialResult]) -> RunSpeed:
        def mean(values: list[float]) -> float | None:
            return float(np.mean(values)) if results else None

        return cls(
            runs=len(results),
            wall_s_per_run=mean([r.wall_s for r in results]),
            render_s_per_run=mean([r.render_s for r in results]),
            perceive_s_per_run=mean([r.perceive_s for r in results]),
            frames_per_run=mean([r.frames for r in results]),
        )


@dataclass(frozen=True)
class DockSimSummary:
    """dock-sim's summary.json: per method its runs overall and per case, the filter's accuracy, the settings.

    In the file, ``overall`` and ``cases`` at the top are the first method's (``method``), and every method is
    under ``methods``; ``to_json`` writes and ``from_json`` reads that layout.
    """

    method: str
    methods: Mapping[str, MethodRuns]
    filter: Mapping[str, FilterAccuracy]
    settings: DockSimSettings
    speed: RunSpeed

    @property
    def overall(self) -> RunGroup:
        """The first method's runs, all together."""
        return self.methods[self.method].overall

    @property
    def cases(self) -> Mapping[int, RunGroup]:
        """The first method's runs, per case."""
        return self.methods[self.method].cases

    def to_dict(self) -> dict[str, Any]:
        """The file's layout: the first method's ``overall`` and ``cases`` also at the top, beside ``method``."""
        record = to_record(self)
        first = record["methods"][self.method]
        return {"method": self.method, "overall": first["overall"], "cases": first["cases"], **record}

    def to_json(self) -> str:
        """summary.json's text."""
        return json_text(self.to_dict())

    @classmethod
    def from_json(cls, text: str) -> DockSimSummary:
        """Read summary.json's text back."""
        return from_record(cls, json.loads(text), "summary.json")

    @classmethod
    def read(cls, path: Path) -> DockSimSummary:
        """Read a summary.json file back."""
        return cls.from_json(path.read_text(encoding="utf-8"))


def runs_csv(results: Sequence[TrialResult]) -> str:
    """One row per run."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        [
            "case",
            "trial",
            "method",
            "start_x_m",
            "start_y_m",
            "start_heading_deg",
            "classified_case",
            "state",
            "success",
            "retries",
            "time_s",
            "lateral_cm",
            "longitudinal_cm",
            "heading_deg",
            "impact_speed_mps",
            "frames",
            "wall_s",
            "render_s",
            "perceive_s",
            "reason",
            "failure",
            "planner",
            "fault",
            "fault_triggered",
            "charging",
            "reseats",
            "recoveries",
            "collided",
            "redock",
            "posed_frames",
            "predicted_frames",
        ]
    )
    for r in results:
        w.writerow(
            [
                r.case,
                r.trial,
                r.method,
                f"{r.start.x:.4f}",
                f"{r.start.y:.4f}",
                f"{math.degrees(r.start.theta):.2f}",
                r.classified_case or "",
                r.state,
                str(r.success).lower(),
                r.retries,
                f"{r.time_s:.2f}",
                f"{r.lateral_cm:.3f}",
                f"{r.longitudinal_cm:.3f}",
                f"{r.heading_deg:.3f}",
                "" if r.impact_speed is None else f"{r.impact_speed:.4f}",
                r.frames,
                f"{r.wall_s:.2f}",
                f"{r.render_s:.2f}",
                f"{r.perceive_s:.2f}",
                r.reason,
                r.failure,
                r.planner,
                r.fault,
                str(r.fault_triggered).lower(),
                "" if r.charging is None else str(r.charging).lower(),
                r.reseats,
                r.recoveries,
                str(r.collided).lower(),
                r.redock,
                r.posed_frames,
                r.predicted_frames,
            ]
        )
    return buf.getvalue()
