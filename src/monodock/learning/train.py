"""Training the regression models of the papers: seven regressors, 80/20 split, the lowest test MSE wins.

For each marker set (e.g. all three markers seen, or marker 2 alone) this trains one global depth model on all
rows, and one angle (yaw) model per 5 cm depth segment over 25-250 cm (Sensors 2025, §4.2). A segment with
too few rows borrows the rows of its neighbours (k±1, then k±2, ...). Every (set, target, segment) task tries
each of the seven model types with up to ``trials`` random hyperparameter draws; each draw is fit on the 80 %
split and scored on the 20 % split; the model type whose best draw has the lowest test MSE is kept.

All fits run in parallel (joblib, loky processes), each with its own seed derived from the configuration's seed
and the task, so results do not depend on the number of workers. Features are rounded to float32 before
fitting: the exported ONNX models take float32 input, and trees then split on the very numbers they will see.

The model types and their search spaces are in ``learning.regressors``, the sets, configuration and tasks in
``learning.tasks``; those of their names in this module's ``__all__`` are importable from here too.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import warnings
from collections.abc import Generator, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from joblib import Parallel, delayed, parallel_config
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from monodock.compute import active_client
from monodock.core.interrupt import sigint_blocked
from monodock.errors import InputError
from monodock.learning.regressors import SEARCH_SPACES, make_regressor, resolve_draw
from monodock.learning.tasks import Task, TaskIdentity, TrainConfig, TrainingSet, make_tasks, stable_seed
from monodock.learning.treefit import lean_predict

__all__ = [
    "ModelScore",
    "SetResult",
    "TaskResult",
    "TrainingResult",
    "train",
]


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
class TaskResult(TaskIdentity):
    """One training task's outcome: the global depth model or one segment's angle model of one set.

    Its TaskIdentity fields are its task's.

    Attributes:
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


def _batches(tasks: Sequence[Task], config: TrainConfig, n_features: Sequence[int]) -> list[_Batch]:
    from sklearn.model_selection import ParameterSampler

    batches: list[_Batch] = []
    for t_index, t in enumerate(tasks):
        if t.reason is not None:
            continue
        draws: list[_Draw] = []
        cost = 0.0
        for model in config.models:
            space = SEARCH_SPACES[model]
            n_iter = config.trials if space else 1
            sampler = ParameterSampler(
                space, n_iter=n_iter, random_state=stable_seed(config.seed, t.key, model) % (2**31)
            )
            raws = list(sampler) if space else [{}]
            n_fit = len(t.svr_rows) if model == "svr" else len(t.train_rows)
            cost += len(raws) * _COST[model] * n_fit * (n_fit / 1000.0 if model == "svr" else 1.0)
            for trial, raw in enumerate(raws):
                params = resolve_draw(
                    model, raw, y_std=t.y_std, n_features=n_features[t.set_index], leaf_budget=t.leaf_budget
                )
                draws.append(_Draw(model, trial, params, stable_seed(config.seed, t.key, model, trial)))
        batches.append(_Batch(t_index, tuple(draws), tuple(config.models), cost))
    return batches


def _rank(s: _Score, models: Sequence[str]) -> tuple[float, int, int]:
    """Lowest MSE first; ties go to the earlier model type and draw, so the order of the fits never matters."""
    mse = s.mse if math.isfinite(s.mse) else math.inf
    return mse, models.index(s.model), s.trial


# (X, y) of some of a task's rows: its training split, SVR's (a subsample of that on large tasks) or its test split.
_Rows = tuple[NDArray[np.float64], NDArray[np.float64]]


def _fit_task(batch: _Batch, train: _Rows, svr: _Rows, test: _Rows, *, lean: bool = True) -> _TaskOutcome:
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

    (X_train, y_train), (X_test, y_test) = train, test
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
            X, y = svr if draw.model == "svr" else train
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
                again = _fit_task(batch, train, svr, test, lean=False)
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
    tasks: Sequence[Task],
    data: Sequence[tuple[NDArray[np.float64], TrainingSet]],
    n_workers: int,
    progress: bool,
) -> Generator[_TaskOutcome, None, None]:

    def args(batch: _Batch) -> tuple[_Batch, _Rows, _Rows, _Rows]:
        t = tasks[batch.task]
        X32, s = data[t.set_index]
        y = s.depth if t.target == "depth" else s.yaw_deg
        train = X32[t.train_rows], y[t.train_rows]
        # The same arrays when SVR sees every training row: pickled once.
        svr = train if t.svr_rows is t.train_rows else (X32[t.svr_rows], y[t.svr_rows])
        return batch, train, svr, (X32[t.test_rows], y[t.test_rows])

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
        # --cluster (compute.cluster): every task a task of the Dask cluster, through joblib's dask backend.
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
    tasks = make_tasks(sets, config)
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
