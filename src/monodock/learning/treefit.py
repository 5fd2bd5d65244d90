"""Test-split predictions of random-forest and gradient-boosting draws, bit-identical to scikit-learn's, for less.

The model selection fits ~1,800 forest and boosting draws, most on 5 cm segments of 40-200 rows. There
scikit-learn spends about as long around each tree as growing it (cloning the forest's template tree through
``inspect.signature``, checking the sample weights, a fresh random state, joblib's dispatch). Here the same trees
grow in scikit-learn's own Cython classes (the criterion, splitter, builder and tree that
``DecisionTreeRegressor._fit`` builds) from the same random states in the same order, and the predictions are
summed by scikit-learn's own code (``predict_stages`` for boosting; the forest's in-order mean), so every score
is the one scikit-learn's estimator would give: ~1.5x faster on those draws, ``monodock train`` 101.5 s -> 79.4 s
on a 3,000-row drive (docs/benchmarks.md).

Only scores come from here. In every task the best lean draw is fitted again by scikit-learn itself
(``learning.train``), and its test predictions must equal these bit for bit, or the task is scored again with
scikit-learn alone. The equivalence holds for the pinned scikit-learn (``requirements/lock.txt``); a release
that breaks it costs time, not correctness, and fails ``tests/learning/test_treefit.py``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["LEAN_MODELS", "lean_predict"]

LEAN_MODELS = ("random_forest", "gradient_boosting")

# The hyperparameters the lean fits understand, as the selection draws them (learning.regressors.resolve_draw: a
# float max_features, max_leaf_nodes always set); a draw with any other falls back to scikit-learn.
_FOREST_KEYS = frozenset({"n_estimators", "max_depth", "min_samples_leaf", "max_features", "max_leaf_nodes"})
_BOOSTING_KEYS = _FOREST_KEYS | {"learning_rate", "subsample"}
_MAX_INT = np.iinfo(np.int32).max


def lean_predict(
    model: str,
    params: Mapping[str, Any],
    random_state: int,
    X: NDArray[np.float64],
    y: NDArray[np.float64],
    X_test: NDArray[np.float64],
) -> NDArray[np.float64] | None:
    """The test predictions of ``make_regressor(model, params, random_state)`` fitted on (X, y), or None when
    this model or these parameters have no lean fit (then fit the estimator itself).

    X and X_test hold float32 values (the estimators convert to float32 first); rows are finite.
    """
    keys = set(params)
    drawn = "max_leaf_nodes" in keys and isinstance(params.get("max_features"), float)
    if model == "random_forest" and drawn and keys <= _FOREST_KEYS:
        return _forest(params, random_state, X, y, X_test)
    if model == "gradient_boosting" and drawn and keys <= _BOOSTING_KEYS:
        return _boosting(params, random_state, X, y, X_test)
    return None


def _float32(X: NDArray[np.float64], X_test: NDArray[np.float64]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The rows as the estimators see them: C-ordered float32."""
    return np.ascontiguousarray(X, dtype=np.float32), np.ascontiguousarray(X_test, dtype=np.float32)


class _Fitted:
    """What ``predict_stages`` reads of a fitted tree: its ``tree_``."""

    __slots__ = ("tree_",)

    def __init__(self, tree: Any) -> None:
        self.tree_ = tree


def _grow(
    X32: NDArray[np.float32],
    y2: NDArray[np.float64],
    weight: NDArray[np.float64],
    params: Mapping[str, Any],
    rng: np.random.RandomState,
) -> Any:
    """One tree as ``DecisionTreeRegressor(criterion="squared_error", **params)._fit`` grows it (dense rows, one
    output, no missing values, no monotonic constraints, no pruning, a leaf budget: best-first)."""
    from sklearn.tree._criterion import MSE
    from sklearn.tree._splitter import BestSplitter
    from sklearn.tree._tree import BestFirstTreeBuilder, Tree

    n, n_features = X32.shape
    max_depth = params.get("max_depth")
    max_depth = _MAX_INT if max_depth is None else int(max_depth)
    leaf = int(params.get("min_samples_leaf", 1))
    split = max(2, 2 * leaf)
    fraction = float(params["max_features"])
    max_features = max(1, int(fraction * n_features)) if fraction > 0.0 else 0
    splitter = BestSplitter(MSE(1, n), max_features, leaf, 0.0, rng, None)
    tree = Tree(n_features, np.array([1], dtype=np.intp), 1)
    builder = BestFirstTreeBuilder(splitter, split, leaf, 0.0, max_depth, int(params["max_leaf_nodes"]), 0.0)
    builder.build(tree, X32, y2, weight, None)
    return tree


def _forest(
    params: Mapping[str, Any], seed: int, X: NDArray[np.float64], y: NDArray[np.float64], X_test: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``RandomForestRegressor(random_state=seed, n_jobs=1, **params)``: bootstrap, squared error."""
    from sklearn.ensemble._forest import _generate_sample_indices

    X32, T32 = _float32(X, X_test)
    y2 = np.ascontiguousarray(y, dtype=np.float64).reshape(-1, 1)
    n = X32.shape[0]
    rng = np.random.RandomState(seed)
    # _make_estimator -> _set_random_states: one draw per tree, in order, before any tree grows.
    seeds = [rng.randint(_MAX_INT) for _ in range(int(params["n_estimators"]))]
    total = np.zeros(T32.shape[0])
    for s in seeds:
        counts = np.bincount(_generate_sample_indices(s, n, n, None), minlength=n)
        tree = _grow(X32, y2, counts.astype(np.float64), params, np.random.RandomState(s))
        total += tree.predict(T32)[:, 0]
    total /= len(seeds)
    return total


def _boosting(
    params: Mapping[str, Any], seed: int, X: NDArray[np.float64], y: NDArray[np.float64], X_test: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``GradientBoostingRegressor(random_state=seed, **params)``: squared error, mean start, row subsampling."""
    from sklearn._loss.loss import HalfSquaredError
    from sklearn.dummy import DummyRegressor
    from sklearn.ensemble._gb import _init_raw_predictions, _update_terminal_regions
    from sklearn.ensemble._gradient_boosting import _random_sample_mask, predict_stages

    X32, T32 = _float32(X, X_test)
    y = np.asarray(y, dtype=np.float64)
    n = X32.shape[0]
    weight = np.ones(n, dtype=np.float64)
    loss = HalfSquaredError(sample_weight=weight)
    init = DummyRegressor(strategy="mean").fit(X32, y)
    raw = _init_raw_predictions(X32, init, loss, False)
    rng = np.random.RandomState(seed)
    subsample = float(params.get("subsample", 1.0))
    n_inbag = max(1, int(subsample * n))
    mask = np.ones(n, dtype=bool)
    lr = float(params.get("learning_rate", 0.1))
    stages = int(params["n_estimators"])
    trees = np.empty((stages, 1), dtype=object)
    for i in range(stages):
        if subsample < 1.0:
            mask = _random_sample_mask(n, n_inbag, rng)
        neg = -loss.gradient(y_true=y, raw_prediction=raw, sample_weight=None)  # (n,): one tree per stage
        w = weight * mask.astype(np.float64) if subsample < 1.0 else weight
        tree = _grow(X32, neg.reshape(-1, 1), w, params, rng)
        _update_terminal_regions(loss, tree, X32, y, neg, raw, w, mask, learning_rate=lr, k=0)
        trees[i, 0] = _Fitted(tree)
    out = _init_raw_predictions(T32, init, loss, False)
    predict_stages(trees, T32, lr, out)
    return np.asarray(out.ravel(), dtype=np.float64)
