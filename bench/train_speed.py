"""Training and prediction cost of the regression models: the full 315-model selection, bundle, one-row latency.

Builds a synthetic training set of ``--rows`` rows (default 20,000) for one marker set with 20 realistic
features: the four side lengths and the centre of each of the three dock markers and marker 2's centre offset,
from an exact pinhole projection (600 px focal length, 640x480) of the charger at random poses with 0.3 px
corner noise. Depths follow the uneven per-segment sample counts of the Sensors 2025 paper's Table 2 (scaled
to ``--rows``; its 245-250 cm segment has none), yaw is uniform in ±30°, the lateral offset within ±30 % of
the depth. Then:

(a) times ``monodock.learning.train.train`` with the papers' search (1 depth + 45 angle tasks × 7 model types × up to
    10 draws) on ``--jobs`` worker processes;
(b) times ``monodock.learning.export.save_bundle`` (ONNX export) and reports the bundle's size on disk;
(c) times ``Bundle.load`` (checksums + ONNX Runtime sessions);
(d) times one-row prediction through the loaded Bundle (depth, and the first segment's angle model), and, for
    each model type, refits the type's best depth hyperparameters on all rows (SVR: the first 4,000) and times
    one-row prediction, median over ``--calls`` calls: ONNX Runtime (1 thread, the bundle's session options)
    vs scikit-learn ``predict`` on the same float32 row, pinned to one CPU with one BLAS thread.

With ``--cli DATASET.parquet`` it instead times ``monodock train DATASET.parquet`` end to end (a subprocess: imports,
the selection, ONNX export, the fused tables, the report with its figures) beside the issue-24 target of 60 s for a
3,000-row labelled drive (make one with ``monodock simulate --format rosbag2 --frames 3000 --seed 1`` and
``monodock label``; it is simulated, not synthesised), and with ``--compare BUNDLE`` checks that the new bundle chose
the same model type with the same parameters and test metrics (every candidate's too) in every segment.

Run from the repo root:

    python bench/train_speed.py [--rows 20000] [--jobs 2] [--seed 0] [--out FILE.md]
    python bench/train_speed.py --cli DATASET.parquet [--compare OLD_BUNDLE]   # monodock train's wall time vs 60 s
    python bench/train_speed.py --dataset DATASET.parquet [--set m1m2m3]   # the real features of a labelled drive
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from _common import emit, environment, fmt, markdown_table
from monodock.estimation.bundle import Bundle, bundle_size_bytes, ort_session
from monodock.learning.dataset import read_dataset
from monodock.learning.export import onnx_model_bytes, save_bundle
from monodock.learning.pipeline import training_sets
from monodock.learning.regressors import MODEL_NAMES, make_regressor
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import train

# Samples per 5 cm segment from 25 cm in the paper's Table 2 (the 245-250 cm segment is not listed: none).
PAPER_SEGMENT_COUNTS = [
    69, 276, 335, 431, 429, 428, 366, 460, 577, 494, 442, 338, 369, 469, 433, 957, 982, 853, 977, 934, 703, 909,
    705, 598, 396, 458, 193, 138, 117, 101, 23, 21, 18, 49, 83, 63, 61, 93, 49, 9, 7, 8, 10, 47, 0,
]  # fmt: skip

FOCAL_PX = 600.0
CENTRE_PX = (320.0, 240.0)
MARKER_SIZE = 0.10
MARKERS_Y = (0.20, 0.0, -0.20)  # left, centre, right, in the dock frame (y left)
MARKER_Z = 0.30
CAMERA_Z = 0.25
CORNER_NOISE_PX = 0.3


def _side(uv: np.ndarray, a: int, b: int) -> np.ndarray:
    """Pixel length of the side from corner a to corner b of each row's marker."""
    return np.linalg.norm(uv[:, a] - uv[:, b], axis=1)


