"""The model bundle at run time: loading, verifying and predicting with the trained ONNX models.

A bundle is a folder holding ``bundle.json`` and one ``.onnx`` file per chosen model (the depth model and the
per-segment angle models of every marker set), written by ``learning.export``. Loading reads only JSON and
ONNX, never a pickle, so a bundle from a stranger cannot run code; each model file must match the SHA-256
recorded in ``bundle.json``, ``bundle.json`` itself must match the digest it carries (``manifest_sha256``, over the
rest of it), and the feature schema must be the one this monodock computes. The calibration the
models were trained with (camera, dock layout, robot mounts) and the fused method's tables travel in
``bundle.json``'s metadata; ``Bundle.camera()``, ``layout()``, ``robot()`` and ``fusion_tables()`` read them.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final, cast

import numpy as np
from numpy.typing import NDArray

from monodock.core.config import load_json
from monodock.errors import ConfigError, InputError
from monodock.estimation.bundle_format import BundleMetadata, Manifest, ModelEntry, SetEntry
from monodock.estimation.calibration_records import CalibrationRecords, RecordKey
from monodock.estimation.fused import FusionTables
from monodock.estimation.segments import SegmentTable
from monodock.perception.features import MARKER_SETS, MODEL_FEATURE_SCHEMA, model_feature_names

__all__ = [
    "BUNDLE_FILE",
    "BUNDLE_SCHEMA_VERSION",
    "INPUT_NAME",
    "MANIFEST_DIGEST",
    "Bundle",
    "bundle_size_bytes",
    "load_bundle",
    "manifest_digest",
    "ort_session",
    "seal_manifest",
]

# 2: bundle.json carries a digest of itself (version 1 had none, so any edit to its metadata went unnoticed).
BUNDLE_SCHEMA_VERSION = 2
BUNDLE_FILE = "bundle.json"
INPUT_NAME = "input"
MANIFEST_DIGEST: Final = "manifest_sha256"


def manifest_digest(manifest: Mapping[str, Any]) -> str:
    """SHA-256 of the manifest without its own digest field, over a canonical JSON form (sorted keys, no spaces).

    Python writes and reads floats exactly (shortest round-trip repr), so a manifest read back and re-encoded gives
    the same bytes, whatever indentation the file was written with.
    """
    body = {k: v for k, v in manifest.items() if k != MANIFEST_DIGEST}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(canonical.encode("ascii")).hexdigest()


def seal_manifest(manifest: Manifest) -> Manifest:
    """The manifest with its digest set, last (what ``learning.export`` writes)."""
    sealed = manifest.copy()
    sealed.pop(MANIFEST_DIGEST, None)
    sealed[MANIFEST_DIGEST] = manifest_digest(manifest)
    return sealed


_SAFE_FILE = re.compile(r"^[A-Za-z0-9_.-]+\.onnx$")


def ort_session(model: bytes) -> Any:
    """An ONNX Runtime session tuned for one-row latency: one thread, sequential execution, CPU only."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.log_severity_level = 3
    return ort.InferenceSession(model, sess_options=so, providers=["CPUExecutionProvider"])


class _Model:
    """One loaded ONNX model: its session and output name."""

    __slots__ = ("n_features", "output", "session")

    def __init__(self, session: Any, n_features: int) -> None:
        self.session = session
        self.output = session.get_outputs()[0].name
        self.n_features = n_features

    def predict(self, X: NDArray[Any]) -> NDArray[np.float64]:
        x = np.asarray(X, dtype=np.float32)
        if x.ndim == 1:
            x = x.reshape(1, -1)
        if x.ndim != 2 or x.shape[1] != self.n_features:
            raise InputError(f"expected {self.n_features} features per row, got an array of shape {np.shape(X)}")
        out = self.session.run([self.output], {INPUT_NAME: x})[0]
        return np.asarray(out, dtype=np.float64).reshape(-1)


