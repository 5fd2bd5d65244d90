"""Training the regression models of the papers: seven regressors, 80/20 split, the lowest test MSE wins.

For each marker set (e.g. all three markers seen, or marker 2 alone) this trains one global depth model on all
rows, and one angle (yaw) model per 5 cm depth segment over 25-250 cm (Sensors 2025, §4.2). A segment with
too few rows borrows the rows of its neighbours (k±1, then k±2, ...). Every (set, target, segment) task tries
each of the seven model types with up to ``trials`` random hyperparameter draws; each draw is fit on the 80 %
split and scored on the 20 % split; the model type whose best draw has the lowest test MSE is kept.

All fits run in parallel (joblib, loky processes), each with its own seed derived from the configuration's seed
and the task, so results do not depend on the number of workers. Features are rounded to float32 before
fitting: the exported ONNX models take float32 input, and trees then split on the very numbers they will see.
"""

from __future__ import annotations

import logging
import math
import os
import re
import sys
import time
import warnings
import zlib
from collections.abc import Generator, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from joblib import Parallel, delayed, parallel_config
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from monodock.core.cluster import active_client
from monodock.core.interrupt import sigint_blocked
from monodock.errors import ConfigError, InputError
from monodock.estimation.segments import SegmentTable
from monodock.learning.treefit import lean_predict

__all__ = [
    "MODEL_NAMES",
    "ModelScore",
    "SetResult",
    "TaskResult",
    "TrainConfig",
    "TrainingResult",
    "TrainingSet",
    "describe_search_space",
    "make_regressor",
    "segment_quota",
    "train",
]

MODEL_NAMES: tuple[str, ...] = (
    "linear",
    "ridge",
    "lasso",
    "decision_tree",
    "random_forest",
    "svr",
    "gradient_boosting",
)

# Model types that see standardised inputs (a StandardScaler in front, inside the exported model).
SCALED_MODELS = frozenset({"linear", "ridge", "lasso", "svr"})

# Upper bounds on the leaves of one fitted tree model, summed over its trees. They keep the ONNX bundle small:
# about 80 bytes per leaf, so at most 80 B × (16384 + 45 × 2048) ≈ 8.7 MB per marker set even if every task
# chose a full-budget forest. The global depth model, being only one and fit on every row, gets more.
LEAF_BUDGET_DEPTH = 16384
LEAF_BUDGET_ANGLE = 2048

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


@dataclass(frozen=True)
class ModelScore:
    """The best of one model type's hyperparameter draws on one task, scored on the task's test split.

    Attributes:
        model: The model type, one of MODEL_NAMES.
        params: The hyperparameters of the best draw, as passed to make_regressor (JSON-able).
        mse: Test mean squared error (m² for depth, deg² for yaw); inf if the model failed.
        r2: Test coefficient of determination (NaN when undefined, e.g. a constant test target).
        fit_seconds: Wall time of that draw's fit.
        n_fit: Rows the model was fit on (fewer than the training split for SVR on large tasks).
        trials: Draws tried.
    """

    model: str
    params: dict[str, Any]
    mse: float
    r2: float
    fit_seconds: float
    n_fit: int
    trials: int