def synthetic_set(rows: int, seed: int) -> TrainingSet:
    """A one-set training table with 20 features from projected marker corners, the paper's depth histogram."""
    rng = np.random.default_rng(seed)
    counts = np.asarray(PAPER_SEGMENT_COUNTS, dtype=np.float64)
    per_seg = np.floor(counts / counts.sum() * rows).astype(int)
    per_seg[np.argmax(per_seg)] += rows - per_seg.sum()
    depth = np.concatenate([rng.uniform(0.25 + 0.05 * k, 0.30 + 0.05 * k, n) for k, n in enumerate(per_seg)])
    n = len(depth)
    yaw = np.radians(rng.uniform(-30.0, 30.0, n))
    lateral = rng.uniform(-0.3, 0.3, n) * depth
    # Corners of each marker in the dock frame (x into the charger, y left, z up), as seen from the robot.
    h = MARKER_SIZE / 2
    offsets = np.array([[h, h], [-h, h], [-h, -h], [h, -h]])  # tl, tr, br, bl: (dy, dz) with y left
    names: list[str] = []
    cols: list[np.ndarray] = []
    c, s = np.cos(yaw), np.sin(yaw)
    for m, y_m in enumerate(MARKERS_Y, start=1):
        uv = np.empty((n, 4, 2))
        for j, (dy, dz) in enumerate(offsets):
            py = y_m + dy
            # Dock point (0, py, z) in the camera body frame (x forward, y left): rotate by yaw, translate.
            X = depth + (-s * py)
            Y = lateral + c * py
            Z = MARKER_Z + dz - CAMERA_Z
            uv[:, j, 0] = CENTRE_PX[0] - FOCAL_PX * Y / X
            uv[:, j, 1] = CENTRE_PX[1] - FOCAL_PX * Z / X
        uv += rng.normal(0.0, CORNER_NOISE_PX, uv.shape)
        for label, col in (
            ("top", _side(uv, 0, 1)),
            ("bottom", _side(uv, 3, 2)),
            ("left", _side(uv, 0, 3)),
            ("right", _side(uv, 1, 2)),
            ("centre_u", uv[:, :, 0].mean(axis=1)),
            ("centre_v", uv[:, :, 1].mean(axis=1)),
        ):
            names.append(f"m{m}_{label}")
            cols.append(col)
        if m == 2:
            centre_u, centre_v = cols[-2], cols[-1]
    names += ["m2_offset_u", "m2_offset_v"]
    cols += [centre_u - CENTRE_PX[0], centre_v - CENTRE_PX[1]]
    X = np.column_stack(cols)
    # Labels as a LiDAR gives them: ~7 mm depth noise, ~0.5° angle noise.
    depth_label = depth + rng.normal(0.0, 0.007, n)
    yaw_label = np.degrees(yaw) + rng.normal(0.0, 0.5, n)
    return TrainingSet("m1m2m3", tuple(names), X, depth_label, yaw_label, depth)


def _median_us(fn: Any, calls: int) -> float:
    for _ in range(20):  # warm-up
        fn()
    t = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        t[i] = time.perf_counter() - t0
    return float(np.median(t) * 1e6)


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


TARGET_CLI_S = 60.0
_COMPARED = ("model", "params", "mse", "r2", "n_train", "n_test", "n_own", "n_rows", "borrowed", "candidates", "sha256")


def compare_bundles(old: Path, new: Path) -> list[str]:
    """Every difference between two bundles' chosen models, parameters, metrics and ONNX checksums, per task."""
    a, b = (json.loads((p / "bundle.json").read_text(encoding="utf-8"))["sets"] for p in (old, new))
    if set(a) != set(b):
        return [f"marker sets differ: {sorted(a)} vs {sorted(b)}"]
    out = []
    for name in a:
        pairs = [(a[name]["depth"], b[name]["depth"]), *zip(a[name]["yaw"], b[name]["yaw"], strict=True)]
        for ea, eb in pairs:
            out += [
                f"{name} {ea.get('segment', 'depth')} {k}: {ea.get(k)} vs {eb.get(k)}"
                for k in _COMPARED
                if ea.get(k) != eb.get(k)
            ]
    return out