def _describe(names: Sequence[str], other: Sequence[str]) -> str:
    """Names summarised around their first difference from ``other``."""
    first = next((i for i, (a, b) in enumerate(zip(names, other, strict=False)) if a != b), min(len(names), len(other)))
    at = f"#{first + 1} is {names[first]!r}" if first < len(names) else f"ends after {names[-1]!r}" if names else "none"
    return f"{len(names)} features ({at})"


def _read_manifest(p: Path) -> tuple[Path, dict[str, Any]]:
    """The bundle's ``bundle.json`` path and contents as read, checked for this schema version and its own digest.

    The digest proves no accident, not who wrote it: ``_check_structure`` checks the shape before it is typed.
    """
    if not p.is_dir():
        raise InputError(f"{p} is not a model bundle folder")
    mf = p / BUNDLE_FILE
    if not mf.is_file():
        raise InputError(f"{p} is not a model bundle: it has no {BUNDLE_FILE}")
    try:
        manifest = load_json(mf, "bundle manifest")
    except ConfigError as exc:
        raise InputError(str(exc)) from None
    version = manifest.get("schema_version")
    if version != BUNDLE_SCHEMA_VERSION:
        raise InputError(
            f"{p} has bundle schema version {version}; this monodock reads version {BUNDLE_SCHEMA_VERSION}"
        )
    try:
        intact = manifest.get(MANIFEST_DIGEST) == manifest_digest(manifest)
    except (TypeError, ValueError):  # NaN or a value JSON cannot re-encode: not what export wrote
        intact = False
    if not intact:
        raise InputError(f"{mf} does not match its own digest ({MANIFEST_DIGEST}): it was edited or corrupted")
    return mf, manifest


def _check_structure(manifest: dict[str, Any], mf: Path) -> tuple[Manifest, SegmentTable]:
    """The manifest as read, its metadata, marker sets and segment table checked to have the shape export writes.

    The models' entries are checked as they are opened (``_open_models``).
    """
    meta = manifest.get("metadata")
    sets = manifest.get("sets")
    if not isinstance(meta, dict) or not isinstance(sets, dict) or not sets:
        raise InputError(f"{mf} is malformed: 'metadata' or 'sets' is missing")
    try:
        segments = SegmentTable(**manifest["segments"])
    except (KeyError, TypeError, ConfigError) as exc:
        raise InputError(f"{mf} is malformed: bad 'segments' ({exc})") from None
    for name, entry in sets.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("feature_names"), list):
            raise InputError(f"{mf} is malformed: marker set {name} has no list of feature_names")
    return cast(Manifest, manifest), segments


def _check_features(
    sets: dict[str, SetEntry],
    meta: BundleMetadata,
    expected_feature_names: Mapping[str, Sequence[str]] | None,
    feature_schema: str | None,
) -> None:
    """Refuse a bundle trained on another feature schema, or on other features for a set this monodock computes."""
    schema = meta.get("feature_schema", "(none recorded)")
    if feature_schema is not None and schema != feature_schema:
        raise InputError(f"bundle was trained on feature schema {schema}; this monodock computes {feature_schema}")
    if expected_feature_names is None:
        return
    common = [name for name in sets if name in expected_feature_names]
    if not common:
        raise InputError(
            f"bundle has marker sets {', '.join(sets)}; this monodock computes {', '.join(expected_feature_names)}"
        )
    for name in common:
        have = list(sets[name].get("feature_names", []))
        want = list(expected_feature_names[name])
        if have != want:
            raise InputError(
                f"bundle was trained on feature schema {schema} with {_describe(have, want)} for marker set "
                f"{name}; this monodock computes {_describe(want, have)}"
            )


