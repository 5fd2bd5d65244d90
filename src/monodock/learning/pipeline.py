"""The one train→bundle pipeline: a labelled dataset in, a verified model bundle out (``monodock train``).

1. keep a share of the rows out of the regression's training (``fusion.fusion_holdout``), for the fused tables;
2. the rows each marker set's models learn from (``training_sets``: valid labels, every marker of the set seen);
3. the papers' seven regressors per 5 cm segment, best by test MSE (``train.train``);
4. the models as ONNX files and ``bundle.json`` with the calibration and schema they need (``export``);
5. the fused method's tables, learned on the held-out rows through the saved models (``fusion.train_fusion``).

The whole bundle is written beside its final path and renamed into place at the end, so an interruption or an
error leaves nothing half-written. ``monodock train``, the demo and dock-sim's self-trained
bundles all call ``train_bundle``; the checks on the dataset live here, not in the callers.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monodock.core.atomic import atomic_directory
from monodock.core.camera import CameraModel
from monodock.core.settings import to_mapping
from monodock.errors import InputError
from monodock.estimation.bundle_format import BundleMetadata
from monodock.estimation.fused import FusionTables
from monodock.estimation.regression import ANGLE_LABELS, DEPTH_LABELS
from monodock.learning.dataset import Dataset
from monodock.learning.export import write_bundle
from monodock.learning.fusion import FUSION_FRACTION, fusion_holdout, train_fusion
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import TrainingResult, train
from monodock.perception.features import (
    DEFAULT_MARKER_SETS,
    FEATURE_NAMES,
    MARKER_SETS,
    MODEL_FEATURE_SCHEMA,
    model_feature_names,
    model_features,
)

__all__ = ["MIN_SET_ROWS", "TrainOptions", "TrainedBundle", "bundle_metadata", "train_bundle", "training_sets"]

# Fewer labelled rows than this for a marker set cannot fill 45 segments with anything worth a model.
MIN_SET_ROWS = 20


@dataclass(frozen=True)
class TrainOptions:
    """How to train a bundle (``monodock train``'s options).

    Attributes:
        sets: marker sets to train (``perception.features.MARKER_SETS``); m2 must be one of them.
        trials: hyperparameter draws per model type.
        seed: the seed of the split, the search and the fusion hold-out.
        jobs: worker processes for the fits (0: all cores).
        depth_label: "point" (the papers' nearest LiDAR point) or "line" (the whole-face line).
        angle_label: "line" (the whole-face line) or "endpoints" (the papers').
        fusion_holdout: share of the rows kept out of the regression to learn the fused tables (0: none).
        camera: train with this camera file instead of the dataset's (a robot whose camera file is wrong
            trains, and then runs, with that file).
        source: what the dataset is, for the bundle's metadata.
        progress: show a progress bar over the fits.
    """

    sets: tuple[str, ...] = DEFAULT_MARKER_SETS
    trials: int = 10
    seed: int = 0
    jobs: int = 0
    depth_label: str = "point"
    angle_label: str = "line"
    fusion_holdout: float = FUSION_FRACTION
    camera: CameraModel | None = None
    source: str = ""
    progress: bool = True

    def check(self) -> None:
        """InputError naming the first option that cannot work."""
        if self.trials < 1:
            raise InputError(f"trials must be at least 1, got {self.trials}")
        if not 0.0 <= self.fusion_holdout < 0.5:
            raise InputError(f"the fusion hold-out must be in [0, 0.5), got {self.fusion_holdout}")
        bad = [n for n in self.sets if n not in MARKER_SETS]
        if bad or not self.sets:
            raise InputError(f"unknown marker set '{bad[0] if bad else ''}' (from {', '.join(MARKER_SETS)})")
        if "m2" not in self.sets:
            raise InputError("the marker sets must include m2: marker 2 alone is what the last half-metre sees")
        if self.depth_label not in DEPTH_LABELS:
            raise InputError(f"depth label '{self.depth_label}' is not one of {', '.join(DEPTH_LABELS)}")
        if self.angle_label not in ANGLE_LABELS:
            raise InputError(f"angle label '{self.angle_label}' is not one of {', '.join(ANGLE_LABELS)}")


@dataclass(frozen=True)
class TrainedBundle:
    """What ``train_bundle`` made: the bundle folder, the training result, the fused tables and the time taken."""

    path: Path
    result: TrainingResult
    holdout_rows: int
    tables: FusionTables | None
    seconds: float

    @property
    def onnx_bytes(self) -> int:
        """The models' size on disk."""
        return sum(f.stat().st_size for f in self.path.glob("*.onnx"))


def training_sets(
    dataset: Dataset,
    set_names: tuple[str, ...],
    *,
    depth_label: str = "point",
    angle_label: str = "line",
    camera: CameraModel | None = None,
) -> list[TrainingSet]:
    """The rows each marker set's models learn from: valid labels, and every marker of the set seen.

    Features are computed with the dataset's own camera unless ``camera`` is given; the segment of a row is its
    depth label measured from the camera (the papers' depth), i.e. the label's x minus the camera mount's x.
    """
    robot = dataset.robot()
    camera = camera or dataset.camera()
    raw = dataset.raw_features()
    valid = np.asarray(dataset["label_valid"], dtype=bool)
    x = np.asarray(dataset[DEPTH_LABELS[depth_label]], dtype=np.float64)
    yaw = np.asarray(dataset[ANGLE_LABELS[angle_label]], dtype=np.float64)
    out = []
    for name in set_names:
        X = model_features(raw, camera, name)
        ok = valid & np.all(np.isfinite(X), axis=1) & np.isfinite(x) & np.isfinite(yaw)
        out.append(
            TrainingSet(
                name=name,
                feature_names=model_feature_names(name),
                X=X[ok],
                depth=x[ok],
                yaw_deg=yaw[ok],
                segment_depth=x[ok] - robot.camera_mount.x,
            )
        )
    return out


def bundle_metadata(dataset: Dataset, *, depth_label: str, angle_label: str, source: str) -> BundleMetadata:
    """What a bundle must carry besides its models: the calibration, layout, schema and label definitions."""
    x = np.asarray(dataset[DEPTH_LABELS[depth_label]], dtype=np.float64)
    ok = np.asarray(dataset["label_valid"], dtype=bool) & np.isfinite(x)
    cam_x = dataset.robot().camera_mount.x
    return {
        "feature_schema": MODEL_FEATURE_SCHEMA,
        "raw_features": list(FEATURE_NAMES),
        # Written from the validated objects, never copied from the file: nothing unknown travels on.
        "layout": to_mapping(dataset.layout()),
        "camera": dataset.camera().to_ros_dict(),
        "robot": to_mapping(dataset.robot()),
        "depth_label": DEPTH_LABELS[depth_label],
        "angle_label": ANGLE_LABELS[angle_label],
        "depth_definition": "targets: DockPose x (m) and yaw (deg) in base_link; segments: x minus camera_mount.x",
        "label_depth_range_m": [float(x[ok].min() - cam_x), float(x[ok].max() - cam_x)] if ok.any() else None,
        "dataset": source,
        "dataset_rows": len(dataset),
    }


def train_bundle(
    dataset: Dataset,
    out: str | os.PathLike[str],
    options: TrainOptions,
    *,
    force: bool = False,
    add_files: Callable[[Path, TrainingResult], None] | None = None,
) -> TrainedBundle:
    """Train a bundle on a labelled dataset and write it to ``out`` atomically (see the module docstring).

    Args:
        dataset: from ``monodock label`` (``learning.dataset``).
        out: the bundle folder to create.
        options: what to train and how.
        force: replace an existing ``out``.
        add_files: writes more files into the bundle folder before it is renamed into place (a report).

    Raises:
        InputError: bad options; ``out`` exists without ``force``; a dataset without refined corners when the
            fused tables are asked for; a marker set with fewer than MIN_SET_ROWS labelled rows.
    """
    options.check()
    where = options.source or "the dataset"
    holdout = (
        fusion_holdout(len(dataset), options.fusion_holdout, options.seed)
        if options.fusion_holdout > 0
        else np.zeros(len(dataset), dtype=bool)
    )
    if holdout.any() and not np.isfinite(dataset.refined_corners()).any():
        raise InputError(
            f"{where} has no refined corners (labelled by an older monodock): label it again, "
            "or train without the fused method's tables (fusion hold-out 0)"
        )
    sets = training_sets(
        dataset.subset(~holdout),
        options.sets,
        depth_label=options.depth_label,
        angle_label=options.angle_label,
        camera=options.camera,
    )
    for s in sets:
        if len(s.depth) < MIN_SET_ROWS:
            raise InputError(f"{where}: only {len(s.depth)} labelled rows with markers {s.name} seen; record more")
    meta = bundle_metadata(
        dataset, depth_label=options.depth_label, angle_label=options.angle_label, source=options.source
    )
    meta["fusion_holdout_rows"] = int(holdout.sum())
    if options.camera is not None:
        meta["camera"] = options.camera.to_ros_dict()
    t0 = time.perf_counter()
    with atomic_directory(out, force=force) as tmp:
        result = train(
            sets, TrainConfig(trials=options.trials, seed=options.seed, jobs=options.jobs), progress=options.progress
        )
        seconds = time.perf_counter() - t0
        write_bundle(tmp, result, metadata=meta)
        tables = train_fusion(tmp, dataset, holdout, camera=options.camera) if holdout.any() else None
        if add_files is not None:
            add_files(tmp, result)
    return TrainedBundle(Path(out), result, int(holdout.sum()), tables, seconds)


def corner_noise_px(tables: FusionTables, side_px: float = 50.0) -> float:
    """The corner noise the tables learned, in pixels on a marker ``side_px`` on a side (for a summary line)."""
    return tables.corner_sigma / math.sqrt(side_px)
