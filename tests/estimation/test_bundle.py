"""Loading a bundle (estimation.bundle): verified checksums and schema, no pickles, one-line refusals."""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimation.bundle import BUNDLE_FILE, Bundle
from monodock.learning.export import save_bundle
from monodock.learning.train import TrainConfig, TrainingResult, TrainingSet, train

SET = "m1m2m3"


FEATURES = ("size", "ratio", "noise_a", "noise_b")


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
