"""What the regression costs per frame at run time, next to marker detection: features → DockPose.

Renders ``--frames`` frames of the charger (default nuisances), detects the markers, and trains the papers'
models on a labelled simulated drive (``--train-stops`` stops, one draw per model: the cost of a model does not
depend on how well it was tuned) or loads them from ``--dataset``. Then, per frame, on one thread:

- detection: ``MarkerDetector.detect`` (OpenCV ArUco, SUBPIX corners), the cost the estimate adds to;
- regression with ONNX Runtime: ``RegressionEstimator.estimate`` from the detection (raw features → model
  inputs → depth model → the segment's angle model → back-projected lateral), the bundle as shipped;
- the same estimator with scikit-learn ``predict`` on the same single rows (the fitted models in memory);
- the model calls alone (depth + angle), ONNX Runtime against scikit-learn.

Prints medians and the ratios measured in this one run. Run from the repo root:

    python bench/regression_speed.py [--frames 300] [--train-stops 1500] [--dataset D.parquet] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from _common import emit, environment, markdown_table
from monodock.estimation.bundle import Bundle
from monodock.estimation.regression import RegressionEstimator
from monodock.estimation.segments import SegmentTable
from monodock.learning.dataset import label_recording, read_dataset
from monodock.learning.export import save_bundle
from monodock.learning.pipeline import bundle_metadata, training_sets
from monodock.learning.tasks import TrainConfig
from monodock.learning.train import TrainingResult, train
from monodock.perception.detect import MarkerDetector
from monodock.perception.features import DEFAULT_MARKER_SETS, MARKER_SETS, MODEL_FEATURE_SCHEMA, model_feature_names
from monodock.sim import Nuisances, PoseDistribution, Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording


class SklearnModels:
    """The Bundle interface over the fitted scikit-learn models of a TrainingResult (what ONNX replaces)."""

    def __init__(self, result: TrainingResult) -> None:
        self.result = result
        self.sets = tuple(s.name for s in result.sets)
        self.segments: SegmentTable = result.config.segments

    def predict_depth(self, set_name: str, X: np.ndarray) -> np.ndarray:
        return np.asarray(self.result.set(set_name).depth.estimator.predict(np.atleast_2d(X).astype(np.float32)))

    def has_angle_model(self, set_name: str, segment: int) -> bool:
        return self.result.set(set_name).angle[segment].estimator is not None

    def predict_yaw_deg(self, set_name: str, segment: int, X: np.ndarray) -> np.ndarray:
        model = self.result.set(set_name).angle[segment].estimator
        return np.asarray(model.predict(np.atleast_2d(X).astype(np.float32)))


def _median_us(fn: Any, items: list[Any], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        for item in items:
            t = time.perf_counter()
            fn(item)
            times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e6


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300, help="frames to time on (default 300)")
    p.add_argument("--train-stops", type=int, default=1500, help="stops of the training drive (default 1500)")
    p.add_argument("--dataset", help="train on this labelled dataset instead of simulating a drive")
    p.add_argument("--repeat", type=int, default=5, help="passes over the frames for each timing (default 5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="also write the markdown here")
    args = p.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        if args.dataset:
            ds = read_dataset(args.dataset)
        else:
            sim = Simulator(nuisances=Nuisances().updated(supersample=4), seed=args.seed)
            stops = plan_drive(sim, DriveConfig(stops=args.train_stops), np.random.default_rng(args.seed))
            print(f"simulating a {args.train_stops}-stop training drive ...", file=sys.stderr)
            write_recording(Path(tmp) / "rec", sim, stops, seed=args.seed, jobs=2)
            ds, _, _ = label_recording(Path(tmp) / "rec", sim.layout)
        sets = training_sets(ds, DEFAULT_MARKER_SETS)
        result = train(sets, TrainConfig(trials=1, seed=args.seed, jobs=2))
        meta = bundle_metadata(ds, depth_label="point", angle_label="line", source="bench")
        save_bundle(Path(tmp) / "bundle", result, metadata=meta)
        bundle = Bundle.load(
            Path(tmp) / "bundle",
            expected_feature_names={s: model_feature_names(s) for s in MARKER_SETS},
            feature_schema=MODEL_FEATURE_SCHEMA,
        )

        sim = Simulator(seed=args.seed + 1)
        det = MarkerDetector(sim.layout)
        dist = PoseDistribution()
        images = [
            sim.frame(sim.sample_pose(dist), 0.0, np.random.default_rng([args.seed, i])).image
            for i in range(args.frames)
        ]
        detections = [det.detect(im) for im in images]
        onnx = RegressionEstimator(bundle, sim.camera, sim.robot)
        skl = RegressionEstimator(SklearnModels(result), sim.camera, sim.robot)  # type: ignore[arg-type]
        valid = sum(onnx.estimate(d).valid for d in detections)
        same = [
            (a.pose, b.pose)
            for a, b in ((onnx.estimate(d), skl.estimate(d)) for d in detections)
            if a.pose is not None and b.pose is not None
        ]
        worst = max((max(abs(a.x - b.x), abs(a.y - b.y), abs(a.yaw - b.yaw)) for a, b in same), default=float("nan"))

        t_detect = _median_us(det.detect, images, 1)
        t_onnx = _median_us(onnx.estimate, detections, args.repeat)
        t_skl = _median_us(skl.estimate, detections, max(1, args.repeat // 5))
        # The model calls alone, on the rows the estimator would feed them.
        from monodock.perception.features import feature_vector, model_features

        rows = [model_features(feature_vector(d, sim.camera), sim.camera, "m2") for d in detections if d.seen("center")]
        t_model_onnx = _median_us(lambda x: bundle.predict_depth("m2", x), rows, args.repeat)
        t_model_skl = _median_us(lambda x: SklearnModels(result).predict_depth("m2", x), rows, max(1, args.repeat // 5))

    table = markdown_table(
        ["stage (one frame, one thread)", "median µs", "vs detection"],
        [
            ["marker detection (ArucoDetector, SUBPIX)", f"{t_detect:.0f}", "1.00"],
            ["regression estimate, ONNX Runtime (features → DockPose)", f"{t_onnx:.0f}", f"{t_onnx / t_detect:.3f}"],
            ["regression estimate, scikit-learn predict", f"{t_skl:.0f}", f"{t_skl / t_detect:.3f}"],
            ["depth model call alone, ONNX Runtime", f"{t_model_onnx:.1f}", f"{t_model_onnx / t_detect:.4f}"],
            ["depth model call alone, scikit-learn", f"{t_model_skl:.1f}", f"{t_model_skl / t_detect:.4f}"],
        ],
    )
    chosen = {s.name: s.depth.chosen for s in result.sets}
    text = (
        f"{table}\n\n"
        f"ONNX / scikit-learn, whole estimate: {t_skl / t_onnx:.1f}x faster; {valid}/{len(detections)} frames valid; "
        f"largest ONNX vs scikit-learn difference in x, y (m) or yaw (rad): {worst:.2e}. "
        f"Chosen depth models: {chosen}.\n\n{environment()}"
    )
    raw = {
        "detect_us": t_detect,
        "regression_onnx_us": t_onnx,
        "regression_sklearn_us": t_skl,
        "depth_model_onnx_us": t_model_onnx,
        "depth_model_sklearn_us": t_model_skl,
        "frames": len(detections),
        "valid": valid,
        "max_difference": worst,
        "environment": environment(),
    }
    emit(text, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