def cli_main(args: argparse.Namespace) -> int:
    """Time ``monodock train`` on a labelled dataset end to end, beside the target; compare with an older bundle."""
    with tempfile.TemporaryDirectory() as tmp:
        bundle = Path(tmp) / "bundle"
        cmd = [sys.executable, "-m", "monodock.cli.main", "train", args.cli, "--out", str(bundle)]
        cmd += ["--trials", str(args.trials), "--seed", str(args.seed), "--jobs", str(args.jobs)]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        cpu = os.times().children_user + os.times().children_system
        rows = json.loads((bundle / "bundle.json").read_text(encoding="utf-8"))["metadata"]["dataset_rows"]
        diffs = compare_bundles(Path(args.compare), bundle) if args.compare else None
    env = environment()
    lines = [
        f"### `monodock train` on {rows} rows of {args.cli}",
        "",
        f"`python bench/train_speed.py --cli {args.cli} --jobs {args.jobs} --trials {args.trials} --seed {args.seed}`"
        f" — {env['date_utc']} UTC, {env['machine']}.",
        "",
        markdown_table(
            ["stage", "value"],
            [
                [f"monodock train, wall (s; target ≤ {TARGET_CLI_S:g})", fmt(wall, 1)],
                ["CPU of the command and its workers (s)", fmt(cpu, 1)],
            ],
        ),
    ]
    if diffs is not None:
        lines += ["", f"Against {args.compare}: " + ("identical choices and metrics" if not diffs else "DIFFERENT:")]
        lines += [f"- {d}" for d in diffs[:50]]
    raw = {"benchmark": "train_speed_cli", "args": vars(args), "environment": env, "wall_seconds": wall}
    raw |= {"cpu_seconds": cpu, "target_seconds": TARGET_CLI_S, "differences": diffs}
    emit("\n".join(lines), raw, args.out)
    return 0 if not diffs else 1


SVR_FIT_ROWS = 4000  # SVR's fit is O(n²): its latency is timed on a model fit on at most this many rows


