"""``monodock train``: the papers' seven regressors per 5 cm segment, best by MSE, into an ONNX model bundle."""

from __future__ import annotations

import argparse
from pathlib import Path

from monodock.cli.options import SubParsers, add_cluster, add_command, add_jobs, add_seed, float_in, int_in, jobs
from monodock.core.atomic import check_writable
from monodock.errors import MonodockError
from monodock.learning.dataset import read_dataset
from monodock.learning.pipeline import TrainOptions, corner_noise_px, train_bundle
from monodock.learning.train import TrainingResult
from monodock.perception.features import MARKER_SETS
from monodock.report.training import write_training_report

__all__ = ["add_parser", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``train``."""
    tr = add_command(subparsers, "train", run)
    tr.add_argument("dataset", help="dataset Parquet file from monodock label")
    tr.add_argument("--out", required=True, help="bundle directory to write")
    tr.add_argument(
        "--trials", type=int_in(1, 1000), default=10, help="hyperparameter draws per model, 1-1000 (default 10)"
    )
    tr.add_argument(
        "--sets",
        default="m1m2m3,m2",
        help="marker sets to train, comma-separated, from m1m2m3, m1m2, m2m3, m2 (default m1m2m3,m2)",
    )
    tr.add_argument("--depth-label", choices=("point", "line"), default="point", help="point: the papers' (default)")
    tr.add_argument("--angle-label", choices=("line", "endpoints"), default="line", help="endpoints: the papers'")
    tr.add_argument(
        "--fusion-holdout",
        type=float_in(0.0, 0.5, high_open=True),
        default=0.1,
        help="share of rows kept out of the regression to learn the fused method's tables from, in [0, 0.5) "
        "(0.1; 0: none)",
    )
    add_seed(tr)
    add_jobs(tr, "all cores")
    add_cluster(tr)
    tr.add_argument("--force", action="store_true", help="replace an existing bundle")


def _sets(value: str) -> tuple[str, ...]:
    names = tuple(v.strip() for v in value.split(",") if v.strip())
    bad = [n for n in names if n not in MARKER_SETS]
    if bad or not names:
        raise MonodockError(f"--sets: unknown marker set '{bad[0] if bad else value}' (from {', '.join(MARKER_SETS)})")
    if "m2" not in names:
        raise MonodockError("--sets must include m2: marker 2 alone is what the last half-metre of a docking sees")
    return names


def run(args: argparse.Namespace) -> int:
    """the papers' seven regressors per segment, best by MSE, into an ONNX bundle"""
    if args.trials < 1:
        raise MonodockError("--trials must be at least 1")
    if not 0.0 <= args.fusion_holdout < 0.5:
        raise MonodockError(f"--fusion-holdout must be in [0, 0.5), got {args.fusion_holdout}")
    options = TrainOptions(
        sets=_sets(args.sets),
        trials=args.trials,
        seed=args.seed,
        jobs=jobs(args.jobs) if args.jobs else 0,
        depth_label=args.depth_label,
        angle_label=args.angle_label,
        fusion_holdout=args.fusion_holdout,
        source=str(args.dataset),
    )
    check_writable(args.out, force=args.force, inputs=(args.dataset,))
    ds = read_dataset(args.dataset)

    # The pipeline (learning.pipeline), with the training report inside the bundle.
    def report(folder: Path, result: TrainingResult) -> None:
        write_training_report(folder / "report", result, title=f"monodock training report: {args.dataset}")

    trained = train_bundle(ds, args.out, options, force=args.force, add_files=report)
    if trained.tables is not None:
        print(
            f"fused method: tables learned on {trained.holdout_rows} held-out rows "
            f"(corner noise {corner_noise_px(trained.tables):.3f} px on a 50 px marker)"
        )
    print(
        f"trained in {trained.seconds:.0f} s; bundle {trained.onnx_bytes / 1e6:.1f} MB -> {trained.path} "
        f"(report: {trained.path / 'report'})"
    )
    return 0
