"""``monodock evaluate``: every method on a held-out recording against the LiDAR labels and the truth, or, with
``--robustness``, against one simulated nuisance or calibration error at a time."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from monodock.cli.label import label
from monodock.cli.options import (
    SubParsers,
    add_cluster,
    add_command,
    add_jobs,
    add_seed,
    add_topics,
    bundle_calibration,
    int_in,
    jobs,
)
from monodock.core.atomic import atomic_directory, check_writable
from monodock.errors import InputError
from monodock.estimation.bundle import load_bundle
from monodock.estimation.methods import MethodSetup, build_methods
from monodock.evaluation.heldout import evaluate_heldout, reference_poses
from monodock.evaluation.robustness import RobustnessConfig, run_robustness
from monodock.learning.dataset import read_dataset
from monodock.report.evaluation import write_evaluation_report
from monodock.report.robustness import write_robustness_report
from monodock.sim.render import MAX_SUPERSAMPLE

__all__ = ["add_parser", "run"]


def add_parser(subparsers: SubParsers) -> None:
    """Add ``evaluate``."""
    ev = add_command(subparsers, "evaluate", run)
    ev.add_argument(
        "recording",
        nargs="?",
        help="held-out recording, or a dataset .parquet from monodock label (not with --robustness)",
    )
    ev.add_argument("--model", required=True, help="model bundle directory")
    ev.add_argument("--out", required=True, help="report folder")
    ev.add_argument("--camera", help="camera file, instead of the recording's CameraInfo")
    ev.add_argument("--robot", help="robot YAML, instead of the bundle's mounts")
    ev.add_argument("--layout", help="dock layout YAML (must match the bundle's)")
    ev.add_argument("--force", action="store_true", help="replace an existing report folder")
    g = ev.add_argument_group("robustness (--robustness: simulated test frames instead of a recording)")
    g.add_argument(
        "--robustness",
        action="store_true",
        help="sweep image nuisances (noise, blur, exposure, occlusion) and calibration errors (focal, marker "
        "size, camera mount) one at a time and plot every method's error against each",
    )
    g.add_argument(
        "--frames", type=int_in(1, 100_000), help="test poses, the same at every level, 1-100000 (default 300)"
    )
    g.add_argument(
        "--calibration-frames",
        type=int_in(50, 100_000),
        help="LiDAR-labelled frames the fused tables are re-learned from, 50-100000 (300)",
    )
    add_seed(g, "seed of the poses and of every frame's draws (default 0)", default=None)
    g.add_argument(
        "--supersample",
        type=int_in(1, MAX_SUPERSAMPLE),
        help=f"S, 1-{MAX_SUPERSAMPLE}: test frames' pixels where three surfaces meet get SxS samples (default 16)",
    )
    add_jobs(g)
    add_cluster(g)
    add_topics(ev)


def _inputs(args: argparse.Namespace) -> tuple[str | None, ...]:
    """What ``evaluate`` reads: its --out must be none of these (nor a folder holding one)."""
    return (args.recording, args.model, args.camera, args.robot, args.layout)


def _robustness(args: argparse.Namespace) -> int:
    """``evaluate --robustness``: simulated test frames, one nuisance or calibration error at a time."""
    if args.recording is not None:
        raise InputError(f"--robustness simulates its own frames: drop the recording '{args.recording}'")
    for flag, value, least in (
        ("--frames", args.frames, 1),
        ("--calibration-frames", args.calibration_frames, 50),
    ):
        if value is not None and value < least:
            raise InputError(f"{flag} must be at least {least}, got {value}")
    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    check_writable(args.out, force=args.force, inputs=_inputs(args))
    bundle = load_bundle(args.model)
    camera, layout, robot = bundle_calibration(args, bundle)
    config = RobustnessConfig(
        frames=args.frames or 300,
        calibration_frames=args.calibration_frames or 300,
        seed=args.seed or 0,
        jobs=jobs(args.jobs),
        supersample=args.supersample or RobustnessConfig.supersample,
    )
    result = run_robustness(Path(args.model), camera, layout, robot, config)
    with atomic_directory(args.out, force=args.force) as out:
        write_robustness_report(result, out)
    for row in result.summary().headline:
        f, b = row.worst["fused"], row.worst["board"]
        print(
            f"{row.axis:12s} worst: fused {f.depth_mae_cm:.2f} cm / {f.lateral_mae_cm:.2f} cm / "
            f"{f.yaw_mae_deg:.2f} deg, board {b.depth_mae_cm:.2f} cm / {b.lateral_mae_cm:.2f} cm / "
            f"{b.yaw_mae_deg:.2f} deg"
        )
    print(f"report: {Path(args.out) / 'report.html'} ({result.runtime_s:.0f} s)")
    return 0


def run(args: argparse.Namespace) -> int:
    """every method on a held-out recording against LiDAR labels and truth; --robustness: against one simulated nuisance
    or calibration error at a time"""
    if args.robustness:
        return _robustness(args)
    if args.recording is None:
        raise InputError("give the held-out RECORDING (or a dataset .parquet), or --robustness")
    extra = [
        f
        for f, v in (
            ("--frames", args.frames),
            ("--calibration-frames", args.calibration_frames),
            ("--seed", args.seed),
            ("--supersample", args.supersample),
            ("--jobs", args.jobs),
            ("--cluster", args.cluster),
        )
        if v is not None
    ]
    if extra:
        raise InputError(f"{extra[0]} only applies with --robustness")
    # Before the labelling, which takes minutes: the report folder must be free (or --force) and no input.
    check_writable(args.out, force=args.force, inputs=_inputs(args))
    bundle = load_bundle(args.model)
    camera, layout, robot = bundle_calibration(args, bundle)
    if str(args.recording).endswith(".parquet"):
        ds = read_dataset(args.recording)
    else:
        ds = label(args, layout, camera if args.camera else None)
    # A row counts only with a whole, finite reference pose: an all-NaN dataset would give empty tables and exit 0.
    if not any(np.isfinite(ref).all(axis=1).any() for ref in reference_poses(ds).values()):
        raise InputError(
            f"{args.recording}: no row has a finite LiDAR label or the truth (x, y, yaw): nothing to evaluate against"
        )
    learnt = ("regression", "fused") if bundle.has_fusion_tables else ("regression",)
    if not bundle.has_fusion_tables:
        print("note: the bundle has no fusion tables (trained before the fused method); fused is left out")
    methods = build_methods(learnt, MethodSetup(ds.camera(), layout, robot, bundle))
    with atomic_directory(args.out, force=args.force) as out:
        result = evaluate_heldout(ds, methods)
        summary = result.summary()
        write_evaluation_report(out, result, summary, title=f"monodock evaluation: {args.recording}")
    for method, row in summary.overall.items():
        print(
            f"{method:10s} valid {row.valid}/{row.frames}  depth MAE {row.depth_mae_cm:.2f} cm  "
            f"lateral MAE {row.lateral_mae_cm:.2f} cm  yaw MAE {row.yaw_mae_deg:.2f} deg"
        )
    print(f"report: {Path(args.out) / 'report.html'}")
    return 0
