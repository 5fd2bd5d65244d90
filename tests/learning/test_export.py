"""ONNX export (learning.export): predictions equal scikit-learn's for every model type; the manifest; no overwrite."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimation.bundle import BUNDLE_FILE, Bundle, bundle_size_bytes
from monodock.learning.export import save_bundle
from monodock.learning.regressors import MODEL_NAMES
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import TrainingResult, train
from shared import FEATURES, META, SET, SPARSE_SEGMENT, as_float32


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
    assert manifest["schema_version"] == 2
    # The manifest's own digest: SHA-256 of its canonical JSON without the digest field.
    body = {k: v for k, v in manifest.items() if k != "manifest_sha256"}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    assert manifest["manifest_sha256"] == hashlib.sha256(canonical.encode()).hexdigest()
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