def _open_models(
    p: Path, mf: Path, sets: dict[str, SetEntry], segments: SegmentTable
) -> tuple[dict[str, _Model], dict[str, list[_Model | None]]]:
    """Per marker set, its depth model and its per-segment yaw models (None for a segment without one)."""
    depth: dict[str, _Model] = {}
    yaw: dict[str, list[_Model | None]] = {}
    for name, entry in sets.items():
        nf = len(entry["feature_names"])
        depth_entry, yaw_entries = entry.get("depth"), entry.get("yaw")
        if not isinstance(yaw_entries, list) or len(yaw_entries) != segments.count:
            raise InputError(f"{mf} is malformed: marker set {name} needs {segments.count} yaw entries")
        model = _open(p, depth_entry, nf, mf)
        if model is None:
            raise InputError(f"{mf} is malformed: marker set {name} has no depth model")
        depth[name] = model
        yaw[name] = [_open(p, e, nf, mf) for e in yaw_entries]
    return depth, yaw


class Bundle(CalibrationRecords):
    """A loaded model bundle: predicts depth (m) and per-segment yaw (deg) with ONNX Runtime, one thread."""

    manifest: Manifest
    path: Path
    segments: SegmentTable
    sets: tuple[str, ...]

    def __init__(
        self,
        path: Path,
        manifest: Manifest,
        segments: SegmentTable,
        depth: dict[str, _Model],
        yaw: dict[str, list[_Model | None]],
    ) -> None:
        """Use ``Bundle.load``."""
        self.path = path
        self.manifest = manifest
        self.segments = segments
        self.sets = tuple(depth)
        self._depth = depth
        self._yaw = yaw

    @classmethod
    def load(
        cls,
        path: str | os.PathLike[str],
        *,
        expected_feature_names: Mapping[str, Sequence[str]] | None = None,
        feature_schema: str | None = None,
    ) -> Bundle:
        """Read a bundle folder, check it, and open an ONNX Runtime session for every model.

        Args:
            path: The bundle folder.
            expected_feature_names: Per set, the features this monodock computes; a set of the bundle that
                is listed here must have exactly these, in order.
            feature_schema: The feature schema this monodock computes; must equal metadata["feature_schema"].

        Returns:
            The bundle.

        Raises:
            InputError: Not a bundle, invalid or other-version JSON, a missing or tampered model file, a
                feature mismatch, or a model ONNX Runtime cannot load. One line saying which.
        """
        p = Path(path)
        mf, raw = _read_manifest(p)
        manifest, segments = _check_structure(raw, mf)
        _check_features(manifest["sets"], manifest["metadata"], expected_feature_names, feature_schema)
        depth, yaw = _open_models(p, mf, manifest["sets"], segments)
        bundle = cls(p, manifest, segments, depth, yaw)
        # The calibration it was trained with is checked as its files would be, before any estimate (the part
        # that is there: a bundle lacking one is refused, naming it, where it is needed).
        for key, read in (("camera", bundle.camera), ("layout", bundle.layout), ("robot", bundle.robot)):
            if key in bundle.metadata:
                read()
        return bundle

    # --- what the models were trained with ------------------------------------------------------------------

    @property
    def metadata(self) -> BundleMetadata:
        """``bundle.json``'s metadata: the calibration, feature schema, labels and the fused method's tables."""
        return self.manifest["metadata"]

    # camera(), layout() and robot(): CalibrationRecords, from these two.
    def _meta(self, key: RecordKey) -> dict[str, Any]:
        if key not in self.metadata:
            raise InputError(f"{self.path}: {BUNDLE_FILE} has no '{key}' in its metadata")
        return self.metadata[key]

    def _record_name(self, key: RecordKey) -> str:
        return f"{self.path}: {key}"

    @property
    def has_fusion_tables(self) -> bool:
        """Whether the bundle carries the fused method's tables (bundles trained before it do not)."""
        return "fusion" in self.metadata

    def fusion_tables(self) -> FusionTables:
        """The fused method's tables; one-line InputError for a bundle trained without them."""
        if not self.has_fusion_tables:
            raise InputError(
                f"{self.path}: this bundle has no fusion tables (trained before the fused method); retrain it"
            )
        return FusionTables.from_dict(self.metadata["fusion"], str(self.path))

    @property
    def size_bytes(self) -> int:
        """Total size of the bundle's files on disk."""
        return bundle_size_bytes(self.path)

    def feature_names(self, set_name: str) -> tuple[str, ...]:
        """The feature names (input columns, in order) of a marker set's models."""
        return tuple(self._set(set_name)["feature_names"])

    def entry(self, set_name: str, segment: int | None = None) -> ModelEntry:
        """The manifest entry (model type, metrics, rows, borrowing) of the depth model or a segment's angle model."""
        s = self._set(set_name)
        if segment is None:
            return s["depth"].copy()
        return s["yaw"][segment].copy()

    def predict_depth(self, set_name: str, X: NDArray[Any]) -> NDArray[np.float64]:
        """Depth in metres for each row of X, shape (n, f) or (f,); returns shape (n,) (or (1,) for one row)."""
        self._set(set_name)
        return self._depth[set_name].predict(X)

    def has_angle_model(self, set_name: str, segment: int) -> bool:
        """Whether a marker set has an angle model for the segment (False outside the segment table)."""
        models = self._yaw.get(set_name)
        return models is not None and 0 <= segment < len(models) and models[segment] is not None

    def predict_yaw_deg(self, set_name: str, segment: int, X: NDArray[Any]) -> NDArray[np.float64]:
        """Yaw in degrees from the segment's angle model for each row of X, shape (n, f) or (f,)."""
        self._set(set_name)
        if not 0 <= segment < self.segments.count:
            raise InputError(f"segment {segment} is outside 0..{self.segments.count - 1}")
        model = self._yaw[set_name][segment]
        if model is None:
            reason = self.manifest["sets"][set_name]["yaw"][segment].get("reason", "no model")
            raise InputError(f"marker set {set_name} has no angle model for {self.segments.label(segment)}: {reason}")
        return model.predict(X)

    def _set(self, set_name: str) -> SetEntry:
        if set_name not in self._depth:
            raise InputError(f"the bundle has no marker set {set_name!r}; it has {', '.join(self.sets)}")
        return self.manifest["sets"][set_name]