@dataclass(frozen=True)
class TaskResult:
    """One training task's outcome: the global depth model or one segment's angle model of one set.

    Attributes:
        set_name: The TrainingSet's name.
        target: "depth" (metres) or "yaw_deg" (degrees).
        segment: The segment index for angle models, None for the depth model.
        n_own: Rows of the segment itself (all rows for depth).
        borrowed: (first, last) segment of the window whose rows were used, inclusive, when the segment had to
            borrow from its neighbours; else None.
        sources: The segments that actually contributed rows (empty for the depth model, which uses every row).
        n_rows: Rows used after borrowing (the paper's N).
        n_train: Rows of the training split.
        n_test: Rows of the test split.
        scores: Every tried model type's best draw, in the configuration's order.
        chosen: The model type with the lowest test MSE; None when there is no model.
        estimator: The chosen fitted scikit-learn estimator (None when there is no model).
        test_rows: Row indices (into the TrainingSet) of the test split.
        y_test: Targets of the test split.
        y_pred: The chosen model's predictions on the test split.
        reason: Why there is no model (None when there is one).
    """

    set_name: str
    target: str
    segment: int | None
    n_own: int
    borrowed: tuple[int, int] | None
    sources: tuple[int, ...]
    n_rows: int
    n_train: int
    n_test: int
    scores: Mapping[str, ModelScore]
    chosen: str | None
    estimator: Any
    test_rows: NDArray[np.int64]
    y_test: NDArray[np.float64]
    y_pred: NDArray[np.float64]
    reason: str | None = None

    @property
    def best(self) -> ModelScore | None:
        """The chosen model's score, or None."""
        return None if self.chosen is None else self.scores[self.chosen]


@dataclass(frozen=True)
class SetResult:
    """The models of one marker set: one depth model and one angle task per segment (some without a model)."""

    name: str
    feature_names: tuple[str, ...]
    n_rows: int
    depth: TaskResult
    angle: tuple[TaskResult, ...]


@dataclass(frozen=True)
class TrainingResult:
    """Everything training produced: per set the chosen models, every model's scores, and the test splits.

    Attributes:
        config: The configuration used.
        sets: One SetResult per TrainingSet, in input order.
        seconds: Wall time of the whole training.
        n_fits: Model fits run (tasks × models × draws).
        fit_seconds: Sum of the wall times of all fits.
        fit_cpu_seconds: Sum of the CPU times of all fits (what the search costs, whatever else the machine runs).
        jobs: Worker processes used.
    """

    config: TrainConfig
    sets: tuple[SetResult, ...]
    seconds: float
    n_fits: int
    fit_seconds: float
    fit_cpu_seconds: float
    jobs: int

    def set(self, name: str) -> SetResult:
        """The result of the set called ``name``."""
        for s in self.sets:
            if s.name == name:
                return s
        raise KeyError(name)


# ---------------------------------------------------------------------------------------------------------------
# Model zoo and search spaces


class _LogUniform:
    """A log-uniform distribution over [lo, hi] for ParameterSampler (anything with ``rvs`` will do)."""

    def __init__(self, lo: float, hi: float) -> None:
        self.lo, self.hi = lo, hi

    def rvs(self, random_state: np.random.RandomState) -> float:
        return float(math.exp(random_state.uniform(math.log(self.lo), math.log(self.hi))))

    def __repr__(self) -> str:
        return f"log-uniform {self.lo:g}–{self.hi:g}"


class _Uniform(_LogUniform):
    """A uniform distribution over [lo, hi]."""

    def rvs(self, random_state: np.random.RandomState) -> float:
        return float(random_state.uniform(self.lo, self.hi))

    def __repr__(self) -> str:
        return f"uniform {self.lo:g}–{self.hi:g}"


class _IntUniform:
    """Integers lo..hi (inclusive), each equally likely."""

    def __init__(self, lo: int, hi: int) -> None:
        self.lo, self.hi = lo, hi

    def rvs(self, random_state: np.random.RandomState) -> int:
        return int(random_state.randint(self.lo, self.hi + 1))

    def __repr__(self) -> str:
        return f"integers {self.lo}–{self.hi}"


