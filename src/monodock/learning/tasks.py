"""What training is given, and the tasks it makes of it: the marker sets' rows, the configuration, and per set
one depth task on every row and one angle task per 5 cm depth segment, each with its rows and 80/20 split.

A segment with too few rows borrows the rows of its neighbours (k±1, then k±2, ...) until it has its quota
(segment_quota). Every random choice is seeded from the configuration's seed and the task (stable_seed), so a
task's split does not depend on the others.
"""

from __future__ import annotations

import math
import re
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from monodock.errors import ConfigError, InputError
from monodock.estimation.segments import SegmentTable
from monodock.learning.regressors import LEAF_BUDGET_ANGLE, LEAF_BUDGET_DEPTH, MODEL_NAMES

__all__ = ["Task", "TaskIdentity", "TrainConfig", "TrainingSet", "make_tasks", "segment_quota", "stable_seed"]

_SET_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True)
class TrainingSet:
    """Rows for one marker set, e.g. name "m1m2m3" (all three markers seen) or "m2" (marker 2 alone).

    Attributes:
        name: The set's name: letters, digits, '_' or '-' (it becomes part of file names).
        feature_names: One name per column of ``X``.
        X: Features, shape (n, len(feature_names)), all finite.
        depth: Depth target in metres (the DockPose x label), shape (n,).
        yaw_deg: Angle target in degrees, shape (n,).
        segment_depth: The depth in metres from the camera that assigns a row to its 5 cm segment, shape (n,).
    """

    name: str
    feature_names: tuple[str, ...]
    X: NDArray[np.float64]
    depth: NDArray[np.float64]
    yaw_deg: NDArray[np.float64]
    segment_depth: NDArray[np.float64]

    def __post_init__(self) -> None:
        if not _SET_NAME.match(self.name):
            raise InputError(f"training set name {self.name!r} must be 1-64 letters, digits, '_' or '-'")
        n = len(self.depth)
        if self.X.ndim != 2 or self.X.shape != (n, len(self.feature_names)):
            raise InputError(
                f"training set {self.name}: X has shape {self.X.shape}, expected ({n}, {len(self.feature_names)})"
            )
        for label, a in (("depth", self.depth), ("yaw_deg", self.yaw_deg), ("segment_depth", self.segment_depth)):
            if a.shape != (n,):
                raise InputError(f"training set {self.name}: {label} has shape {a.shape}, expected ({n},)")
        for label, a in (("X", self.X), ("depth", self.depth), ("yaw_deg", self.yaw_deg)):
            if not np.all(np.isfinite(a)):
                raise InputError(f"training set {self.name}: {label} holds NaN or infinite values")
        if len(set(self.feature_names)) != len(self.feature_names):
            raise InputError(f"training set {self.name}: feature names are not unique")


@dataclass(frozen=True)
class TrainConfig:
    """How to train: search effort, split, seed, segment borrowing rules, model types and workers.

    Attributes:
        trials: Hyperparameter draws per model type and task (types without hyperparameters: 1).
        test_size: Fraction of each task's rows held out for scoring (the papers' 80/20 split).
        seed: Seed of every random choice (splits, draws, tree seeds, SVR subsample).
        min_segment_samples: A segment with fewer rows borrows its neighbours' rows until it has this many.
        min_rows_per_feature: ... or until it has this many rows per input feature, if that is more: a
            linear model of 40 inputs fitted on 50 noisy labels learns their noise.
        max_borrow: Borrow from at most this many segments on either side.
        min_rows: Below this many rows after borrowing, a segment gets no angle model.
        svr_max_rows: SVR (O(n²) to fit) is fit on a seeded subsample of at most this many training rows.
        models: Model types to try, from MODEL_NAMES.
        jobs: Worker processes; 0 means one per available core.
        segments: The depth segments of the angle models.
    """

    trials: int = 10
    test_size: float = 0.2
    seed: int = 0
    min_segment_samples: int = 40
    min_rows_per_feature: float = 3.0
    max_borrow: int = 4
    min_rows: int = 10
    svr_max_rows: int = 4000
    models: tuple[str, ...] = MODEL_NAMES
    jobs: int = 0
    segments: SegmentTable = field(default_factory=SegmentTable)

    def __post_init__(self) -> None:
        unknown = [m for m in self.models if m not in MODEL_NAMES]
        if unknown:
            raise ConfigError(f"unknown model type(s) {', '.join(unknown)}; choose from {', '.join(MODEL_NAMES)}")
        if not self.models or len(set(self.models)) != len(self.models):
            raise ConfigError("models must name at least one model type, each once")
        if self.trials < 1:
            raise ConfigError(f"trials must be at least 1, got {self.trials}")
        if not 0.0 < self.test_size < 1.0:
            raise ConfigError(f"test_size must be between 0 and 1, got {self.test_size}")
        if self.seed < 0:
            raise ConfigError(f"seed must be non-negative, got {self.seed}")
        if self.min_rows < 5 or self.min_segment_samples < self.min_rows:
            raise ConfigError(
                f"need 5 <= min_rows <= min_segment_samples, got {self.min_rows} and {self.min_segment_samples}"
            )
        if not self.min_rows_per_feature >= 0:
            raise ConfigError(f"min_rows_per_feature must be >= 0, got {self.min_rows_per_feature}")
        if self.max_borrow < 0 or self.jobs < 0 or self.svr_max_rows < 10:
            raise ConfigError("max_borrow and jobs must be >= 0 and svr_max_rows >= 10")


