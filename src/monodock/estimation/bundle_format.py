"""The shape of a bundle's ``bundle.json``: what ``learning.export`` writes and ``estimation.bundle`` reads.

One set of ``TypedDict``s for both sides, so a key added to or renamed in the writer is a type error in the
reader. They describe the JSON as written (field order is the order written); reading still checks the parts a
hand-edited file could get wrong (``estimation.bundle``). The calibration records in the metadata (camera,
layout, robot) and the fused method's tables are those files' own formats, read by their own readers.
"""

from __future__ import annotations

from typing import Any, NotRequired, TypedDict

__all__ = [
    "BundleMetadata",
    "CandidateScores",
    "Manifest",
    "ModelEntry",
    "OnnxFormat",
    "SegmentsEntry",
    "SetEntry",
    "TrainingFacts",
]


class CandidateScores(TypedDict):
    """One tried model type's test scores (null for NaN or infinite)."""

    mse: float | None
    r2: float | None


class ModelEntry(TypedDict):
    """One model of a marker set (its depth model or a segment's angle model); ``file`` is null without one."""

    file: str | None
    model: str | None
    params: dict[str, Any] | None
    mse: float | None
    r2: float | None
    n_train: int
    n_test: int
    n_own: int
    n_rows: int
    borrowed: list[int] | None
    sha256: str | None
    bytes: int | None
    candidates: dict[str, CandidateScores]
    segment: NotRequired[int]  # angle models only
    reason: NotRequired[str]  # why there is no model (file null only)


class SetEntry(TypedDict):
    """One marker set: its models' input columns, rows, the depth model and one angle entry per segment."""

    feature_names: list[str]
    n_rows: int
    depth: ModelEntry
    yaw: list[ModelEntry]


class SegmentsEntry(TypedDict):
    """The angle models' depth segments (``estimation.segments.SegmentTable``'s fields)."""

    start_m: float
    width_m: float
    count: int


class OnnxFormat(TypedDict):
    """The models' input name, type and opsets."""

    input: str
    dtype: str
    opset: dict[str, int]


class TrainingFacts(TypedDict):
    """How long training took, how many fits, on how many workers."""

    seconds: float
    fits: int
    jobs: int


class BundleMetadata(TypedDict, total=False):
    """What the models were trained with (``learning.pipeline.bundle_metadata``), plus the fused method's tables.

    Every key is optional in the type: a bundle lacking one is refused where it is needed, naming it.
    """

    feature_schema: str
    raw_features: list[str]
    layout: dict[str, Any]
    camera: dict[str, Any]
    robot: dict[str, Any]
    depth_label: str
    angle_label: str
    depth_definition: str
    label_depth_range_m: list[float] | None
    dataset: str
    dataset_rows: int
    fusion_holdout_rows: int
    fusion: dict[str, Any]


class Manifest(TypedDict):
    """``bundle.json``: the versions, metadata, training facts and marker sets; its digest last."""

    schema_version: int
    created: str
    versions: dict[str, str]
    metadata: BundleMetadata
    targets: dict[str, str]
    onnx: OnnxFormat
    segments: SegmentsEntry
    train_config: dict[str, Any]
    training: TrainingFacts
    onnx_bytes: int
    sets: dict[str, SetEntry]
    manifest_sha256: NotRequired[str]  # set by seal_manifest