# Raw search spaces; _resolve turns a draw into estimator parameters. SVR's C and epsilon and Lasso's alpha are
# drawn relative to the target's standard deviation, SVR's gamma relative to 1/n_features (inputs are
# standardised), so one space suits depth in metres and yaw in degrees alike.
_SPACES: dict[str, dict[str, Any]] = {
    "linear": {},
    "ridge": {"alpha": _LogUniform(1e-4, 1e3)},
    "lasso": {"alpha_rel": _LogUniform(1e-4, 1e-1)},
    "decision_tree": {
        "max_depth": _IntUniform(4, 16),
        "min_samples_leaf": _IntUniform(1, 20),
        "max_features": [1.0, 0.7],
    },
    "random_forest": {
        "n_estimators": _IntUniform(20, 100),
        "max_depth": _IntUniform(4, 16),
        "min_samples_leaf": _IntUniform(1, 10),
        "max_features": [0.33, 0.5, 1.0],
    },
    "svr": {
        "C_rel": _LogUniform(0.1, 100.0),
        "gamma_rel": _LogUniform(0.05, 5.0),
        "epsilon_rel": _LogUniform(1e-3, 0.1),
    },
    "gradient_boosting": {
        "n_estimators": _IntUniform(30, 150),
        "learning_rate": _LogUniform(0.03, 0.3),
        "max_depth": _IntUniform(2, 4),
        "min_samples_leaf": _IntUniform(1, 20),
        "subsample": _Uniform(0.5, 0.9),
        "max_features": [0.5, 1.0],
    },
}

_SPACE_NOTES = {
    "linear": "ordinary least squares (no hyperparameters; one fit)",
    "lasso": "alpha = alpha_rel × std(target); random coordinate order, at most 5000 passes",
    "decision_tree": "leaves ≤ budget",
    "random_forest": "max_leaf_nodes = budget // n_estimators (total leaves ≤ budget)",
    "svr": "RBF kernel; C = C_rel × std(target), gamma = gamma_rel / n_features, epsilon = epsilon_rel × std(target)",
    "gradient_boosting": "squared error; max_leaf_nodes = min(2^max_depth, budget // n_estimators)",
}


def describe_search_space(model: str) -> str:
    """A one-line description of a model type's hyperparameter search space, for reports."""
    space = _SPACES[model]
    parts = [f"{k}: {v!r}" if not isinstance(v, list) else f"{k}: one of {v}" for k, v in sorted(space.items())]
    scaled = "standardised inputs" if model in SCALED_MODELS else "raw inputs"
    extra = _SPACE_NOTES.get(model)
    return "; ".join([scaled, *parts, *([extra] if extra else [])])


def _plain(v: Any) -> Any:
    """A parameter value as a plain JSON-able Python value."""
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    return v