def _latency_per_model(ts: Any, sr: Any, row: np.ndarray, calls: int) -> dict[str, dict[str, float]]:
    """Per model type, one-row latency on one CPU (ONNX Runtime and scikit-learn): the depth task, the type's
    first hyperparameter draw."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from threadpoolctl import threadpool_limits

    X32 = ts.X.astype(np.float32)
    latency: dict[str, dict[str, float]] = {}
    fit_rows = min(len(X32), SVR_FIT_ROWS)
    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Lasso's convergence warnings: the fit is only timed here
        for model in MODEL_NAMES:
            params = sr.depth.scores[model].params
            est = make_regressor(model, params, 0)
            n_fit = fit_rows if model == "svr" else len(X32)
            est.fit(X32[:n_fit].astype(np.float64), ts.depth[:n_fit])
            sess = ort_session(onnx_model_bytes(est, X32.shape[1]))
            out_name = sess.get_outputs()[0].name
            t_onnx = _median_us(lambda sess=sess, out_name=out_name: sess.run([out_name], {"input": row}), calls)
            t_skl = _median_us(lambda est=est: est.predict(row), max(100, calls // 10))
            latency[model] = {"onnx_us": t_onnx, "sklearn_us": t_skl, "ratio": t_skl / t_onnx}
    return latency


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--rows", type=_positive, default=20000, help="synthetic training rows (default 20000)")
    p.add_argument("--jobs", type=_positive, default=2, help="training worker processes (default 2)")
    p.add_argument("--trials", type=_positive, default=10, help="draws per model type and task (default 10)")
    p.add_argument("--calls", type=_positive, default=2000, help="one-row calls to time per model (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the data and the training (default 0)")
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    p.add_argument("--dataset", help="time on this labelled dataset (monodock label) instead of synthetic rows")
    p.add_argument("--set", default="m1m2m3", help="with --dataset: the marker set to train (default m1m2m3)")
    p.add_argument("--cli", metavar="DATASET", help="time `monodock train DATASET` end to end against the 60 s target")
    p.add_argument("--compare", metavar="BUNDLE", help="with --cli: the same choices and metrics as this bundle?")
    args = p.parse_args(argv)

    if args.cli:
        return cli_main(args)
    if args.dataset:
        ts = training_sets(read_dataset(args.dataset), (args.set,))[0]
    else:
        ts = synthetic_set(args.rows, args.seed)
    config = TrainConfig(trials=args.trials, seed=args.seed, jobs=args.jobs)
    t0 = time.perf_counter()
    result = train([ts], config)
    train_s = time.perf_counter() - t0
    sr = result.sets[0]
    chosen = [sr.depth.chosen] + [t.chosen for t in sr.angle]

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bundle"
        t0 = time.perf_counter()
        save_bundle(out, result, metadata={"feature_schema": "bench-synthetic/1"})
        save_s = time.perf_counter() - t0
        size = bundle_size_bytes(out)
        n_files = len(list(out.glob("*.onnx")))
        t0 = time.perf_counter()
        bundle = Bundle.load(out, expected_feature_names={ts.name: ts.feature_names})
        load_s = time.perf_counter() - t0
        row = ts.X[:1].astype(np.float32)
        t_bundle_depth = _median_us(lambda: bundle.predict_depth(ts.name, row[0]), args.calls)
        seg = next(k for k, t in enumerate(sr.angle) if t.chosen is not None)
        t_bundle_yaw = _median_us(lambda: bundle.predict_yaw_deg(ts.name, seg, row[0]), args.calls)

    latency = _latency_per_model(ts, sr, row, args.calls)

    mb = size / 1e6
    env = environment()
    n_models = sum(c is not None for c in chosen)
    data = (
        f"{len(ts.depth)} rows of {args.dataset}, marker set {ts.name}, {len(ts.feature_names)} features"
        if args.dataset
        else f"synthetic {len(ts.feature_names)}-feature set, the paper's depth histogram"
    )
    command = f"--dataset {args.dataset} --set {args.set}" if args.dataset else f"--rows {args.rows}"
    lines = [
        f"### Training and one-row prediction cost ({data})",
        "",
        f"`python bench/train_speed.py {command} --jobs {args.jobs} --trials {args.trials} "
        f"--seed {args.seed}` — {env['date_utc']} UTC, {env['machine']}, numpy {env['numpy']}. "
        f"{result.n_fits} fits over {1 + len(sr.angle)} tasks; {n_models} models chosen "
        f"({sum(c is None for c in chosen)} segments without a model).",
        "",
        markdown_table(
            ["stage", "value"],
            [
                [f"(a) train: full selection, {args.jobs} workers (s)", fmt(train_s, 1)],
                ["(a) sum of all fits' wall times (s)", fmt(result.fit_seconds, 1)],
                ["(a) sum of all fits' CPU times (s)", fmt(result.fit_cpu_seconds, 1)],
                ["(b) save_bundle: ONNX export + write (s)", fmt(save_s, 2)],
                [f"(b) bundle size on disk (MB, {n_files} .onnx files)", fmt(mb, 2)],
                ["(c) Bundle.load: checksums + sessions (s)", fmt(load_s, 3)],
                [f"(d) Bundle.predict_depth, one row, chosen {sr.depth.chosen} (µs)", fmt(t_bundle_depth, 1)],
                [
                    f"(d) Bundle.predict_yaw_deg, one row, segment {seg} {sr.angle[seg].chosen} (µs)",
                    fmt(t_bundle_yaw, 1),
                ],
            ],
        ),
        "",
        f"One-row latency per model type (depth task, the type's best draw; SVR fit on "
        f"{min(len(ts.X), SVR_FIT_ROWS)} rows), "
        f"median of {args.calls} calls, one CPU, one thread:",
        "",
        markdown_table(
            ["model", "ONNX Runtime µs", "sklearn predict µs", "sklearn / ONNX"],
            [[m, fmt(v["onnx_us"], 1), fmt(v["sklearn_us"], 1), fmt(v["ratio"], 1)] for m, v in latency.items()],
        ),
        "",
        "Depth task (test split): "
        + ", ".join(f"{m} {fmt(math.sqrt(sc.mse) * 100, 2)} cm RMS" for m, sc in sr.depth.scores.items())
        + f"; chosen {sr.depth.chosen}.",
    ]
    raw = {
        "benchmark": "train_speed",
        "args": vars(args),
        "environment": env,
        "train_seconds": train_s,
        "n_fits": result.n_fits,
        "save_seconds": save_s,
        "bundle_bytes": size,
        "load_seconds": load_s,
        "bundle_predict_depth_us": t_bundle_depth,
        "bundle_predict_yaw_us": t_bundle_yaw,
        "latency": latency,
        "chosen": chosen,
        "depth_scores": {m: {"mse": sc.mse, "r2": sc.r2} for m, sc in sr.depth.scores.items()},
    }
    emit("\n".join(lines), raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
