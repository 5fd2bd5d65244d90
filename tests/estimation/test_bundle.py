"""Loading a bundle (estimation.bundle): verified checksums and schema, no pickles, one-line refusals."""

from __future__ import annotations

import hashlib
import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimation.bundle import BUNDLE_FILE, MANIFEST_DIGEST, Bundle, seal_manifest
from shared import FEATURES, SET


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


def _edit_manifest(bundle: Path, edit: object, *, reseal: bool = True) -> None:
    """Edit bundle.json; ``reseal`` re-computes its digest (a test of what the loader checks after the digest)."""
    path = bundle / BUNDLE_FILE
    manifest = json.loads(path.read_text())
    edit(manifest)  # type: ignore[operator]
    path.write_text(json.dumps(seal_manifest(manifest) if reseal else manifest))


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m["metadata"]["layout"].update(marker_size=0.12),
        lambda m: m["metadata"].pop("layout"),
        lambda m: m["sets"][SET]["depth"].update(mse=0.0),
        lambda m: m.update(created="2030-01-01T00:00:00Z"),
        lambda m: m.pop(MANIFEST_DIGEST),
    ],
    ids=["marker size changed", "layout removed", "a metric", "the date", "no digest"],
)
def test_any_edit_of_bundle_json_is_refused(bundle_copy: Path, edit: object) -> None:
    """The manifest is covered too: a calibration edited in it (issue 18: the camera mount moved by a metre) changed
    every estimate without a word."""
    _edit_manifest(bundle_copy, edit, reseal=False)
    with pytest.raises(InputError, match=r"bundle\.json does not match its own digest \(manifest_sha256\)"):
        Bundle.load(bundle_copy)


def test_the_digest_does_not_depend_on_the_file_layout(bundle_copy: Path) -> None:
    """Re-indented or key-reordered, the same content loads: the digest is over canonical JSON."""
    path = bundle_copy / BUNDLE_FILE
    manifest = json.loads(path.read_text())
    path.write_text(json.dumps(dict(reversed(list(manifest.items()))), indent=4))
    Bundle.load(bundle_copy)


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
    _edit_manifest(bundle_copy, lambda m: m.update(schema_version=1))
    with pytest.raises(InputError, match="schema version 1; this monodock reads version 2"):
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