def _resolve(model: str, raw: Mapping[str, Any], *, y_std: float, n_features: int, leaf_budget: int) -> dict[str, Any]:
    """Estimator parameters from one raw draw, given the task's target spread, width and leaf budget."""
    p = {k: _plain(v) for k, v in raw.items()}
    scale = y_std if y_std > 0 else 1.0
    if model == "lasso":
        return {"alpha": p["alpha_rel"] * scale}
    if model == "svr":
        return {"C": p["C_rel"] * scale, "gamma": p["gamma_rel"] / n_features, "epsilon": p["epsilon_rel"] * scale}
    if model == "decision_tree":
        return {**p, "max_leaf_nodes": leaf_budget}
    if model == "random_forest":
        return {**p, "max_leaf_nodes": max(8, leaf_budget // int(p["n_estimators"]))}
    if model == "gradient_boosting":
        leaves = min(2 ** int(p["max_depth"]), max(4, leaf_budget // int(p["n_estimators"])))
        return {**p, "max_leaf_nodes": leaves}
    return p


def make_regressor(model: str, params: Mapping[str, Any], random_state: int = 0) -> Any:
    """An unfitted scikit-learn estimator of one model type with the given hyperparameters.

    Linear, ridge, lasso and SVR are Pipelines with a StandardScaler first; tree models see raw inputs.

    Args:
        model: One of MODEL_NAMES.
        params: Hyperparameters of the final estimator (as in ModelScore.params).
        random_state: Seed of the randomised models (trees, forest, boosting).

    Returns:
        The estimator.
    """
    from sklearn.ensemble import GradientBoostingRegressor, RandomForestRegressor
    from sklearn.linear_model import Lasso, LinearRegression, Ridge
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVR
    from sklearn.tree import DecisionTreeRegressor

    p = dict(params)
    if model == "linear":
        inner: Any = LinearRegression(**p)
    elif model == "ridge":
        inner = Ridge(**p)
    elif model == "lasso":
        inner = Lasso(max_iter=5000, selection="random", random_state=random_state, **p)
    elif model == "svr":
        inner = SVR(kernel="rbf", cache_size=500, **p)
    elif model == "decision_tree":
        return DecisionTreeRegressor(random_state=random_state, **p)
    elif model == "random_forest":
        return RandomForestRegressor(random_state=random_state, n_jobs=1, **p)
    elif model == "gradient_boosting":
        return GradientBoostingRegressor(random_state=random_state, **p)
    else:
        raise ConfigError(f"unknown model type {model}; choose from {', '.join(MODEL_NAMES)}")
    return Pipeline([("scale", StandardScaler()), ("model", inner)])


# ---------------------------------------------------------------------------------------------------------------
# Tasks


def _seed(*parts: int | str) -> int:
    """A 32-bit seed that depends only on ``parts`` (strings hashed with CRC-32, stable across runs)."""
    words = [zlib.crc32(p.encode("utf-8")) if isinstance(p, str) else int(p) for p in parts]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint32)[0])


@dataclass(frozen=True)
class _Task:
    """One (set, target, segment) problem with its rows and split, before any fit."""

    set_index: int
    set_name: str
    target: str
    segment: int | None
    n_own: int
    borrowed: tuple[int, int] | None
    sources: tuple[int, ...]
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
) -> _Task:
    """The task of the depth model (``segment`` None) or of one segment's angle model, split 80/20."""
    from sklearn.model_selection import train_test_split

    target = "depth" if segment is None else "yaw_deg"
    key_seed = _seed(config.seed, s.name, target, "all" if segment is None else segment)
    empty = np.zeros(0, dtype=np.int64)
    task = _Task(
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
        pick = np.random.default_rng(_seed(key_seed, "svr")).choice(len(train_rows), config.svr_max_rows, replace=False)
        svr_rows = train_rows[np.sort(pick)]
    y = s.depth if segment is None else s.yaw_deg
    return replace(
        task,
        train_rows=train_rows,
        test_rows=np.sort(np.asarray(test_rows, dtype=np.int64)),
        svr_rows=svr_rows,
        y_std=float(np.std(y[train_rows])),
    )


def _tasks(sets: Sequence[TrainingSet], config: TrainConfig) -> list[_Task]:
    tasks: list[_Task] = []
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


# ---------------------------------------------------------------------------------------------------------------
# Fitting


@dataclass(frozen=True)
class _Draw:
    """One hyperparameter draw of one model type."""

    model: str
    trial: int
    params: dict[str, Any]
    random_state: int


@dataclass(frozen=True)
class _Batch:
    """Every draw of every model type on one task: the unit of work a worker gets."""

    task: int
    draws: tuple[_Draw, ...]
    models: tuple[str, ...]
    cost: float


@dataclass(frozen=True)
class _Score:
    """How one draw did on its task's test split."""

    model: str
    trial: int
    mse: float
    r2: float
    fit_seconds: float
    cpu_seconds: float
    n_fit: int


@dataclass(frozen=True)
class _TaskOutcome:
    """A task's draws' scores and its best draw's fitted estimator and test predictions."""

    task: int
    scores: tuple[_Score, ...]
    best: _Score
    estimator: Any
    y_pred: NDArray[np.float64]
    rescored: bool = False  # the lean scores disagreed with scikit-learn: scored again by scikit-learn alone


# Rough relative cost per training row, to start the slow tasks first (it only affects scheduling).
_COST = {
    "linear": 0.01,
    "ridge": 0.01,
    "lasso": 0.05,
    "decision_tree": 0.1,
    "random_forest": 3.0,
    "svr": 2.0,
    "gradient_boosting": 3.0,
}


def _batches(tasks: Sequence[_Task], config: TrainConfig, n_features: Sequence[int]) -> list[_Batch]:
    from sklearn.model_selection import ParameterSampler

    batches: list[_Batch] = []
    for t_index, t in enumerate(tasks):
        if t.reason is not None:
            continue
        draws: list[_Draw] = []
        cost = 0.0
        for model in config.models:
            space = _SPACES[model]
            n_iter = config.trials if space else 1
            sampler = ParameterSampler(space, n_iter=n_iter, random_state=_seed(config.seed, t.key, model) % (2**31))
            raws = list(sampler) if space else [{}]
            n_fit = len(t.svr_rows) if model == "svr" else len(t.train_rows)
            cost += len(raws) * _COST[model] * n_fit * (n_fit / 1000.0 if model == "svr" else 1.0)
            for trial, raw in enumerate(raws):
                params = _resolve(
                    model, raw, y_std=t.y_std, n_features=n_features[t.set_index], leaf_budget=t.leaf_budget
                )
                draws.append(_Draw(model, trial, params, _seed(config.seed, t.key, model, trial)))
        batches.append(_Batch(t_index, tuple(draws), tuple(config.models), cost))
    return batches


def _rank(s: _Score, models: Sequence[str]) -> tuple[float, int, int]:
    """Lowest MSE first; ties go to the earlier model type and draw, so the order of the fits never matters."""
    mse = s.mse if math.isfinite(s.mse) else math.inf
    return mse, models.index(s.model), s.trial


def _fit_task(
    batch: _Batch,
    X_train: NDArray[np.float64],
    y_train: NDArray[np.float64],
    X_svr: NDArray[np.float64],
    y_svr: NDArray[np.float64],
    X_test: NDArray[np.float64],
    y_test: NDArray[np.float64],
    *,
    lean: bool = True,
) -> _TaskOutcome:
    """Fit every draw of one task and score each on the test split (runs in a worker process).

    Forest and boosting draws are scored through ``learning.treefit`` (the same predictions for less). The best
    of those lean draws is then fitted by scikit-learn itself, whether or not it wins the task, and when its
    predictions are not the lean ones bit for bit, the whole task is scored again with scikit-learn alone
    (``lean=False``). Only the best draw's estimator comes back: the others would cost their pickling and the
    parent's memory.
    """
    import sklearn
    from sklearn.exceptions import ConvergenceWarning, UndefinedMetricWarning
    from sklearn.metrics import mean_squared_error, r2_score

    scores: list[_Score] = []
    best: tuple[_Score, _Draw, Any, NDArray[np.float64]] | None = None
    best_lean: tuple[_Score, _Draw, Any, NDArray[np.float64]] | None = None
    # One BLAS thread: the workers already fill the cores, and a fixed thread count keeps results bit-identical.
    # The parameters are checked by TrainConfig and the draws, the rows are finite (TrainingSet), and every
    # prediction is checked below: scikit-learn's own checks of each fit (a third of a boosting fit's time on
    # a 5 cm segment's rows) and of each score only repeat that.
    with (
        threadpool_limits(limits=1),
        warnings.catch_warnings(),
        sklearn.config_context(skip_parameter_validation=True, assume_finite=True),
    ):
        warnings.simplefilter("ignore", ConvergenceWarning)
        warnings.simplefilter("ignore", UndefinedMetricWarning)
        for draw in batch.draws:
            X, y = (X_svr, y_svr) if draw.model == "svr" else (X_train, y_train)
            t0, c0 = time.perf_counter(), time.process_time()
            est: Any = None
            found = lean_predict(draw.model, draw.params, draw.random_state, X, y, X_test) if lean else None
            if found is None:
                est = make_regressor(draw.model, draw.params, draw.random_state)
                est.fit(X, y)
            seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
            pred = found if found is not None else np.asarray(est.predict(X_test), dtype=np.float64)
            if np.all(np.isfinite(pred)):
                mse = float(mean_squared_error(y_test, pred))
                r2 = float(r2_score(y_test, pred)) if len(y_test) >= 2 else math.nan
            else:
                mse, r2 = math.inf, math.nan
            score = _Score(draw.model, draw.trial, mse, r2, seconds, cpu, len(y))
            scores.append(score)
            if best is None or _rank(score, batch.models) < _rank(best[0], batch.models):
                best = (score, draw, est, pred)
            if found is not None and (
                best_lean is None or _rank(score, batch.models) < _rank(best_lean[0], batch.models)
            ):
                best_lean = (score, draw, est, pred)
        assert best is not None  # a batch has at least one draw
        if best_lean is not None:  # scikit-learn's own estimator of the best lean draw must predict the same
            _, draw, _, pred = best_lean
            check = make_regressor(draw.model, draw.params, draw.random_state).fit(X_train, y_train)
            if not np.array_equal(np.asarray(check.predict(X_test), dtype=np.float64), pred):
                again = _fit_task(batch, X_train, y_train, X_svr, y_svr, X_test, y_test, lean=False)
                return replace(again, rescored=True)
            if best[0] is best_lean[0]:
                best = (best[0], draw, check, pred)
    return _TaskOutcome(batch.task, tuple(scores), best[0], best[2], best[3])


def _worker_count(jobs: int) -> int:
    if jobs > 0:
        return jobs
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def _run(
    batches: Sequence[_Batch],
    tasks: Sequence[_Task],
    data: Sequence[tuple[NDArray[np.float64], TrainingSet]],
    n_workers: int,
    progress: bool,
) -> Generator[_TaskOutcome, None, None]:

    def args(batch: _Batch) -> tuple[Any, ...]:
        t = tasks[batch.task]
        X32, s = data[t.set_index]
        y = s.depth if t.target == "depth" else s.yaw_deg
        X_train, y_train = X32[t.train_rows], y[t.train_rows]
        # The same arrays when SVR sees every training row: pickled once.
        X_svr, y_svr = (X_train, y_train) if t.svr_rows is t.train_rows else (X32[t.svr_rows], y[t.svr_rows])
        return batch, X_train, y_train, X_svr, y_svr, X32[t.test_rows], y[t.test_rows]

    order = sorted(batches, key=lambda b: -b.cost)
    with tqdm(
        total=sum(len(b.draws) for b in order),
        desc="training",
        unit="fit",
        file=sys.stderr,
        disable=None if progress else True,
    ) as bar:
        client = active_client()
        if n_workers == 1 and client is None:
            for batch in order:
                yield _fit_task(*args(batch))
                bar.update(len(batch.draws))
            return
        # --cluster (core.cluster): every task a task of the Dask cluster, through joblib's dask backend.
        where = parallel_config("loky", n_jobs=n_workers) if client is None else parallel_config("dask", client=client)
        # One task per call, its rows sent with it (a few hundred kB at most). max_nbytes=None: they go pickled,
        # not through temp memory-mapped folders, whose tracker would print a "leaked folder" warning after the
        # parent when the workers are killed mid-fit. batch_size=1: the tasks are few, long and sorted by cost.
        with where:
            parallel = Parallel(return_as="generator_unordered", max_nbytes=None, batch_size=1)
        # The loky workers start here (and take the blocked SIGINT: a Ctrl-C is the parent's to handle).
        with sigint_blocked():
            outputs = parallel(delayed(_fit_task)(*args(batch)) for batch in order)
        try:
            for out in outputs:
                yield out
                bar.update(len(out.scores))
        finally:
            # Stopped early (Ctrl-C, SIGTERM, an error here or in the caller): joblib kills the workers
            # (executor shutdown with kill_workers) instead of waiting for their fits; its warning that
            # results went unused says nothing to the user.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                outputs.close()


def _model_scores(out: _TaskOutcome | None, draws: _Batch | None, models: Sequence[str]) -> dict[str, ModelScore]:
    """Every tried model type's best draw on one task, in the configuration's order."""
    if out is None or draws is None:
        return {}
    params = {(d.model, d.trial): d.params for d in draws.draws}
    scores: dict[str, ModelScore] = {}
    for model in models:
        tried = [s for s in out.scores if s.model == model]
        if not tried:
            continue
        b = min(tried, key=lambda s: _rank(s, models))
        scores[model] = ModelScore(model, params[(model, b.trial)], b.mse, b.r2, b.fit_seconds, b.n_fit, len(tried))
    return scores


def train(sets: Sequence[TrainingSet], config: TrainConfig, *, progress: bool = True) -> TrainingResult:
    """Train every set's depth model and per-segment angle models and choose the best model type of each.

    Args:
        sets: The training rows, one TrainingSet per marker set (names unique).
        config: Search effort, split, seed, borrowing rules, model types and workers.
        progress: Show a progress bar over completed fits on stderr.

    Returns:
        The chosen fitted models with every model type's best test scores and the test splits.

    Raises:
        InputError: No sets, duplicate set names, or a set with fewer than ``config.min_rows`` rows.
    """
    t0 = time.perf_counter()
    if not sets:
        raise InputError("no training sets given")
    names = [s.name for s in sets]
    if len(set(names)) != len(names):
        raise InputError(f"training set names must be unique, got {', '.join(names)}")
    tasks = _tasks(sets, config)
    # float32 values (held as float64): what the ONNX models will see, so trees split on the same numbers.
    data = [(s.X.astype(np.float32).astype(np.float64), s) for s in sets]
    batches = _batches(tasks, config, [len(s.feature_names) for s in sets])
    n_fits = sum(len(b.draws) for b in batches)
    n_workers = min(_worker_count(config.jobs), max(1, len(batches)))

    outcomes: dict[int, _TaskOutcome] = {}
    # closing: an exception in this loop stops the workers now, not when the generator is collected.
    with closing(_run(batches, tasks, data, n_workers, progress)) as outputs:
        for done in outputs:
            outcomes[done.task] = done
    rescored = sum(o.rescored for o in outcomes.values())
    if rescored:  # costs time, never correctness: say so, or a broken lean path would go unseen
        import sklearn

        logging.getLogger("monodock").warning(
            f"{rescored} of {len(outcomes)} training tasks were scored twice: learning.treefit's lean trees did not "
            f"predict what scikit-learn {sklearn.__version__} does, so scikit-learn alone scored them (same models, "
            "more time)"
        )
    fit_seconds = sum(s.fit_seconds for o in outcomes.values() for s in o.scores)
    cpu_seconds = sum(s.cpu_seconds for o in outcomes.values() for s in o.scores)

    batch_of = {b.task: b for b in batches}
    results: list[TaskResult] = []
    for t_index, t in enumerate(tasks):
        s = sets[t.set_index]
        y = s.depth if t.target == "depth" else s.yaw_deg
        out = outcomes.get(t_index)
        reason = t.reason
        if out is not None and not math.isfinite(out.best.mse):
            reason = "every model failed (non-finite predictions)"
        chosen = out if out is not None and reason is None else None
        results.append(
            TaskResult(
                set_name=t.set_name,
                target=t.target,
                segment=t.segment,
                n_own=t.n_own,
                borrowed=t.borrowed,
                sources=t.sources,
                n_rows=len(t.rows),
                n_train=len(t.train_rows),
                n_test=len(t.test_rows),
                scores=_model_scores(out, batch_of.get(t_index), config.models),
                chosen=None if chosen is None else chosen.best.model,
                estimator=None if chosen is None else chosen.estimator,
                test_rows=t.test_rows,
                y_test=y[t.test_rows].astype(np.float64),
                y_pred=np.zeros(0) if chosen is None else chosen.y_pred,
                reason=reason,
            )
        )

    set_results = []
    per_set = 1 + config.segments.count
    for i, s in enumerate(sets):
        block = results[i * per_set : (i + 1) * per_set]
        set_results.append(SetResult(s.name, tuple(s.feature_names), len(s.depth), block[0], tuple(block[1:])))
    return TrainingResult(
        config, tuple(set_results), time.perf_counter() - t0, n_fits, fit_seconds, cpu_seconds, n_workers
    )
