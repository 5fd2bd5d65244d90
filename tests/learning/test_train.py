"""Training the papers' regressors (learning.train) on synthetic rows with a known answer: selection, borrowing,
workers, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from monodock.errors import ConfigError, InputError
from monodock.estimation.segments import SegmentTable
from monodock.learning.regressors import MODEL_NAMES
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import TrainingResult, train
from shared import FEATURES, SET, SPARSE_SEGMENT, as_float32


def test_segment_table_index_and_bounds() -> None:
    seg = SegmentTable()
    assert seg.index(0.25) == 0
    assert seg.index(0.2999) == 0
    assert seg.index(0.30) == 1
    assert seg.index(1.0) == 15
    assert seg.index(2.5) == 44  # the far edge belongs to the last segment
    assert seg.index(2.5001) is None
    assert seg.index(0.2499) is None
    assert seg.index(float("nan")) is None
    assert seg.bounds(0) == pytest.approx((0.25, 0.30))
    assert seg.bounds(44) == pytest.approx((2.45, 2.50))
    assert seg.label(1) == "30–35 cm"


def test_selection_picks_lowest_test_mse_and_reports_it_exactly(data: TrainingSet, result: TrainingResult) -> None:
    from sklearn.metrics import mean_squared_error, r2_score

    s = result.set(SET)
    assert len(s.angle) == 45
    X = as_float32(data.X)
    tasks = [s.depth, *(t for t in s.angle if t.chosen is not None)]
    assert len(tasks) > 5
    for t in tasks:
        assert set(t.scores) == set(MODEL_NAMES)
        assert t.chosen == min(t.scores, key=lambda m: t.scores[m].mse)
        y = data.depth if t.target == "depth" else data.yaw_deg
        np.testing.assert_array_equal(t.y_test, y[t.test_rows])
        assert t.n_test == len(t.test_rows)
        assert t.n_train + t.n_test == t.n_rows
        pred = t.estimator.predict(X[t.test_rows])
        np.testing.assert_allclose(pred, t.y_pred, rtol=0, atol=1e-12)
        assert t.best is not None
        assert mean_squared_error(t.y_test, pred) == pytest.approx(t.best.mse, rel=1e-12)
        assert r2_score(t.y_test, pred) == pytest.approx(t.best.r2, rel=1e-9)
    assert s.depth.best is not None
    assert s.depth.best.r2 > 0.99
    assert s.depth.scores["linear"].trials == 1
    assert s.depth.scores["random_forest"].trials == 2


def test_sparse_segments_borrow_and_far_segments_get_no_model(result: TrainingResult) -> None:
    s = result.set(SET)
    sparse = s.angle[SPARSE_SEGMENT]
    assert sparse.n_own == 10
    assert sparse.borrowed == (SPARSE_SEGMENT - 1, SPARSE_SEGMENT + 1)
    assert sparse.n_rows == 150
    assert sparse.sources == (SPARSE_SEGMENT - 1, SPARSE_SEGMENT, SPARSE_SEGMENT + 1)
    assert sparse.chosen is not None
    full = s.angle[2]
    assert full.borrowed is None
    assert full.n_rows == full.n_own == 70
    # Segment 7 (60-65 cm) has no rows of its own but segment 6 is within reach; segment 11 has none in ±4.
    assert s.angle[7].n_own == 0
    assert s.angle[7].borrowed == (6, 8)
    assert s.angle[7].chosen is not None
    assert s.angle[7].sources == (6,)
    far = s.angle[44]
    assert far.chosen is None
    assert far.estimator is None
    assert far.reason is not None
    assert "0 rows" in far.reason
    assert all(t.chosen is None for t in s.angle[11:])


def test_results_do_not_depend_on_worker_count(data: TrainingSet, result: TrainingResult) -> None:
    other = train([data], TrainConfig(trials=2, jobs=2, seed=3), progress=False)
    assert other.jobs == 2
    for a, b in zip(
        (result.sets[0].depth, *result.sets[0].angle), (other.sets[0].depth, *other.sets[0].angle), strict=True
    ):
        assert a.chosen == b.chosen
        assert a.borrowed == b.borrowed
        np.testing.assert_array_equal(a.test_rows, b.test_rows)
        np.testing.assert_array_equal(a.y_pred, b.y_pred)
        for m, sa in a.scores.items():
            sb = b.scores[m]
            assert (sa.params, sa.mse, sa.n_fit) == (sb.params, sb.mse, sb.n_fit)
            assert sa.r2 == sb.r2 or (np.isnan(sa.r2) and np.isnan(sb.r2))


def test_bad_configuration_and_rows_are_refused(data: TrainingSet) -> None:
    with pytest.raises(ConfigError, match="unknown model"):
        TrainConfig(models=("linear", "xgboost"))
    with pytest.raises(ConfigError, match="test_size"):
        TrainConfig(test_size=1.0)
    X = data.X.copy()
    X[0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        TrainingSet(SET, FEATURES, X, data.depth, data.yaw_deg, data.segment_depth)
    with pytest.raises(InputError, match="shape"):
        TrainingSet(SET, FEATURES[:3], data.X, data.depth, data.yaw_deg, data.segment_depth)
    with pytest.raises(InputError, match="name"):
        TrainingSet("../evil", FEATURES, data.X, data.depth, data.yaw_deg, data.segment_depth)
