"""The papers' seven candidate regressors and their hyperparameter search spaces.

Each model type is a scikit-learn estimator (make_regressor); linear, ridge, lasso and SVR see standardised
inputs. A search space holds the distributions that ``ParameterSampler`` draws from; resolve_draw turns one draw
into the estimator's parameters for a task (its target's spread, its width and its leaf budget).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from monodock.errors import ConfigError

__all__ = [
    "LEAF_BUDGET_ANGLE",
    "LEAF_BUDGET_DEPTH",
    "MODEL_NAMES",
    "SCALED_MODELS",
    "SEARCH_SPACES",
    "describe_search_space",
    "make_regressor",
    "resolve_draw",
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


# Raw search spaces; resolve_draw turns a draw into estimator parameters. SVR's C and epsilon and Lasso's alpha are
# drawn relative to the target's standard deviation, SVR's gamma relative to 1/n_features (inputs are
# standardised), so one space suits depth in metres and yaw in degrees alike.
SEARCH_SPACES: dict[str, dict[str, Any]] = {
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
    space = SEARCH_SPACES[model]
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


def resolve_draw(
    model: str, raw: Mapping[str, Any], *, y_std: float, n_features: int, leaf_budget: int
) -> dict[str, Any]:
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
