"""The lean forest and boosting fits (learning.treefit) predict exactly what scikit-learn's estimators predict, and
the model selection gives the same result with them as without, even when they are wrong."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pytest

from monodock.learning import train as train_module
from monodock.learning.regressors import make_regressor
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import TrainingResult, train
from monodock.learning.treefit import LEAN_MODELS, lean_predict
from shared import synthetic_set


def _draw(rng: np.random.Generator, model: str) -> dict[str, Any]:
    """Parameters as the selection draws them (learning.train's search spaces and leaf budgets)."""
    trees = int(rng.integers(20, 61))
    p: dict[str, Any] = {
        "n_estimators": trees,
        "max_depth": int(rng.integers(2, 17)),
        "min_samples_leaf": int(rng.integers(1, 21)),
        "max_features": float(rng.choice([0.33, 0.5, 0.7, 1.0])),
        "max_leaf_nodes": max(4, int(rng.choice([2048, 16384])) // trees),
    }
    if model == "gradient_boosting":
        p["learning_rate"] = float(rng.uniform(0.03, 0.3))
        p["subsample"] = float(rng.choice([1.0, rng.uniform(0.5, 0.9)]))
    return p


@pytest.mark.parametrize("model", LEAN_MODELS)
@pytest.mark.parametrize("case", range(6))
def test_lean_predictions_are_scikit_learns_bit_for_bit(model: str, case: int) -> None:
    import sklearn

    rng = np.random.default_rng([case, LEAN_MODELS.index(model)])
    n, f = int(rng.integers(12, 400)), int(rng.choice([4, 17, 43]))
    # float32 values, as the selection hands them over; ties among them (a rounded feature) included.
    X = rng.normal(size=(n, f)).astype(np.float32).astype(np.float64)
    X[:, -1] = np.round(X[:, -1])
    y = 3.0 * X[:, 0] + np.sin(X[:, 1]) + rng.normal(0.0, 0.3, n)
    X_test = rng.normal(size=(37, f)).astype(np.float32).astype(np.float64)
    params, seed = _draw(rng, model), int(rng.integers(0, 2**31))
    lean = lean_predict(model, params, seed, X, y, X_test)
    with sklearn.config_context(skip_parameter_validation=True, assume_finite=True):
        reference = make_regressor(model, params, seed).fit(X, y).predict(X_test)
    assert lean is not None
    np.testing.assert_array_equal(lean, reference)


def test_other_models_and_parameters_are_left_to_scikit_learn() -> None:
    X, y = np.zeros((20, 3)), np.arange(20.0)
    assert lean_predict("svr", {"C": 1.0}, 0, X, y, X) is None
    assert lean_predict("random_forest", {"n_estimators": 10, "bootstrap": False}, 0, X, y, X) is None
    drawn = {"n_estimators": 10, "max_depth": 4, "min_samples_leaf": 1, "max_features": 0.5, "max_leaf_nodes": 8}
    assert lean_predict("random_forest", drawn, 0, X, y, X) is not None
    assert lean_predict("random_forest", {**drawn, "max_features": 2}, 0, X, y, X) is None  # not as drawn
    assert lean_predict("random_forest", {k: v for k, v in drawn.items() if k != "max_leaf_nodes"}, 0, X, y, X) is None


def _scikit_learn_only(*_: Any) -> None:
    return None


def _same(a: TrainingResult, b: TrainingResult) -> None:
    for sa, sb in zip(a.sets, b.sets, strict=True):
        for ta, tb in zip((sa.depth, *sa.angle), (sb.depth, *sb.angle), strict=True):
            assert ta.chosen == tb.chosen
            assert (ta.estimator is None) == (ta.chosen is None) == (tb.estimator is None)
            assert type(ta.estimator) is type(tb.estimator)
            assert {m: (s.mse, s.r2, s.params) for m, s in ta.scores.items()} == {
                m: (s.mse, s.r2, s.params) for m, s in tb.scores.items()
            }
            np.testing.assert_array_equal(ta.y_pred, tb.y_pred)


# Two draws of the lean types beside two model types that are always scikit-learn's, so that either may win a task.
_CONFIG = TrainConfig(trials=2, seed=5, jobs=1, models=("linear", "svr", "random_forest", "gradient_boosting"))


@pytest.fixture(scope="module")
def data_and_plain() -> tuple[TrainingSet, TrainingResult]:
    """The synthetic rows, and their selection by scikit-learn alone (no lean fit)."""
    data = synthetic_set(3)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(train_module, "lean_predict", _scikit_learn_only)
        return data, train([data], _CONFIG, progress=False)


def test_the_selection_is_the_same_with_and_without_the_lean_fits(
    data_and_plain: tuple[TrainingSet, TrainingResult],
) -> None:
    data, plain = data_and_plain
    used: list[str] = []

    def counted(model: str, *args: Any) -> Any:
        out = lean_predict(model, *args)
        if out is not None:
            used.append(model)
        return out

    with pytest.MonkeyPatch.context() as m:
        m.setattr(train_module, "lean_predict", counted)
        lean = train([data], _CONFIG, progress=False)
    _same(lean, plain)
    # Every forest and boosting draw of the selection took the lean path (its draws are what treefit takes).
    draws = sum(
        s.trials for t in (lean.sets[0].depth, *lean.sets[0].angle) for m, s in t.scores.items() if m in LEAN_MODELS
    )
    assert len(used) == draws > 0
    chosen = [t.chosen for t in (lean.sets[0].depth, *lean.sets[0].angle) if t.chosen is not None]
    assert set(chosen) & set(LEAN_MODELS)  # the lean fits chose some tasks' models: the check above saw them


def test_a_lean_fit_that_disagrees_with_scikit_learn_is_caught_and_the_task_scored_again(
    data_and_plain: tuple[TrainingSet, TrainingResult],
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Were a scikit-learn release to grow its trees otherwise, the refit of a task's best lean draw would disagree
    with its lean score, and the task would be scored again by scikit-learn: the result is scikit-learn's alone,
    and one warning says how many tasks it took (a broken lean path costs time, and is seen)."""
    data, plain = data_and_plain

    def off_by_a_little(*args: Any) -> Any:
        out = lean_predict(*args)
        return None if out is None else out * 0.999  # slightly better or worse: the ranking may change too

    monkeypatch.setattr(train_module, "lean_predict", off_by_a_little)
    with caplog.at_level(logging.WARNING, logger="monodock"):
        _same(train([data], _CONFIG, progress=False), plain)
    lines = [r.getMessage() for r in caplog.records if r.name == "monodock"]
    assert len(lines) == 1, lines
    fitted = sum(t.reason is None for t in (plain.sets[0].depth, *plain.sets[0].angle))
    assert lines[0].startswith(f"{fitted} of {fitted} training tasks were scored twice"), lines  # each has trees
