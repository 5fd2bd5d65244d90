"""Evaluation (papers §4.6–4.7, Tables 4–5, Figs. 12–13): every method on a held-out labelled recording,
against the LiDAR labels (the papers' reference) and the simulator's truth when the recording has it.

Also the papers' SolvePnP failure, reproduced on purpose: PnP given a marker size or focal length that is off
scales its depth by the same factor, while the regression, which learned depth from the LiDAR, does not use
the marker size at all and absorbs a focal-length error it was trained with.

``evaluate_heldout`` computes everything into a ``HeldoutResult``; ``monodock.report.evaluation`` draws it, and
``HeldoutResult.summary()`` is the summary.json contract.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.config import json_text
from monodock.core.layout import DockLayout
from monodock.core.records import to_record
from monodock.core.robot import RobotConfig
from monodock.estimation.methods import MethodFrame, MethodSetup, PoseMethod, build_methods, run_methods
from monodock.estimation.pnp import PoseEstimate
from monodock.evaluation.dock_results import RunGroup
from monodock.evaluation.limit import PhysicalLimit, physical_limit
from monodock.evaluation.metrics import BandRow, band_table
from monodock.learning.dataset import Dataset
from monodock.perception.detect import Detection
from monodock.perception.features import detection_from_features, refined_detection_from_row

__all__ = [
    "PAPERS",
    "HeldoutResult",
    "HeldoutSummary",
    "MethodResult",
    "MiscalibrationRow",
    "PaperFigure",
    "PaperSamples",
    "Reference",
    "RowInput",
    "band_rows",
    "dataset_rows",
    "errors",
    "estimate_dataset",
    "evaluate_heldout",
    "geometric_methods",
    "invalid_reasons",
    "mean_abs_error",
    "miscalibration_study",
    "paper_samples",
    "reference_poses",
]


class Reference(enum.StrEnum):
    """What the estimates are compared with: the LiDAR labels (the papers' reference), or the simulator's truth."""

    TRUTH = "truth"
    LIDAR = "lidar"

    @property
    def label(self) -> str:
        """The reference's name in a table."""
        return "simulator truth" if self is Reference.TRUTH else "LiDAR labels"


@dataclass(frozen=True)
class PaperFigure:
    """One of the papers' headline figures: a method's mean errors against their LiDAR, Tables 4-5 (28 samples)."""

    method: str
    samples: int
    depth_mae_cm: float
    yaw_mae_deg: float


# Oh & Kim (Sensors 2025), Tables 4-5: their regression and their SolvePnP (given a wrong calibration).
PAPERS = (
    PaperFigure("regression", 28, 1.18, 3.11),
    PaperFigure("SolvePnP", 28, 58.54, 6.64),
)


@dataclass(frozen=True)
class MethodResult:
    """One method over a dataset: poses (n, 3) as x m, y m, yaw rad (NaN rows invalid) and the reasons."""

    method: str
    poses: NDArray[np.float64]
    reasons: tuple[str, ...]

    @property
    def valid(self) -> NDArray[np.bool_]:
        return np.asarray(np.isfinite(self.poses[:, 0]))


@dataclass(frozen=True)
class RowInput:
    """What a method sees of one dataset row: the raw features, OpenCV's detection and the refined one."""

    raw: NDArray[np.float64]
    detection: Detection
    refined: Detection


def _collect(method: str, estimates: Sequence[PoseEstimate]) -> MethodResult:
    poses = np.full((len(estimates), 3), np.nan)
    for i, e in enumerate(estimates):
        if e.pose is not None:
            poses[i] = (e.pose.x, e.pose.y, e.pose.yaw)
    return MethodResult(method, poses, tuple(e.reason for e in estimates))


def geometric_methods(camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> dict[str, PoseMethod]:
    """The PnP baselines, all on the given calibration."""
    return build_methods(("pnp", "board"), MethodSetup(camera, layout, robot))


def dataset_rows(dataset: Dataset) -> list[RowInput]:
    """What every method sees of each row: the raw features, OpenCV's detection and the refined one."""
    camera, layout = dataset.camera(), dataset.layout()
    raw = dataset.raw_features()
    refined = dataset.refined_corners()
    return [
        RowInput(
            r, detection_from_features(r, layout, camera.size), refined_detection_from_row(r, q, layout, camera.size)
        )
        for r, q in zip(raw, refined, strict=True)
    ]


def estimate_dataset(
    dataset: Dataset, methods: Mapping[str, PoseMethod], *, rows: Sequence[RowInput] | None = None
) -> dict[str, MethodResult]:
    """Run every method, in order, on every row of a dataset, from the corners and raw features the dataset
    stores (``rows``: its ``dataset_rows``, when already built)."""
    rows = dataset_rows(dataset) if rows is None else rows
    camera, modules = dataset.camera(), dataset.layout().modules
    answers: dict[str, list[PoseEstimate]] = {name: [] for name in methods}
    for row in rows:
        found = run_methods(
            methods, MethodFrame(row.detection, camera, modules, refined_corners=row.refined, raw=row.raw)
        )
        for name, estimate in found.items():
            answers[name].append(estimate)
    return {name: _collect(name, found) for name, found in answers.items()}


def reference_poses(dataset: Dataset) -> dict[Reference, NDArray[np.float64]]:
    """The references, (n, 3) x m, y m, yaw rad: "lidar" (labels; NaN where invalid) and "truth" if present."""
    ok = np.asarray(dataset["label_valid"], dtype=bool)
    lidar = np.column_stack(
        [dataset["label_x_m"], dataset["label_y_m"], np.radians(np.asarray(dataset["label_yaw_deg"], dtype=float))]
    ).astype(np.float64)
    lidar[~ok] = np.nan
    out = {Reference.LIDAR: lidar}
    truth = np.column_stack(
        [dataset["truth_x_m"], dataset["truth_y_m"], np.radians(np.asarray(dataset["truth_yaw_deg"], dtype=float))]
    ).astype(np.float64)
    if np.isfinite(truth[:, 0]).any():
        out[Reference.TRUTH] = truth
    return out


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles wrapped into [-pi, pi); NaN stays NaN."""
    with np.errstate(invalid="ignore"):
        return np.asarray(np.remainder(a + np.pi, 2 * np.pi) - np.pi, dtype=np.float64)


def errors(reference: NDArray[np.float64], poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed errors (estimate - reference) per row; NaN where either is missing."""
    e = poses - reference
    e[:, 2] = _wrap(e[:, 2])
    return e


def band_rows(
    depth: NDArray[np.float64], reference: NDArray[np.float64], results: Mapping[str, MethodResult]
) -> list[BandRow]:
    """Per-band and overall rows of each method against one reference (rows without a reference are left out)."""
    has_ref = np.isfinite(reference[:, 0])
    rows: list[BandRow] = []
    for name, r in results.items():
        rows += band_table(name, depth[has_ref], errors(reference, r.poses)[has_ref])
    return rows


@dataclass(frozen=True)
class MiscalibrationRow:
    """A method's depth error when the calibration it is given is off by a factor."""

    quantity: str
    factor: float
    method: str
    depth_mae_cm: float
    depth_bias_pct: float  # mean signed error over the depth from the camera, percent
    yaw_mae_deg: float


def _scaled_layout(layout: DockLayout, factor: float) -> DockLayout:
    return dataclasses.replace(layout, marker_size=layout.marker_size * factor)


def miscalibration_study(
    dataset: Dataset,
    reference: NDArray[np.float64],
    *,
    factors: Sequence[float] = (1.0, 1.05, 1.5),
    regression: Mapping[tuple[str, float], Callable[[CameraModel], Mapping[str, PoseMethod]]] | None = None,
    correct: Mapping[str, MethodResult] | None = None,
    rows: Sequence[RowInput] | None = None,
) -> list[MiscalibrationRow]:
    """Depth and yaw error of the PnP methods (and the regression when given) under a wrong marker size or focal.

    Args:
        dataset: the labelled held-out data (its camera and layout are the correct calibration).
        reference: (n, 3) poses to compare with (truth, or the LiDAR labels).
        factors: the scale errors to apply (1.0: correct).
        regression: per (quantity, factor) a factory that returns the regression method(s) to run with the
            given (wrong) camera, e.g. a bundle trained with that camera. The marker size is not an input
            of the regression, so its rows there are the regression with the correct bundle.
        correct: the methods' results on this dataset with the correct calibration (``evaluate_heldout``'s),
            used as they are where the study's calibration is the correct one (factor 1), and for a
            "regression" under a wrong marker size (which it does not read) when ``regression`` has no
            factory for it; nothing is estimated twice.
        rows: the dataset's ``dataset_rows``, when already built.
    """
    camera, layout, robot = dataset.camera(), dataset.layout(), dataset.robot()
    if rows is None:
        rows = dataset_rows(dataclasses.replace(dataset, metadata={**dataset.metadata, "camera": camera.to_ros_dict()}))
    known = dict(correct or {})
    out: list[MiscalibrationRow] = []
    ok = np.isfinite(reference[:, 0])
    for quantity in ("marker size", "focal length"):
        for f in factors:
            cam = camera.focal_scaled(f) if quantity == "focal length" else camera
            lay = _scaled_layout(layout, f) if quantity == "marker size" else layout
            explicit = regression[(quantity, f)](cam) if regression is not None and (quantity, f) in regression else {}
            methods = {**geometric_methods(cam, lay, robot), **explicit}
            # Where the calibration is the correct one, a method's answers are the ones already known.
            reuse = [n for n in methods if f == 1.0 and n in known and n not in explicit]
            if "regression" not in methods and "regression" in known and (quantity == "marker size" or f == 1.0):
                reuse.append("regression")
            fresh = estimate_dataset(dataset, {n: m for n, m in methods.items() if n not in reuse}, rows=rows)
            results = {n: known[n] if n in reuse else fresh[n] for n in dict.fromkeys([*methods, *reuse])}
            for name, r in results.items():
                e = errors(reference, r.poses)[ok]
                good = np.isfinite(e[:, 0])
                # Relative to the depth from the camera: what a wrong scale multiplies.
                rel = e[good, 0] / (reference[ok][good, 0] - robot.camera_mount.x)
                out.append(
                    MiscalibrationRow(
                        quantity,
                        f,
                        name,
                        float(np.mean(np.abs(e[good, 0]))) * 100 if good.any() else math.nan,
                        float(np.mean(rel)) * 100 if good.any() else math.nan,
                        float(np.degrees(np.mean(np.abs(e[good, 2])))) if good.any() else math.nan,
                    )
                )
    return out


def _sample_rows(valid: NDArray[np.bool_], count: int) -> NDArray[np.int64]:
    idx = np.flatnonzero(valid)
    if len(idx) <= count:
        return idx
    return idx[np.linspace(0, len(idx) - 1, count).round().astype(np.int64)]


def mean_abs_error(poses: NDArray[np.float64], reference: NDArray[np.float64], col: int, scale: float) -> float:
    """Mean absolute error of one column (0 x, 1 y, 2 yaw, wrapped) times ``scale``, over the rows with both."""
    d = poses[:, col] - reference[:, col]
    e = np.abs(_wrap(d) if col == 2 else d) * scale
    e = e[np.isfinite(e)]
    return float(e.mean()) if e.size else math.nan


@dataclass(frozen=True)
class PaperSamples:
    """Tables 4 and 5 of the papers, on this recording: rows spread over it where every compared method answered.

    Attributes:
        rows: the dataset rows sampled.
        lidar: (k, 3) the LiDAR labels there (the papers' A), x m, y m, yaw rad.
        estimates: per method of regression (B), pnp (C) and board that ran, (k, 3) its estimates there.
        truth: (k, 3) the simulator's truth there, when known.
    """

    rows: NDArray[np.int64]
    lidar: NDArray[np.float64]
    estimates: Mapping[str, NDArray[np.float64]]
    truth: NDArray[np.float64] | None


def paper_samples(
    reference: NDArray[np.float64],
    results: Mapping[str, MethodResult],
    *,
    truth: NDArray[np.float64] | None = None,
    count: int = 28,
) -> PaperSamples:
    """``count`` samples spread over the recording where the LiDAR, the regression and both PnPs all answered."""
    want = [m for m in ("regression", "pnp", "board") if m in results]
    valid = np.isfinite(reference[:, 0])
    for m in want:
        valid &= results[m].valid
    rows = _sample_rows(valid, count)
    return PaperSamples(
        rows=rows,
        lidar=reference[rows],
        estimates={m: results[m].poses[rows] for m in want},
        truth=None if truth is None else truth[rows],
    )


def invalid_reasons(results: Mapping[str, MethodResult]) -> dict[str, dict[str, int]]:
    """Per method, how many frames had no estimate for each reason (its text up to the first bracket)."""
    reasons: dict[str, dict[str, int]] = {}
    for name, result in results.items():
        counts: dict[str, int] = {}
        for reason in result.reasons:
            if reason:
                counts[reason.split(" (")[0]] = counts.get(reason.split(" (")[0], 0) + 1
        reasons[name] = counts
    return reasons


def _score(r: BandRow) -> dict[str, float | int]:
    """A method's overall row as summary.json has it."""
    return {
        "frames": r.frames,
        "valid": r.valid,
        "depth_mae_cm": r.depth_mae_cm,
        "depth_p95_cm": r.depth_p95_cm,
        "lateral_mae_cm": r.lateral_mae_cm,
        "lateral_p95_cm": r.lateral_p95_cm,
        "yaw_mae_deg": r.yaw_mae_deg,
        "yaw_p95_deg": r.yaw_p95_deg,
    }


@dataclass(frozen=True)
class HeldoutSummary:
    """The evaluation's summary.json: every method's overall errors, the studies, and (from the demo) docking.

    Attributes:
        rows: labelled rows of the held-out dataset.
        has_truth: whether it has the simulator's truth.
        against_truth: per method its overall row against the truth (None without truth).
        against_lidar: per method its overall row against the LiDAR labels.
        physical_limit: the Cramér–Rao study (None when not run, or without refined corners).
        limit_studied: whether the study was run (with truth and the fused method); its block is then present,
            empty when the dataset had no refined corners.
        miscalibration: the wrong marker size / focal length study.
        invalid_reasons: per method, frames without an estimate by reason.
        docking: per method, the closed-loop docking's overall group (the demo's), or None.
    """

    rows: int
    has_truth: bool
    against_truth: Mapping[str, BandRow] | None
    against_lidar: Mapping[str, BandRow]
    physical_limit: PhysicalLimit | None
    limit_studied: bool
    miscalibration: tuple[MiscalibrationRow, ...]
    invalid_reasons: Mapping[str, Mapping[str, int]]
    docking: Mapping[str, RunGroup] | None = None

    @property
    def overall(self) -> Mapping[str, BandRow]:
        """Per method the overall row against the best reference: the truth when known, else the LiDAR."""
        return self.against_truth if self.against_truth is not None else self.against_lidar

    def to_dict(self) -> dict[str, Any]:
        """The JSON object, keys and nesting as summary.json has them."""
        out: dict[str, Any] = {"rows": self.rows, "has_truth": self.has_truth}
        if self.against_truth is not None:
            out["against_truth"] = {m: _score(r) for m, r in self.against_truth.items()}
        out["against_lidar"] = {m: _score(r) for m, r in self.against_lidar.items()}
        if self.limit_studied:
            out["physical_limit"] = self.physical_limit.to_dict() if self.physical_limit is not None else {}
        out["miscalibration"] = [dataclasses.asdict(r) for r in self.miscalibration]
        out["invalid_reasons"] = {m: dict(c) for m, c in self.invalid_reasons.items()}
        if self.docking is not None:
            out["docking"] = {m: to_record(g) for m, g in self.docking.items()}
        return out

    def to_json(self) -> str:
        """summary.json's text."""
        return json_text(self.to_dict())


@dataclass(frozen=True)
class HeldoutResult:
    """Every method on one held-out dataset, against its references, and the studies on it.

    Attributes:
        rows: labelled rows of the dataset.
        results: per method (regression, pnp, board, fused as run) its estimates of every row.
        references: "lidar" (the labels; NaN where invalid) and, when known, "truth": (rows, 3) x m, y m, yaw rad.
        depth: each row's depth from the camera, m, by the truth when known, else the labels.
        bands: per reference ("truth" first when known, then "lidar") every method's rows by 25 cm band.
        samples: the data of the papers' Tables 4 and 5.
        miscalibration: the study of a wrong marker size or focal length.
        limit: the physical limit (None without truth, the fused method or refined corners).
        limit_studied: whether the physical limit was studied (truth and the fused method were there).
        invalid_reasons: per method, frames without an estimate by reason.
    """

    rows: int
    results: Mapping[str, MethodResult]
    references: Mapping[Reference, NDArray[np.float64]]
    depth: NDArray[np.float64]
    bands: Mapping[Reference, tuple[BandRow, ...]]
    samples: PaperSamples
    miscalibration: tuple[MiscalibrationRow, ...]
    limit: PhysicalLimit | None
    limit_studied: bool
    invalid_reasons: Mapping[str, Mapping[str, int]]

    @property
    def has_truth(self) -> bool:
        return Reference.TRUTH in self.references

    def overall(self, reference: Reference) -> dict[str, BandRow]:
        """Per method its row over all depths against one reference."""
        return {r.method: r for r in self.bands[reference] if r.band == "all"}

    def summary(self, *, docking: Mapping[str, RunGroup] | None = None) -> HeldoutSummary:
        """The summary.json contract; ``docking`` adds the closed-loop docking's groups (the demo's)."""
        return HeldoutSummary(
            rows=self.rows,
            has_truth=self.has_truth,
            against_truth=self.overall(Reference.TRUTH) if self.has_truth else None,
            against_lidar=self.overall(Reference.LIDAR),
            physical_limit=self.limit,
            limit_studied=self.limit_studied,
            miscalibration=self.miscalibration,
            invalid_reasons=self.invalid_reasons,
            docking=docking,
        )


def evaluate_heldout(
    dataset: Dataset,
    learnt: Mapping[str, PoseMethod] | None = None,
    *,
    miscalibrated: Mapping[tuple[str, float], Callable[[CameraModel], Mapping[str, PoseMethod]]] | None = None,
) -> HeldoutResult:
    """Run the regression and fused (when given), single-marker PnP and board PnP on a labelled dataset.

    Args:
        dataset: the held-out labelled dataset (its camera, layout and robot are the right calibration).
        learnt: the methods that need a bundle, by name ("regression", "fused"), as ``build_methods`` makes
            them; the fused method with the truth also brings the physical-limit study.
        miscalibrated: regression factories for the miscalibration study's wrong focal lengths (see
            ``miscalibration_study``).
    """
    camera, layout, robot = dataset.camera(), dataset.layout(), dataset.robot()
    learnt = dict(learnt or {})
    methods: dict[str, PoseMethod] = {k: learnt[k] for k in ("regression",) if k in learnt}
    methods.update(geometric_methods(camera, layout, robot))
    methods.update({k: v for k, v in learnt.items() if k not in methods})
    has_fused = "fused" in learnt
    rows = dataset_rows(dataset)
    results = estimate_dataset(dataset, methods, rows=rows)
    refs = reference_poses(dataset)
    best = refs.get(Reference.TRUTH, refs[Reference.LIDAR])
    depth = best[:, 0] - robot.camera_mount.x
    # The truth first when known: it is the headline's reference.
    bands = {r: tuple(band_rows(depth, refs[r], results)) for r in (Reference.TRUTH, Reference.LIDAR) if r in refs}
    studied = Reference.TRUTH in refs and has_fused
    limit = physical_limit(dataset, {m: r.poses for m, r in results.items()}) if studied else None
    samples = paper_samples(refs[Reference.LIDAR], results, truth=refs.get(Reference.TRUTH))
    study = miscalibration_study(dataset, best, regression=miscalibrated, correct=results, rows=rows)
    return HeldoutResult(
        rows=len(dataset),
        results=results,
        references=refs,
        depth=depth,
        bands=bands,
        samples=samples,
        miscalibration=tuple(study),
        limit=limit,
        limit_studied=studied,
        invalid_reasons=invalid_reasons(results),
    )
