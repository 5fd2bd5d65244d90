"""Model selection, segment borrowing, the ONNX bundle round trip and its refusals, and the training report."""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from monodock.errors import ConfigError, InputError
from monodock.estimation.bundle import BUNDLE_FILE, Bundle, bundle_size_bytes
from monodock.estimation.segments import SegmentTable
from monodock.learning.export import save_bundle
from monodock.learning.train import MODEL_NAMES, TrainConfig, TrainingResult, TrainingSet, train
from monodock.report.training import training_tables, write_training_report

SET = "m1m2m3"
FEATURES = ("size", "ratio", "noise_a", "noise_b")
SPARSE_SEGMENT = 3  # 40-45 cm: only 10 rows of its own
META = {"feature_schema": "test-features/1", "layout": {"marker_size": 0.1}}


def synthetic_set(seed: int = 0) -> TrainingSet:
    """Rows from a known function: depth = 60 / size, yaw linear in a ratio whose slope grows with depth.

    Depths cover 25-60 cm (segments 0-6), with segment 3 nearly empty; farther segments have no rows.
    """
    rng = np.random.default_rng(seed)
    per_segment = [70, 70, 70, 10, 70, 70, 70]
    depth = np.concatenate([rng.uniform(0.25 + 0.05 * k, 0.30 + 0.05 * k, n) for k, n in enumerate(per_segment)])
    n = len(depth)
    yaw = rng.uniform(-30.0, 30.0, n)
    size = 60.0 / depth + rng.normal(0.0, 0.2, n)
    ratio = yaw * (0.01 + 0.02 * depth) + rng.normal(0.0, 0.01, n)
    X = np.column_stack([size, ratio, rng.normal(size=n), 50.0 * rng.normal(size=n)])
    return TrainingSet(SET, FEATURES, X, depth + rng.normal(0.0, 0.003, n), yaw, depth)


def as_float32(X: NDArray[np.float64]) -> NDArray[np.float64]:
    return X.astype(np.float32).astype(np.float64)


@pytest.fixture(scope="module")
def data() -> TrainingSet:
    return synthetic_set()


@pytest.fixture(scope="module")
def result(data: TrainingSet) -> TrainingResult:
    return train([data], TrainConfig(trials=2, jobs=1, seed=3), progress=False)


