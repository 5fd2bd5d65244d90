"""The model bundle: trained models as ONNX files plus a JSON manifest, and loading them for prediction.

A bundle is a folder holding ``bundle.json`` and one ``.onnx`` file per chosen model (the depth model and the
per-segment angle models of every marker set). Loading reads only JSON and ONNX, never a pickle, so a bundle
from a stranger cannot run code; each model file must match the SHA-256 recorded in ``bundle.json``.

Every model takes one float32 input named ``input`` of shape [None, n_features] and has one output. Tree
models are exported by skl2onnx as they are (they were fit on float32 values, so they split on the same
numbers). The scaled linear models are exported by skl2onnx in double precision behind a float-to-double
cast, and SVR as an explicit double-precision RBF kernel expansion: ONNX's SVMRegressor computes in float32
only, which is up to ~5e-4 off scikit-learn on yaw in degrees.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from datetime import UTC, datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.atomic import atomic_directory, write_text_atomic
from monodock.errors import ConfigError, InputError
from monodock.learning.train import SegmentTable, TaskResult, TrainingResult

__all__ = [
    "BUNDLE_FILE",
    "BUNDLE_SCHEMA_VERSION",
    "INPUT_NAME",
    "TARGET_OPSET",
    "Bundle",
    "bundle_size_bytes",
    "onnx_model_bytes",
    "ort_session",
    "save_bundle",
    "update_bundle_metadata",
]

BUNDLE_SCHEMA_VERSION = 1
BUNDLE_FILE = "bundle.json"
INPUT_NAME = "input"
# Opsets every ONNX Runtime since 1.13 runs (ReduceSumSquare still takes its axes as an attribute in 17).
TARGET_OPSET = {"": 17, "ai.onnx.ml": 3}

_VERSIONED = ("monodock", "scikit-learn", "skl2onnx", "onnx", "onnxruntime", "numpy")
_SAFE_FILE = re.compile(r"^[A-Za-z0-9_.-]+\.onnx$")


# ---------------------------------------------------------------------------------------------------------------
# Export


def _float_input(model: Any) -> Any:
    """The model with its double input replaced by a float32 input and a Cast to double in front."""
    from onnx import TensorProto, helper

    graph = model.graph
    (inp,) = graph.input
    inner = f"{inp.name}_f64"
    for node in graph.node:
        for i, name in enumerate(node.input):
            if name == inp.name:
                node.input[i] = inner
    graph.node.insert(0, helper.make_node("Cast", [inp.name], [inner], to=TensorProto.DOUBLE, name="cast_input"))
    inp.type.tensor_type.elem_type = TensorProto.FLOAT
    return model


def _svr_onnx(pipeline: Any, n_features: int) -> Any:
    """StandardScaler + RBF SVR as a double-precision ONNX graph with a float32 input.

    y = Σ_i α_i exp(-γ |z - s_i|²) + b with z the standardised input, computed as
    exp(2γ z·s_i - γ|z|² - γ|s_i|²).
    """
    from onnx import TensorProto, helper, numpy_helper

    scaler, svr = pipeline.steps[0][1], pipeline.steps[-1][1]
    if svr.kernel != "rbf":
        raise ValueError(f"only the RBF kernel is exported, not {svr.kernel}")
    gamma = float(svr._gamma)
    sv = np.asarray(svr.support_vectors_, dtype=np.float64)
    mean = np.zeros(n_features) if scaler.mean_ is None else np.asarray(scaler.mean_, dtype=np.float64)
    scale = np.ones(n_features) if scaler.scale_ is None else np.asarray(scaler.scale_, dtype=np.float64)
    inits = {
        "mean": mean.reshape(1, -1),
        "scale": scale.reshape(1, -1),
        "sv_t2g": (2.0 * gamma) * sv.T,
        "minus_gamma": np.array([-gamma]),
        "sv_term": (-gamma * np.sum(sv * sv, axis=1)).reshape(1, -1),
        "dual": np.asarray(svr.dual_coef_, dtype=np.float64).reshape(-1, 1),
        "intercept": np.asarray(svr.intercept_, dtype=np.float64).reshape(1, 1),
    }
    nodes = [
        helper.make_node("Cast", [INPUT_NAME], ["x64"], to=TensorProto.DOUBLE),
        helper.make_node("Sub", ["x64", "mean"], ["centred"]),
        helper.make_node("Div", ["centred", "scale"], ["z"]),
        helper.make_node("MatMul", ["z", "sv_t2g"], ["cross"]),
        helper.make_node("ReduceSumSquare", ["z"], ["zz"], axes=[1], keepdims=1),
        helper.make_node("Mul", ["zz", "minus_gamma"], ["z_term"]),
        helper.make_node("Add", ["cross", "z_term"], ["partial"]),
        helper.make_node("Add", ["partial", "sv_term"], ["exponent"]),
        helper.make_node("Exp", ["exponent"], ["kernel"]),
        helper.make_node("MatMul", ["kernel", "dual"], ["weighted"]),
        helper.make_node("Add", ["weighted", "intercept"], ["variable"]),
    ]
    graph = helper.make_graph(
        nodes,
        "svr_rbf",
        [helper.make_tensor_value_info(INPUT_NAME, TensorProto.FLOAT, [None, n_features])],
        [helper.make_tensor_value_info("variable", TensorProto.DOUBLE, [None, 1])],
        initializer=[numpy_helper.from_array(v, name=k) for k, v in inits.items()],
    )
    # IR version 8 goes with opset 17 (onnx's newest IR is ahead of what ONNX Runtime reads).
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", TARGET_OPSET[""])], ir_version=8)
    model.producer_name = "monodock"
    return model


def onnx_model_bytes(estimator: Any, n_features: int) -> bytes:
    """The serialized ONNX model of a fitted monodock estimator (see ``train.make_estimator``).

    Args:
        estimator: A fitted tree model, or a Pipeline of StandardScaler and a linear model or RBF SVR.
        n_features: Width of the input.

    Returns:
        ONNX bytes with one float32 input ``input`` of shape [None, n_features] and one (n, 1) output.
    """
    from onnx import checker
    from skl2onnx import to_onnx
    from skl2onnx.common.data_types import DoubleTensorType, FloatTensorType
    from sklearn.pipeline import Pipeline
    from sklearn.svm import SVR

    if isinstance(estimator, Pipeline) and isinstance(estimator.steps[-1][1], SVR):
        model = _svr_onnx(estimator, n_features)
    elif isinstance(estimator, Pipeline):
        # Double precision inside: float32 sums of large, cancelling linear coefficients drift past 1e-4.
        model = to_onnx(
            estimator, initial_types=[(INPUT_NAME, DoubleTensorType([None, n_features]))], target_opset=TARGET_OPSET
        )
        model = _float_input(model)
    else:
        model = to_onnx(
            estimator, initial_types=[(INPUT_NAME, FloatTensorType([None, n_features]))], target_opset=TARGET_OPSET
        )
    checker.check_model(model)
    return bytes(model.SerializeToString())


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in _VERSIONED:
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            out[name] = "unknown"
    return out


def _number(x: float) -> float | None:
    """A float for JSON: NaN and infinities become null."""
    return float(x) if math.isfinite(x) else None


def _entry(task: TaskResult, file: str | None, digest: str | None, size: int | None) -> dict[str, Any]:
    best = task.best
    entry: dict[str, Any] = {
        "file": file,
        "model": task.chosen,
        "params": None if best is None else best.params,
        "mse": None if best is None else _number(best.mse),
        "r2": None if best is None else _number(best.r2),
        "n_train": task.n_train,
        "n_test": task.n_test,
        "n_own": task.n_own,
        "n_rows": task.n_rows,
        "borrowed": None if task.borrowed is None else list(task.borrowed),
        "sha256": digest,
        "bytes": size,
        "candidates": {m: {"mse": _number(s.mse), "r2": _number(s.r2)} for m, s in task.scores.items()},
    }
    if task.segment is not None:
        entry["segment"] = task.segment
    if file is None:
        entry["reason"] = task.reason or "no model"
    return entry


def save_bundle(
    out: str | os.PathLike[str], result: TrainingResult, *, metadata: Mapping[str, Any], force: bool = False
) -> Path:
    """Write a model bundle folder atomically: one ONNX file per chosen model and ``bundle.json``.

    Args:
        out: The bundle folder to create.
        result: What ``train.train`` returned.
        metadata: JSON-able facts kept verbatim under "metadata" (layout, camera, robot, feature schema, labels).
        force: Replace an existing ``out``.

    Returns:
        The bundle folder.

    Raises:
        InputError: ``out`` exists and ``force`` is not given, or cannot be written.
        TypeError: ``metadata`` is not JSON-serialisable.
    """
    try:
        meta = json.loads(json.dumps(dict(metadata), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise TypeError(f"bundle metadata must be JSON-serialisable: {exc}") from exc
    cfg = result.config
    sets: dict[str, Any] = {}
    total = 0
    with atomic_directory(out, force=force) as tmp:

        def write(task: TaskResult, file: str, n_features: int) -> dict[str, Any]:
            nonlocal total
            if task.estimator is None:
                return _entry(task, None, None, None)
            data = onnx_model_bytes(task.estimator, n_features)
            (tmp / file).write_bytes(data)
            total += len(data)
            return _entry(task, file, hashlib.sha256(data).hexdigest(), len(data))

        for s in result.sets:
            nf = len(s.feature_names)
            sets[s.name] = {
                "feature_names": list(s.feature_names),
                "n_rows": s.n_rows,
                "depth": write(s.depth, f"{s.name}.depth.onnx", nf),
                "yaw": [write(t, f"{s.name}.yaw.{t.segment:02d}.onnx", nf) for t in s.angle],
            }
        manifest = {
            "schema_version": BUNDLE_SCHEMA_VERSION,
            "created": datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z"),
            "versions": _versions(),
            "metadata": meta,
            "targets": {"depth": "metres (DockPose x label)", "yaw": "degrees (DockPose yaw label)"},
            "onnx": {"input": INPUT_NAME, "dtype": "float32", "opset": TARGET_OPSET},
            "segments": asdict(cfg.segments),
            "train_config": {**{k: v for k, v in asdict(cfg).items() if k != "segments"}, "models": list(cfg.models)},
            "training": {"seconds": round(result.seconds, 3), "fits": result.n_fits, "jobs": result.jobs},
            "onnx_bytes": total,
            "sets": sets,
        }
        (tmp / BUNDLE_FILE).write_text(json.dumps(manifest, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return Path(out)


def update_bundle_metadata(path: str | os.PathLike[str], key: str, value: Any) -> None:
    """Add or replace one entry of a saved bundle's metadata; bundle.json is rewritten atomically.

    For what is learned after the models exist (the fused method's tables come from the models' answers).
    """
    mf = Path(path) / BUNDLE_FILE
    manifest = json.loads(mf.read_text(encoding="utf-8"))
    manifest["metadata"][key] = json.loads(json.dumps(value, allow_nan=False))
    write_text_atomic(mf, json.dumps(manifest, indent=1, allow_nan=False) + "\n", force=True)


def bundle_size_bytes(path: str | os.PathLike[str]) -> int:
    """Total size on disk of the files in a bundle folder, in bytes."""
    return sum(f.stat().st_size for f in Path(path).iterdir() if f.is_file())


# ---------------------------------------------------------------------------------------------------------------
# Loading


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


class Bundle:
    """A loaded model bundle: predicts depth (m) and per-segment yaw (deg) with ONNX Runtime, one thread."""

    manifest: dict[str, Any]
    path: Path
    segments: SegmentTable
    sets: tuple[str, ...]

    def __init__(
        self,
        path: Path,
        manifest: dict[str, Any],
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
        if not p.is_dir():
            raise InputError(f"{p} is not a model bundle folder")
        mf = p / BUNDLE_FILE
        if not mf.is_file():
            raise InputError(f"{p} is not a model bundle: it has no {BUNDLE_FILE}")
        try:
            manifest = json.loads(mf.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{mf} is not valid JSON: {exc}") from None
        if not isinstance(manifest, dict):
            raise InputError(f"{mf} is not a bundle manifest (not a JSON object)")
        version = manifest.get("schema_version")
        if version != BUNDLE_SCHEMA_VERSION:
            raise InputError(
                f"{p} has bundle schema version {version}; this monodock reads version {BUNDLE_SCHEMA_VERSION}"
            )
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

        schema = meta.get("feature_schema", "(none recorded)")
        if feature_schema is not None and schema != feature_schema:
            raise InputError(f"bundle was trained on feature schema {schema}; this monodock computes {feature_schema}")
        if expected_feature_names is not None:
            common = [name for name in sets if name in expected_feature_names]
            if not common:
                raise InputError(
                    f"bundle has marker sets {', '.join(sets)}; this monodock computes "
                    f"{', '.join(expected_feature_names)}"
                )
            for name in common:
                have = list(sets[name].get("feature_names", []))
                want = list(expected_feature_names[name])
                if have != want:
                    raise InputError(
                        f"bundle was trained on feature schema {schema} with {_describe(have, want)} for marker set "
                        f"{name}; this monodock computes {_describe(want, have)}"
                    )

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
        return cls(p, manifest, segments, depth, yaw)

    @property
    def size_bytes(self) -> int:
        """Total size of the bundle's files on disk."""
        return bundle_size_bytes(self.path)

    def feature_names(self, set_name: str) -> tuple[str, ...]:
        """The feature names (input columns, in order) of a marker set's models."""
        return tuple(self._set(set_name)["feature_names"])

    def entry(self, set_name: str, segment: int | None = None) -> dict[str, Any]:
        """The manifest entry (model type, metrics, rows, borrowing) of the depth model or a segment's angle model."""
        s = self._set(set_name)
        if segment is None:
            return dict(s["depth"])
        return dict(s["yaw"][segment])

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

    def _set(self, set_name: str) -> dict[str, Any]:
        if set_name not in self._depth:
            raise InputError(f"the bundle has no marker set {set_name!r}; it has {', '.join(self.sets)}")
        entry: dict[str, Any] = self.manifest["sets"][set_name]
        return entry


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