def stable_seed(*parts: int | str) -> int:
    """A 32-bit seed that depends only on ``parts`` (strings hashed with CRC-32, stable across runs)."""
    words = [zlib.crc32(p.encode("utf-8")) if isinstance(p, str) else int(p) for p in parts]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint32)[0])


@dataclass(frozen=True)
class TaskIdentity:
    """Which (set, target, segment) problem a task is and where its rows come from; its result carries the same.

    Attributes:
        set_name: The TrainingSet's name.
        target: "depth" (metres) or "yaw_deg" (degrees).
        segment: The segment index for angle models, None for the depth model.
        n_own: Rows of the segment itself (all rows for depth).
        borrowed: (first, last) segment of the window whose rows were used, inclusive, when the segment had to
            borrow from its neighbours; else None.
        sources: The segments that actually contributed rows (empty for the depth model, which uses every row).
    """

    set_name: str
    target: str
    segment: int | None
    n_own: int
    borrowed: tuple[int, int] | None
    sources: tuple[int, ...]


@dataclass(frozen=True)
class Task(TaskIdentity):
    """One (set, target, segment) problem with its rows and split, before any fit."""

    set_index: int
    rows: NDArray[np.int64]
    leaf_budget: int
    train_rows: NDArray[np.int64]
    test_rows: NDArray[np.int64]
    svr_rows: NDArray[np.int64]
    y_std: float
    reason: str | None = None

    @property
    def key(self) -> str:
        return f"{self.set_name}/{self.target}/{'all' if self.segment is None else self.segment}"


def segment_quota(config: TrainConfig, n_features: int) -> int:
    """Rows an angle segment should have before it stops borrowing from its neighbours."""
    return max(config.min_segment_samples, math.ceil(config.min_rows_per_feature * n_features))


def _segment_rows(
    seg_of_row: NDArray[np.int64], k: int, config: TrainConfig, n_features: int
) -> tuple[NDArray[np.int64], int, tuple[int, int] | None]:
    """Rows for segment ``k``: its own, plus neighbours k±1, k±2, ... while fewer than the segment quota."""
    own = np.flatnonzero(seg_of_row == k)
    quota = segment_quota(config, n_features)
    lo = hi = k
    d = 0
    while int(np.count_nonzero((seg_of_row >= lo) & (seg_of_row <= hi))) < quota and d < config.max_borrow:
        d += 1
        lo, hi = max(0, k - d), min(config.segments.count - 1, k + d)
    rows = np.flatnonzero((seg_of_row >= lo) & (seg_of_row <= hi))
    borrowed = None if (lo, hi) == (k, k) else (lo, hi)
    return rows, len(own), borrowed


def _make_task(
    s: TrainingSet,
    set_index: int,
    segment: int | None,
    rows: NDArray[np.int64],
    seg_of_row: NDArray[np.int64],
    borrowed: tuple[int, int] | None,
    config: TrainConfig,
) -> Task:
    """The task of the depth model (``segment`` None) or of one segment's angle model, split 80/20."""
    from sklearn.model_selection import train_test_split

    target = "depth" if segment is None else "yaw_deg"
    key_seed = stable_seed(config.seed, s.name, target, "all" if segment is None else segment)
    empty = np.zeros(0, dtype=np.int64)
    task = Task(
        set_index=set_index,
        set_name=s.name,
        target=target,
        segment=segment,
        n_own=len(rows) if segment is None else int(np.count_nonzero(seg_of_row == segment)),
        borrowed=borrowed,
        sources=() if segment is None else tuple(int(i) for i in np.unique(seg_of_row[rows])),
        rows=rows,
        leaf_budget=LEAF_BUDGET_DEPTH if segment is None else LEAF_BUDGET_ANGLE,
        train_rows=empty,
        test_rows=empty,
        svr_rows=empty,
        y_std=0.0,
    )
    if len(rows) < config.min_rows:
        where = "" if borrowed is None else f" within ±{config.max_borrow} segments"
        return replace(task, reason=f"only {len(rows)} rows{where} (need {config.min_rows})")
    train_rows, test_rows = train_test_split(rows, test_size=config.test_size, random_state=key_seed % (2**31))
    train_rows = np.sort(np.asarray(train_rows, dtype=np.int64))
    svr_rows = train_rows
    if len(train_rows) > config.svr_max_rows:
        pick = np.random.default_rng(stable_seed(key_seed, "svr")).choice(
            len(train_rows), config.svr_max_rows, replace=False
        )
        svr_rows = train_rows[np.sort(pick)]
    y = s.depth if segment is None else s.yaw_deg
    return replace(
        task,
        train_rows=train_rows,
        test_rows=np.sort(np.asarray(test_rows, dtype=np.int64)),
        svr_rows=svr_rows,
        y_std=float(np.std(y[train_rows])),
    )


def make_tasks(sets: Sequence[TrainingSet], config: TrainConfig) -> list[Task]:
    """Every set's tasks, set by set: its depth model's, then one per segment's angle model (in segment order).

    Raises:
        InputError: A set with fewer than ``config.min_rows`` rows.
    """
    tasks: list[Task] = []
    for i, s in enumerate(sets):
        all_rows = np.arange(len(s.depth), dtype=np.int64)
        if len(all_rows) < config.min_rows:
            raise InputError(f"training set {s.name} has {len(all_rows)} rows; need at least {config.min_rows}")
        seg_of_row = config.segments.indices(s.segment_depth)
        tasks.append(_make_task(s, i, None, all_rows, seg_of_row, None, config))
        for k in range(config.segments.count):
            rows, _, borrowed = _segment_rows(seg_of_row, k, config, len(s.feature_names))
            tasks.append(_make_task(s, i, k, rows, seg_of_row, borrowed, config))
    return tasks