@pytest.fixture(scope="module")
def saved(result: TrainingResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_bundle(tmp_path_factory.mktemp("b") / "bundle", result, metadata=META)


@pytest.fixture
def bundle_copy(saved: Path, tmp_path: Path) -> Path:
    out = tmp_path / "bundle"
    shutil.copytree(saved, out)
    return out


# ---------------------------------------------------------------------------------------------------------------
# Training


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


# ---------------------------------------------------------------------------------------------------------------
# Bundle


@pytest.mark.parametrize("model", MODEL_NAMES)
def test_onnx_predictions_equal_sklearn_for_every_model_type(model: str, data: TrainingSet, tmp_path: Path) -> None:
    res = train([data], TrainConfig(trials=2, jobs=1, models=(model,)), progress=False)
    out = save_bundle(tmp_path / "b", res, metadata=META)
    bundle = Bundle.load(out, expected_feature_names={SET: FEATURES}, feature_schema="test-features/1")
    s = res.set(SET)
    X = data.X[::3]
    X32 = as_float32(X)
    np.testing.assert_allclose(bundle.predict_depth(SET, X), s.depth.estimator.predict(X32), rtol=0, atol=1e-4)
    checked = 0
    for t in s.angle:
        assert t.segment is not None
        assert bundle.has_angle_model(SET, t.segment) == (t.chosen is not None)
        if t.chosen is None:
            continue
        assert t.chosen == model
        got = bundle.predict_yaw_deg(SET, t.segment, X)
        np.testing.assert_allclose(got, t.estimator.predict(X32), rtol=0, atol=1e-4)
        one = bundle.predict_yaw_deg(SET, t.segment, X[0])  # a single row, shape (f,)
        assert one.shape == (1,)
        assert one[0] == pytest.approx(float(got[0]), abs=1e-9)
        checked += 1
    assert checked >= 8


def test_manifest_has_checksums_metrics_and_size(saved: Path, result: TrainingResult) -> None:
    manifest = json.loads((saved / BUNDLE_FILE).read_text())
    assert manifest["schema_version"] == 1
    assert manifest["metadata"] == META
    assert manifest["segments"] == {"start_m": 0.25, "width_m": 0.05, "count": 45}
    assert {"scikit-learn", "skl2onnx", "onnx", "onnxruntime", "numpy", "monodock"} <= set(manifest["versions"])
    entry = manifest["sets"][SET]
    assert entry["feature_names"] == list(FEATURES)
    entries = [entry["depth"], *entry["yaw"]]
    assert len(entries) == 46
    files = [e for e in entries if e["file"] is not None]
    for e in files:
        assert e["sha256"] == hashlib.sha256((saved / e["file"]).read_bytes()).hexdigest()
        assert e["model"] in MODEL_NAMES
        assert e["mse"] >= 0
        assert {"params", "r2", "n_train", "n_test", "n_own"} <= set(e)
    assert entry["yaw"][SPARSE_SEGMENT]["borrowed"] == [SPARSE_SEGMENT - 1, SPARSE_SEGMENT + 1]
    assert entry["yaw"][44]["file"] is None
    assert "rows" in entry["yaw"][44]["reason"]
    assert sorted(p.name for p in saved.glob("*.onnx")) == sorted(e["file"] for e in files)
    size = bundle_size_bytes(saved)
    assert size == sum(p.stat().st_size for p in saved.iterdir())
    assert manifest["onnx_bytes"] == sum(e["bytes"] for e in files) < size
    bundle = Bundle.load(saved)
    assert bundle.size_bytes == size
    assert bundle.sets == (SET,)
    assert bundle.feature_names(SET) == FEATURES
    assert result.set(SET).depth.chosen == bundle.entry(SET)["model"]


def test_save_never_overwrites_without_force(saved: Path, result: TrainingResult) -> None:
    before = (saved / BUNDLE_FILE).read_bytes()
    with pytest.raises(InputError, match="exists"):
        save_bundle(saved, result, metadata=META)
    assert (saved / BUNDLE_FILE).read_bytes() == before


def test_predicting_without_a_model_or_with_bad_input_is_refused(saved: Path) -> None:
    bundle = Bundle.load(saved)
    assert not bundle.has_angle_model(SET, 44)
    assert not bundle.has_angle_model(SET, 99)
    with pytest.raises(InputError, match="no angle model"):
        bundle.predict_yaw_deg(SET, 44, np.zeros(len(FEATURES)))
    with pytest.raises(InputError, match="features"):
        bundle.predict_depth(SET, np.zeros(len(FEATURES) + 1))
    with pytest.raises(InputError, match="no marker set"):
        bundle.predict_depth("m2", np.zeros(len(FEATURES)))


def _edit_manifest(bundle: Path, edit: object) -> None:
    path = bundle / BUNDLE_FILE
    manifest = json.loads(path.read_text())
    edit(manifest)  # type: ignore[operator]
    path.write_text(json.dumps(manifest))


def test_tampered_model_file_is_refused(bundle_copy: Path) -> None:
    f = bundle_copy / f"{SET}.depth.onnx"
    raw = bytearray(f.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    f.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=r"model file m1m2m3\.depth\.onnx does not match its checksum in bundle\.json"):
        Bundle.load(bundle_copy)


def test_missing_model_file_is_refused(bundle_copy: Path) -> None:
    (bundle_copy / f"{SET}.yaw.02.onnx").unlink()
    with pytest.raises(InputError, match=r"m1m2m3\.yaw\.02\.onnx .* is missing"):
        Bundle.load(bundle_copy)


def test_other_features_or_schema_are_refused(saved: Path) -> None:
    other = ("size", "ratio", "noise_a", "noise_c")
    with pytest.raises(
        InputError, match=r"trained on feature schema test-features/1 with 4 features \(#4 is 'noise_b'\)"
    ):
        Bundle.load(saved, expected_feature_names={SET: other})
    with pytest.raises(InputError, match="this monodock computes 5 features"):
        Bundle.load(saved, expected_feature_names={SET: (*FEATURES, "extra")})
    with pytest.raises(InputError, match="trained on feature schema test-features/1; this monodock computes v2"):
        Bundle.load(saved, feature_schema="v2")
    with pytest.raises(InputError, match="marker sets"):
        Bundle.load(saved, expected_feature_names={"m2": FEATURES})


def test_other_schema_version_and_bad_json_are_refused(bundle_copy: Path, tmp_path: Path) -> None:
    _edit_manifest(bundle_copy, lambda m: m.update(schema_version=2))
    with pytest.raises(InputError, match="schema version 2; this monodock reads version 1"):
        Bundle.load(bundle_copy)
    (bundle_copy / BUNDLE_FILE).write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        Bundle.load(bundle_copy)
    with pytest.raises(InputError, match=r"no bundle\.json"):
        Bundle.load(tmp_path)
    with pytest.raises(InputError, match="not a model bundle folder"):
        Bundle.load(tmp_path / "nowhere")


def test_model_onnx_runtime_cannot_load_is_refused(bundle_copy: Path) -> None:
    junk = b"this is not an onnx model"
    (bundle_copy / f"{SET}.depth.onnx").write_bytes(junk)
    _edit_manifest(bundle_copy, lambda m: m["sets"][SET]["depth"].update(sha256=hashlib.sha256(junk).hexdigest()))
    with pytest.raises(InputError, match="cannot be loaded by ONNX Runtime"):
        Bundle.load(bundle_copy)


class _Evil:
    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (print, ("unpickled!",))


def test_loading_never_unpickles(bundle_copy: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (bundle_copy / "model.pkl").write_bytes(pickle.dumps(_Evil()))

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("a bundle must never be unpickled")

    import joblib

    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)
    monkeypatch.setattr(joblib, "load", refuse)
    bundle = Bundle.load(bundle_copy)
    assert bundle.predict_depth(SET, np.array([150.0, 0.1, 0.0, 0.0])).shape == (1,)
    # A manifest that points at the pickle is refused by name, before anything reads it.
    _edit_manifest(bundle_copy, lambda m: m["sets"][SET]["depth"].update(file="model.pkl"))
    with pytest.raises(InputError, match="invalid model file name"):
        Bundle.load(bundle_copy)


# ---------------------------------------------------------------------------------------------------------------
# Report


def test_training_report_has_the_papers_tables_and_plots(result: TrainingResult, tmp_path: Path) -> None:
    files = write_training_report(tmp_path / "report", result, title="Training")
    assert [p.name for p in files] == ["training.md", f"training_{SET}_depth.png", f"training_{SET}_yaw.png"]
    text = files[0].read_text()
    assert text.startswith("# Training")
    for needle in ("Table 1", "Table 2", "Table 3", "**Avg**", "Random Forest", "40–45 cm", "245–250 cm", "(±1)"):
        assert needle in text
    for png in files[1:]:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    tables = training_tables(result)
    assert len(tables) == 3
    depth_models, segments, segment_models = tables.values()
    assert all(title.startswith(f"Table {i}") and SET in title for i, title in enumerate(tables, start=1))
    assert "★" in depth_models
    assert len(segments.splitlines()) == 2 + 45 + 1
    assert len(segment_models.splitlines()) == 2 + 45
    with pytest.raises(InputError, match="exists"):
        write_training_report(tmp_path / "report", result, title="Training")
    assert (
        write_training_report(tmp_path / "report", result, title="Again", force=True)[0]
        .read_text()
        .startswith("# Again")
    )