def _open(folder: Path, entry: Any, n_features: int, manifest_path: Path) -> _Model | None:
    """The model of one manifest entry, checked against its checksum; None for an entry without a model."""
    if not isinstance(entry, dict):
        raise InputError(f"{manifest_path} is malformed: a model entry is not an object")
    file = entry.get("file")
    if file is None:
        return None
    if not isinstance(file, str) or not _SAFE_FILE.match(file):
        raise InputError(f"{manifest_path} lists an invalid model file name {file!r}")
    f = folder / file
    if not f.is_file():
        raise InputError(f"model file {file} listed in {BUNDLE_FILE} is missing from {folder}")
    data = f.read_bytes()
    if hashlib.sha256(data).hexdigest() != entry.get("sha256"):
        raise InputError(f"model file {file} does not match its checksum in {BUNDLE_FILE} (changed or corrupted)")
    try:
        session = ort_session(data)
    except Exception as exc:  # onnxruntime raises its own exception types for a model it cannot run
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"model file {file} cannot be loaded by ONNX Runtime: {first}") from None
    inputs = session.get_inputs()
    if (
        len(inputs) != 1
        or inputs[0].name != INPUT_NAME
        or inputs[0].type != "tensor(float)"
        or list(inputs[0].shape)[1:] != [n_features]
        or len(session.get_outputs()) != 1
    ):
        raise InputError(f"model file {file} does not take one float input {INPUT_NAME!r} of {n_features} features")
    return _Model(session, n_features)


def load_bundle(path: str | os.PathLike[str]) -> Bundle:
    """A bundle of this monodock's feature schema (any of its marker sets), verified; see ``Bundle.load``."""
    return Bundle.load(
        path,
        expected_feature_names={s: model_feature_names(s) for s in MARKER_SETS},
        feature_schema=MODEL_FEATURE_SCHEMA,
    )


def bundle_size_bytes(path: str | os.PathLike[str]) -> int:
    """Total size on disk of the files in a bundle folder, in bytes."""
    return sum(f.stat().st_size for f in Path(path).iterdir() if f.is_file())
