"""Writing a model bundle: each chosen model as an ONNX file, and ``bundle.json`` with what the reader checks.

Tree models are exported by skl2onnx as they are (they were fit on float32 values, so they split on the same
numbers). The scaled linear models are exported by skl2onnx in double precision behind a float-to-double
cast, and SVR as an explicit double-precision RBF kernel expansion: ONNX's SVMRegressor computes in float32
only, which is up to ~5e-4 off scikit-learn on yaw in degrees. ``estimation.bundle`` reads what this writes.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
from dataclasses import asdict
from datetime import UTC, datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any, cast

import numpy as np

from monodock.core.atomic import atomic_directory, write_text_atomic
from monodock.estimation.bundle import BUNDLE_FILE, BUNDLE_SCHEMA_VERSION, INPUT_NAME, seal_manifest
from monodock.estimation.bundle_format import BundleMetadata, Manifest, ModelEntry, SetEntry
from monodock.learning.train import TaskResult, TrainingResult

__all__ = ["TARGET_OPSET", "onnx_model_bytes", "save_bundle", "update_bundle_metadata", "write_bundle"]

# Opsets every ONNX Runtime since 1.13 runs (ReduceSumSquare still takes its axes as an attribute in 17).
TARGET_OPSET = {"": 17, "ai.onnx.ml": 3}

_VERSIONED = ("monodock", "scikit-learn", "skl2onnx", "onnx", "onnxruntime", "numpy")


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
    """The serialized ONNX model of a fitted monodock estimator (see ``regressors.make_regressor``).

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


def _entry(task: TaskResult, file: str | None, digest: str | None, size: int | None) -> ModelEntry:
    best = task.best
    entry: ModelEntry = {
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
    out: str | os.PathLike[str], result: TrainingResult, *, metadata: BundleMetadata, force: bool = False
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
    with atomic_directory(out, force=force) as tmp:
        write_bundle(tmp, result, metadata=metadata)
    return Path(out)


def write_bundle(folder: Path, result: TrainingResult, *, metadata: BundleMetadata) -> None:
    """Write a bundle's files into an existing empty ``folder`` (``save_bundle`` without the atomic rename)."""
    try:
        meta: BundleMetadata = json.loads(json.dumps(dict(metadata), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise TypeError(f"bundle metadata must be JSON-serialisable: {exc}") from exc
    cfg, seg = result.config, result.config.segments
    sets: dict[str, SetEntry] = {}
    total = 0

    def write(task: TaskResult, file: str, n_features: int) -> ModelEntry:
        nonlocal total
        if task.estimator is None:
            return _entry(task, None, None, None)
        data = onnx_model_bytes(task.estimator, n_features)
        (folder / file).write_bytes(data)
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
    manifest: Manifest = {
        "schema_version": BUNDLE_SCHEMA_VERSION,
        "created": datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z"),
        "versions": _versions(),
        "metadata": meta,
        "targets": {"depth": "metres (DockPose x label)", "yaw": "degrees (DockPose yaw label)"},
        "onnx": {"input": INPUT_NAME, "dtype": "float32", "opset": TARGET_OPSET},
        "segments": {"start_m": seg.start_m, "width_m": seg.width_m, "count": seg.count},
        "train_config": {**{k: v for k, v in asdict(cfg).items() if k != "segments"}, "models": list(cfg.models)},
        "training": {"seconds": round(result.seconds, 3), "fits": result.n_fits, "jobs": result.jobs},
        "onnx_bytes": total,
        "sets": sets,
    }
    text = json.dumps(seal_manifest(manifest), indent=1, allow_nan=False) + "\n"
    (folder / BUNDLE_FILE).write_text(text, encoding="utf-8")


def update_bundle_metadata(path: str | os.PathLike[str], key: str, value: Any) -> None:
    """Add or replace one entry of a saved bundle's metadata; bundle.json is rewritten atomically.

    For what is learned after the models exist (the fused method's tables come from the models' answers).
    """
    mf = Path(path) / BUNDLE_FILE
    manifest: Manifest = json.loads(mf.read_text(encoding="utf-8"))
    # An existing key keeps its place in the file; a new one goes last.
    metadata: dict[str, Any] = {**manifest["metadata"], key: json.loads(json.dumps(value, allow_nan=False))}
    manifest["metadata"] = cast(BundleMetadata, metadata)
    write_text_atomic(mf, json.dumps(seal_manifest(manifest), indent=1, allow_nan=False) + "\n", force=True)
