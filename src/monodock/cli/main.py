"""The ``monodock`` command line: sub-commands that mirror the pipeline (DESIGN.md)."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import numpy as np

from monodock.errors import MonodockError

if TYPE_CHECKING:
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.estimation.bundle import Bundle
    from monodock.estimation.estimator import Estimator, FrameEstimates
    from monodock.learning.dataset import Dataset
    from monodock.sim import Nuisances, PoseDistribution, SimFrame, Simulator

__all__ = ["main"]


# --- shared options -----------------------------------------------------------------------------


def _add_calibration(p: argparse.ArgumentParser, required: bool) -> None:
    p.add_argument("--camera", required=required, help="camera file: ROS camera_info YAML or OpenCV FileStorage")
    p.add_argument("--layout", required=required, help="dock layout YAML")
    p.add_argument("--robot", required=required, help="robot YAML (camera and LiDAR mounts, front_offset)")


def _load_calibration(args: argparse.Namespace) -> tuple[CameraModel, DockLayout, RobotConfig]:
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig

    camera = CameraModel.load(args.camera) if args.camera else CameraModel.default()
    layout = DockLayout.load(args.layout) if args.layout else DockLayout.default()
    robot = RobotConfig.load(args.robot) if args.robot else RobotConfig.default()
    return camera, layout, robot


def _add_nuisances(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("nuisances (defaults: a cheap indoor webcam)")
    g.add_argument("--clean", action="store_true", help="no nuisance at all: the exact render")
    g.add_argument("--read-noise", type=float, help="sensor read noise, 8-bit digital numbers")
    g.add_argument("--shot-noise", type=float, help="photon noise variance per digital number")
    g.add_argument("--defocus", type=float, help="lens blur sigma, pixels")
    g.add_argument("--motion-blur", type=float, help="motion streak length, pixels")
    g.add_argument("--exposure", type=float, help="exposure gain")
    g.add_argument("--exposure-jitter", type=float, help="per-frame log-normal spread of the exposure")
    g.add_argument("--gamma", type=float, help="display gamma (1: linear)")
    g.add_argument("--vignetting", type=float, help="relative fall-off at the image corners")
    g.add_argument("--occluder-probability", type=float, help="chance per frame of an object hiding a marker")
    g.add_argument("--no-clutter", action="store_true", help="no posters or foreign markers around the charger")
    g.add_argument("--supersample", type=int, help="S: edge pixels get SxS area samples (default 16; lower is faster)")
    g.add_argument("--side-walls", type=float, metavar="DIST", help="side walls DIST metres either side of the dock")


def _nuisances(args: argparse.Namespace) -> Nuisances:
    from monodock.sim import Nuisances

    n = Nuisances.clean() if args.clean else Nuisances()
    knobs = {
        "read_noise": args.read_noise,
        "shot_noise": args.shot_noise,
        "defocus_px": args.defocus,
        "motion_blur_px": args.motion_blur,
        "exposure": args.exposure,
        "exposure_jitter": args.exposure_jitter,
        "gamma": args.gamma,
        "vignetting": args.vignetting,
        "occluder_probability": args.occluder_probability,
    }
    changes: dict[str, object] = {k: v for k, v in knobs.items() if v is not None}
    for k, v in changes.items():
        if not (isinstance(v, float) and math.isfinite(v) and v >= 0):
            raise MonodockError(f"--{k.replace('_', '-')} must be a non-negative number, got {v}")
    if args.no_clutter:
        changes["clutter"] = False
    if args.supersample is not None:
        if args.supersample < 1:
            raise MonodockError(f"--supersample must be at least 1, got {args.supersample}")
        changes["supersample"] = args.supersample
    return n.updated(**changes)


def _range_option(p: argparse.ArgumentParser, flag: str, default: tuple[float, float], what: str) -> None:
    p.add_argument(
        flag,
        type=float,
        nargs=2,
        default=default,
        metavar=("MIN", "MAX"),
        help=f"{what} (default {default[0]:g} {default[1]:g})",
    )


def add_estimator_options(p: argparse.ArgumentParser, *, camera_help: str, robot_help: str) -> None:
    """The options of build_estimator, for the commands and nodes that estimate outside this parser."""
    p.add_argument("--model", help="model bundle (regression by default; carries camera, layout and mounts)")
    p.add_argument("--method", choices=("regression", "pnp", "board", "fused"))
    p.add_argument("--camera", help=camera_help)
    p.add_argument("--layout", help="dock layout YAML")
    p.add_argument("--robot", help=robot_help)
    p.add_argument("--refinement", choices=("none", "subpix", "contour"), default="subpix")
    p.add_argument("--image-topic", default="/camera/image_raw")
    p.add_argument("--compressed", action="store_true", help="the image topic is sensor_msgs/CompressedImage")


def _jobs(value: int | None) -> int:
    return value if value and value > 0 else max(1, min(4, os.cpu_count() or 1))


# --- simulate -----------------------------------------------------------------------------------


def _cmd_simulate(args: argparse.Namespace) -> int:
    from monodock.core.atomic import atomic_directory
    from monodock.estimation.estimator import Estimator
    from monodock.sim import PoseDistribution, RoomGeometry, Simulator
    from monodock.sim.export import FrameRecord, write_frame_folder

    camera, layout, robot = _load_calibration(args)
    if args.frames < 1:
        raise MonodockError("--frames must be at least 1")
    if args.preview < 0:
        raise MonodockError("--preview must not be negative")
    dist = PoseDistribution(depth=tuple(args.depth), lateral=tuple(args.lateral), yaw_deg=tuple(args.yaw))
    for name, (lo, hi) in (("depth", args.depth), ("lateral", args.lateral), ("yaw", args.yaw)):
        if not lo <= hi:
            raise MonodockError(f"--{name}: the first value must not exceed the second ({lo} > {hi})")
    room = RoomGeometry()
    if args.side_walls is not None:
        room = RoomGeometry(side_walls=args.side_walls)
    sim = Simulator(layout=layout, camera=camera, robot=robot, nuisances=_nuisances(args), room=room, seed=args.seed)
    try:
        poses = [sim.sample_pose(dist) for _ in range(args.frames)] if args.format == "folder" else []
    except RuntimeError as exc:
        raise MonodockError(str(exc)) from None
    previews: list[tuple[str, bytes]] = []
    estimator = Estimator(camera, layout, robot, ("board",))

    def preview(rec: FrameRecord) -> None:
        if rec.index < args.preview:
            result = estimator.estimate(rec.name, rec.stamp, rec.frame.image)
            previews.append((rec.name, _overlay_png(rec.frame.image, result, estimator, rec.frame.truth.corners)))

    t0 = time.perf_counter()
    if args.format == "rosbag2":
        return _simulate_recording(args, sim, estimator, dist)
    infos = write_frame_folder(
        args.out, sim, poses, seed=args.seed, jobs=_jobs(args.jobs), force=args.force, on_frame=preview
    )
    dt = time.perf_counter() - t0
    print(f"wrote {len(infos)} frames to {args.out} in {dt:.1f} s ({dt / len(infos) * 1000:.0f} ms/frame)")
    if previews:
        with atomic_directory(Path(args.out) / "preview", force=True) as tmp:
            for name, png in previews:
                (tmp / name).write_bytes(png)
        print(f"preview overlays: {Path(args.out) / 'preview'}")
    return 0


def _simulate_recording(args: argparse.Namespace, sim: Simulator, estimator: Estimator, dist: PoseDistribution) -> int:
    """``simulate --format rosbag2``: a stop-and-go data-collection drive written as a rosbag2 recording."""
    from monodock.core.atomic import atomic_directory
    from monodock.recording import write_recording
    from monodock.sim.drive import DriveConfig, plan_drive

    density: str | tuple[float, ...] = args.density
    if "," in args.density:
        try:
            density = tuple(float(w) for w in args.density.split(","))
        except ValueError:
            raise MonodockError(f"--density: not a list of numbers: {args.density}") from None
    config = DriveConfig(
        stops=args.frames,
        depth=dist.depth,
        lateral=dist.lateral,
        yaw_deg=dist.yaw_deg,
        density=density,
        camera_rate_hz=args.camera_rate,
        lidar_rate_hz=args.lidar_rate,
    )
    try:
        stops = plan_drive(sim, config, np.random.default_rng([args.seed, 2]))
    except RuntimeError as exc:
        raise MonodockError(str(exc)) from None
    previews: list[tuple[str, bytes]] = []

    def preview(index: int, frame: SimFrame) -> None:
        if index < args.preview:
            name = f"frame_{index:06d}.png"
            result = estimator.estimate(name, 0.0, frame.image)
            previews.append((name, _overlay_png(frame.image, result, estimator, frame.truth.corners)))

    t0 = time.perf_counter()
    summary = write_recording(
        args.out,
        sim,
        stops,
        seed=args.seed,
        jobs=_jobs(args.jobs),
        storage=args.storage,
        encoding=args.encoding,
        force=args.force,
        on_frame=preview,
    )
    dt = time.perf_counter() - t0
    print(
        f"wrote a {summary.duration_s:.0f} s recording ({summary.images} images, {summary.scans} scans, "
        f"{summary.bytes / 1e6:.0f} MB) to {args.out} in {dt:.1f} s"
    )
    if previews:
        target = Path(str(args.out).rstrip("/") + "_preview")
        with atomic_directory(target, force=True) as tmp:
            for name, png in previews:
                (tmp / name).write_bytes(png)
        print(f"preview overlays: {target}")
    return 0


def _overlay_png(
    image: np.ndarray,
    result: FrameEstimates,
    estimator: Estimator,
    truth_corners: dict[str, np.ndarray] | None = None,
) -> bytes:
    """The overlay of one estimated frame (its detection and board estimate), PNG-encoded."""
    import cv2

    from monodock.report.overlay import draw_overlay

    assert result.detection is not None
    pic = draw_overlay(
        image,
        result.detection,
        estimator.layout,
        estimator.camera,
        estimator.robot,
        result.estimates.get("board"),
        truth_corners,
    )
    ok, buf = cv2.imencode(".png", pic)
    if not ok:
        raise MonodockError("cannot encode the overlay PNG")
    return bytes(buf.tobytes())


def _summary(result: FrameEstimates, method: str = "board") -> str:
    e = result.estimates[method]
    return f"{e.pose}" if e.pose else e.reason


# --- estimate / show ----------------------------------------------------------------------------


def build_estimator(args: argparse.Namespace) -> tuple[Estimator, str]:
    """The Estimator and method of the ``--model`` / ``--method`` / ``--camera --layout --robot`` options.

    With a bundle: its camera, layout and mounts (``--camera``, ``--robot`` override; ``--layout`` must match)
    and the regression by default. Without one: a PnP method (board by default) on the three calibration files.
    """
    from monodock.estimation.estimator import Estimator

    extra = {}
    fused = None
    if args.model:
        from monodock.estimation.regression import RegressionEstimator

        bundle = _load_bundle(args.model)
        camera, layout, robot = _bundle_calibration(args, bundle)
        method = args.method or "regression"
        if method == "regression":
            extra["regression"] = RegressionEstimator(bundle, camera, robot).estimate
        elif method == "fused":
            from monodock.estimation.fused import FusedEstimator, fusion_tables_of

            regression = RegressionEstimator(bundle, camera, robot)
            fused = FusedEstimator(camera, layout, robot, fusion_tables_of(bundle), regression)
    else:
        if args.method in ("regression", "fused"):
            raise MonodockError(f"the {args.method} method needs --model BUNDLE")
        missing = [f"--{k}" for k in ("camera", "layout", "robot") if not getattr(args, k)]
        if missing:
            raise MonodockError(f"without --model, give {' '.join(missing)} (the PnP methods need the calibration)")
        camera, layout, robot = _load_calibration(args)
        method = args.method or "board"
    refinement = getattr(args, "refinement", "subpix")
    return Estimator(camera, layout, robot, (method,), refinement=refinement, extra=extra, fused=fused), method


def _cmd_estimate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from monodock.core.atomic import check_writable, write_text_atomic
    from monodock.errors import InputError
    from monodock.estimation.estimator import estimates_csv
    from monodock.io.frames import iter_frames

    est, method = build_estimator(args)
    check_writable(args.out, force=args.force)
    if args.bag:
        check_writable(args.bag, force=args.force)
    results = []
    for f in tqdm(
        iter_frames(args.inputs, skip_bad=args.skip_bad),
        desc="estimate",
        unit="frame",
        leave=False,
        disable=None,
    ):
        if f.image is None:
            results.append(est.failed(f.name, f.stamp, f.error))
            continue
        try:
            results.append(est.estimate(f.name, f.stamp, f.image))
        except InputError as exc:
            if not args.skip_bad:
                raise
            results.append(est.failed(f.name, f.stamp, str(exc)))
    text = estimates_csv(results)
    write_text_atomic(args.out, text, force=args.force)
    valid = sum(1 for r in results for e in r.estimates.values() if e.valid)
    print(f"{method}: {valid}/{len(results)} frames with an estimate -> {args.out}")
    if args.bag:
        import csv
        import io

        from monodock.recording.nav2 import write_pose_bag

        n = write_pose_bag(args.bag, csv.DictReader(io.StringIO(text)), force=args.force)
        print(f"{n} PoseStamped on detected_dock_pose (base_link) -> {args.bag}")
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from monodock.core.atomic import check_writable, write_bytes_atomic
    from monodock.estimation.estimator import Estimator
    from monodock.io.frames import read_image

    camera, layout, robot = _load_calibration(args)
    check_writable(args.out, force=args.force)
    image = read_image(args.image)
    estimator = Estimator(camera, layout, robot, ("board",))
    result = estimator.estimate(Path(args.image).name, math.nan, image)
    write_bytes_atomic(args.out, _overlay_png(image, result, estimator), force=args.force)
    print(f"board: {_summary(result)} -> {args.out}")
    return 0


# --- label / train / evaluate -------------------------------------------------------------------


def _add_topics(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("recording topics (default: found by message type)")
    g.add_argument("--image-topic", help="sensor_msgs/Image or CompressedImage topic")
    g.add_argument("--camera-info-topic", help="sensor_msgs/CameraInfo topic")
    g.add_argument("--scan-topic", help="sensor_msgs/LaserScan topic")
    g.add_argument(
        "--tolerance", type=float, default=0.05, help="pair an image with a scan at most this far in stamp, s (0.05)"
    )


def _label(args: argparse.Namespace, layout: DockLayout, camera: CameraModel | None) -> Dataset:
    """Label a recording (shared by label and evaluate); prints the reader's warnings and the counts."""
    from monodock.core.camera import CameraModel
    from monodock.core.robot import RobotConfig
    from monodock.learning.dataset import label_recording

    if camera is None and getattr(args, "camera", None):
        camera = CameraModel.load(args.camera)
    robot = RobotConfig.load(args.robot) if getattr(args, "robot", None) else None
    ds, run, warnings = label_recording(
        args.recording,
        layout,
        camera=camera,
        robot=robot,
        image_topic=args.image_topic,
        camera_info_topic=args.camera_info_topic,
        scan_topic=args.scan_topic,
        tolerance_s=args.tolerance,
    )
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    reasons = ", ".join(f"{n} {k}" for k, n in run.invalid_labels.most_common())
    print(
        f"{run.images} images: {run.paired} paired with a scan within {args.tolerance * 1000:.0f} ms, "
        f"{run.unpaired} unpaired, {run.unreadable} unreadable, {run.no_marker2} without marker 2; "
        f"{run.labelled} labelled" + (f"; not labelled: {reasons}" if reasons else "")
    )
    return ds


def _cmd_label(args: argparse.Namespace) -> int:
    from monodock.core.atomic import check_writable
    from monodock.core.layout import DockLayout
    from monodock.learning.dataset import label_error_table, label_errors, write_dataset

    if not (args.tolerance > 0 and math.isfinite(args.tolerance)):
        raise MonodockError(f"--tolerance must be a positive number of seconds, got {args.tolerance}")
    layout = DockLayout.load(args.layout)
    check_writable(args.out, force=args.force)
    ds = _label(args, layout, None)
    if len(ds) == 0:
        raise MonodockError(f"{args.recording}: no images")
    write_dataset(args.out, ds, force=args.force)
    errs = label_errors(ds)
    if errs:
        print("label error against the recording's ground truth:")
        print(label_error_table(errs), end="")
    print(f"dataset: {len(ds)} rows -> {args.out}")
    return 0


def _sets(value: str) -> tuple[str, ...]:
    from monodock.perception.features import MARKER_SETS

    names = tuple(v.strip() for v in value.split(",") if v.strip())
    bad = [n for n in names if n not in MARKER_SETS]
    if bad or not names:
        raise MonodockError(f"--sets: unknown marker set '{bad[0] if bad else value}' (from {', '.join(MARKER_SETS)})")
    if "m2" not in names:
        raise MonodockError("--sets must include m2: marker 2 alone is what the last half-metre of a docking sees")
    return names


def _cmd_train(args: argparse.Namespace) -> int:
    from monodock.core.atomic import check_writable
    from monodock.estimation.bundle import save_bundle
    from monodock.estimation.fused import fusion_holdout, train_fusion
    from monodock.estimation.regression import bundle_metadata, training_sets
    from monodock.learning.dataset import read_dataset
    from monodock.learning.train import TrainConfig, train
    from monodock.report.training import write_training_report

    if args.trials < 1:
        raise MonodockError("--trials must be at least 1")
    check_writable(args.out, force=args.force)
    ds = read_dataset(args.dataset)
    if not 0.0 <= args.fusion_holdout < 0.5:
        raise MonodockError(f"--fusion-holdout must be in [0, 0.5), got {args.fusion_holdout}")
    holdout = (
        fusion_holdout(len(ds), args.fusion_holdout, args.seed)
        if args.fusion_holdout > 0
        else np.zeros(len(ds), dtype=bool)
    )
    if holdout.any() and not np.isfinite(ds.refined_corners()).any():
        raise MonodockError(
            f"{args.dataset} has no refined corners (labelled by an older monodock): label it again, "
            "or train without the fused method's tables (--fusion-holdout 0)"
        )
    sets = training_sets(
        ds.subset(~holdout), _sets(args.sets), depth_label=args.depth_label, angle_label=args.angle_label
    )
    for s in sets:
        if len(s.depth) < 20:
            raise MonodockError(
                f"{args.dataset}: only {len(s.depth)} labelled rows with markers {s.name} seen; record more"
            )
    t0 = time.perf_counter()
    config = TrainConfig(trials=args.trials, seed=args.seed, jobs=_jobs(args.jobs) if args.jobs else 0)
    result = train(sets, config)
    dt = time.perf_counter() - t0
    meta = bundle_metadata(ds, depth_label=args.depth_label, angle_label=args.angle_label, source=str(args.dataset))
    meta["fusion_holdout_rows"] = int(holdout.sum())
    path = save_bundle(args.out, result, metadata=meta, force=args.force)
    if holdout.any():
        tables = train_fusion(path, ds, holdout)
        print(
            f"fused method: tables learned on {int(holdout.sum())} held-out rows "
            f"(corner noise {tables.corner_sigma / math.sqrt(50):.3f} px on a 50 px marker)"
        )
    write_training_report(Path(path) / "report", result, title=f"monodock training report: {args.dataset}")
    size = sum(f.stat().st_size for f in Path(path).glob("*.onnx"))
    print(f"trained in {dt:.0f} s; bundle {size / 1e6:.1f} MB -> {path} (report: {Path(path) / 'report'})")
    return 0


def _load_bundle(path: str) -> Bundle:
    from monodock.estimation.bundle import Bundle
    from monodock.perception.features import MARKER_SETS, MODEL_FEATURE_SCHEMA, model_feature_names

    return Bundle.load(
        path,
        expected_feature_names={s: model_feature_names(s) for s in MARKER_SETS},
        feature_schema=MODEL_FEATURE_SCHEMA,
    )


def _bundle_calibration(args: argparse.Namespace, bundle: Bundle) -> tuple[CameraModel, DockLayout, RobotConfig]:
    """The bundle's camera, layout and mounts; --camera and --robot override, --layout must match."""
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.errors import InputError

    meta = bundle.manifest["metadata"]
    layout = DockLayout.from_dict(meta["layout"], f"{args.model}: layout")
    if getattr(args, "layout", None):
        given = DockLayout.load(args.layout)
        if given != layout:
            raise InputError(
                f"{args.model} was trained for another dock layout ({layout.dictionary}, ids "
                f"{'/'.join(str(m.id) for m in layout.markers)}, {layout.marker_size * 100:g} cm) than {args.layout} "
                f"({given.dictionary}, ids {'/'.join(str(m.id) for m in given.markers)}, "
                f"{given.marker_size * 100:g} cm)"
            )
    camera = (
        CameraModel.load(args.camera)
        if getattr(args, "camera", None)
        else CameraModel.from_ros_dict(meta["camera"], f"{args.model}: camera")
    )
    robot = (
        RobotConfig.load(args.robot)
        if getattr(args, "robot", None)
        else RobotConfig.from_dict(meta["robot"], f"{args.model}: robot")
    )
    return camera, layout, robot


def _cmd_robustness(args: argparse.Namespace) -> int:
    """``evaluate --robustness``: simulated test frames, one nuisance or calibration error at a time."""
    from monodock.core.atomic import atomic_directory, check_writable
    from monodock.errors import InputError
    from monodock.evaluation.robustness import RobustnessConfig, run_robustness
    from monodock.report.robustness import write_robustness_report

    if args.recording is not None:
        raise InputError(f"--robustness simulates its own frames: drop the recording '{args.recording}'")
    for flag, value, least in (
        ("--frames", args.frames, 1),
        ("--calibration-frames", args.calibration_frames, 50),
        ("--supersample", args.supersample, 1),
    ):
        if value is not None and value < least:
            raise InputError(f"{flag} must be at least {least}, got {value}")
    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    check_writable(args.out, force=args.force)
    bundle = _load_bundle(args.model)
    camera, layout, robot = _bundle_calibration(args, bundle)
    config = RobustnessConfig(
        frames=args.frames or 300,
        calibration_frames=args.calibration_frames or 300,
        seed=args.seed or 0,
        jobs=_jobs(args.jobs),
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


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from monodock.core.atomic import atomic_directory
    from monodock.errors import InputError
    from monodock.estimation.fused import FusedEstimator, fusion_tables_of
    from monodock.estimation.regression import RegressionEstimator
    from monodock.evaluation.heldout import evaluate_heldout
    from monodock.learning.dataset import read_dataset
    from monodock.report.evaluation import write_evaluation_report

    if args.robustness:
        return _cmd_robustness(args)
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
        )
        if v is not None
    ]
    if extra:
        raise InputError(f"{extra[0]} only applies with --robustness")
    bundle = _load_bundle(args.model)
    camera, layout, robot = _bundle_calibration(args, bundle)
    if str(args.recording).endswith(".parquet"):
        ds = read_dataset(args.recording)
    else:
        ds = _label(args, layout, camera if args.camera else None)
    regression = RegressionEstimator(bundle, ds.camera(), robot)
    fused = None
    if "fusion" in bundle.manifest["metadata"]:
        fused = FusedEstimator(ds.camera(), layout, robot, fusion_tables_of(bundle), regression)
    else:
        print("note: the bundle has no fusion tables (trained before the fused method); fused is left out")
    with atomic_directory(args.out, force=args.force) as out:
        result = evaluate_heldout(ds, regression, fused=fused)
        summary = result.summary()
        write_evaluation_report(out, result, summary, title=f"monodock evaluation: {args.recording}")
    for method, row in summary.overall.items():
        print(
            f"{method:10s} valid {row.valid}/{row.frames}  depth MAE {row.depth_mae_cm:.2f} cm  "
            f"lateral MAE {row.lateral_mae_cm:.2f} cm  yaw MAE {row.yaw_mae_deg:.2f} deg"
        )
    print(f"report: {Path(args.out) / 'report.html'}")
    return 0


# --- demo ---------------------------------------------------------------------------------------


def _cmd_demo(args: argparse.Namespace) -> int:
    from monodock.cli.demo import DemoConfig, run_demo
    from monodock.core.atomic import check_writable

    for flag, value in (
        ("--train-stops", args.train_stops),
        ("--test-stops", args.test_stops),
        ("--trials", args.trials),
        ("--dock-trials", args.dock_trials),
    ):
        if value < 1:
            raise MonodockError(f"{flag} must be at least 1")
    check_writable(args.out, force=args.force)
    config = DemoConfig(
        train_stops=args.train_stops,
        test_stops=args.test_stops,
        trials=args.trials,
        seed=args.seed,
        jobs=_jobs(args.jobs),
        dock_trials=args.dock_trials,
    )
    demo = run_demo(args.out, config, force=args.force)
    for method, r in demo.summary.overall.items():
        print(
            f"{method:10s} valid {r.valid}/{r.frames}  depth MAE {r.depth_mae_cm:.2f} cm  lateral MAE "
            f"{r.lateral_mae_cm:.2f} cm  yaw MAE {r.yaw_mae_deg:.2f} deg  (against the simulator's truth)"
        )
    for method, g in (demo.summary.docking or {}).items():
        print(
            f"docking {method:10s} {g.successes}/{g.runs} docked; median final lateral "
            f"{g.final_lateral_cm.median:.2f} cm, heading {g.final_heading_deg.median:.2f} deg"
        )
    print(f"report: {Path(args.out) / 'report.html'}  ({demo.seconds:.0f} s)")
    return 0


# --- parser -------------------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    """argparse with the usage error on one line, like every other monodock error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="monodock",
        description="Dock a robot onto its charger with one camera and three ArUco markers.",
        epilog="Every command prints one line and exits 2 on bad input; outputs are never overwritten without --force.",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("simulate", help="render camera frames, LiDAR scans and ground truth to a folder")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--frames", type=int, default=200)
    s.add_argument("--seed", type=int, default=0)
    _range_option(s, "--depth", (0.25, 2.5), "depth from the camera, metres")
    _range_option(s, "--lateral", (-0.4, 0.4), "DockPose y, metres")
    _range_option(s, "--yaw", (-30.0, 30.0), "DockPose yaw, degrees")
    s.add_argument(
        "--preview",
        type=int,
        nargs="?",
        const=5,
        default=0,
        metavar="N",
        help="also write overlay PNGs of the first N frames (default 5) to OUT/preview",
    )
    s.add_argument(
        "--format",
        choices=("folder", "rosbag2"),
        default="folder",
        help="folder: PNGs, scans.npz and ground_truth.csv (default); rosbag2: a stop-and-go data-collection "
        "recording (Image, CameraInfo, LaserScan, /tf_static, ground truth on /monodock/ground_truth)",
    )
    g = s.add_argument_group("recording (--format rosbag2)")
    g.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="rosbag2 storage (default mcap)")
    g.add_argument(
        "--encoding",
        choices=("mono8", "bgr8", "png", "jpeg"),
        default="mono8",
        help="mono8/bgr8: sensor_msgs/Image; png/jpeg: sensor_msgs/CompressedImage (default mono8)",
    )
    g.add_argument(
        "--density",
        default="uniform",
        help="stops per 5 cm depth segment: uniform (default), paper (Table 2's N), or 45 comma-separated weights",
    )
    g.add_argument("--camera-rate", type=float, default=15.0, help="camera frame rate, Hz (default 15)")
    g.add_argument("--lidar-rate", type=float, default=10.0, help="LiDAR scan rate, Hz (default 10)")
    s.add_argument("--jobs", type=int, help="worker processes (default: cores, at most 4)")
    s.add_argument("--force", action="store_true", help="replace an existing output folder")
    _add_calibration(s, required=False)
    _add_nuisances(s)
    s.set_defaults(func=_cmd_simulate)

    e = sub.add_parser("estimate", help="estimate the DockPose in images, folders, videos or recordings")
    e.add_argument("inputs", nargs="+", metavar="INPUT", help="image files, folders of images, videos, or recordings")
    e.add_argument("--model", help="model bundle (carries its camera, layout and mounts; --camera may override)")
    e.add_argument(
        "--method",
        choices=("regression", "pnp", "board", "fused"),
        help="regression: the papers' models (default with --model); pnp: marker 2 alone (IPPE_SQUARE), the "
        "papers' baseline; board: all visible markers (default without --model); fused: planar PnP on "
        "bias-free corners combined with the regression, with a covariance (needs --model)",
    )
    e.add_argument("--out", required=True, help="EST.csv to write")
    e.add_argument("--bag", metavar="OUT_BAG", help="also write the valid poses as a Nav2 detected_dock_pose rosbag2")
    e.add_argument(
        "--refinement", choices=("none", "subpix", "contour"), default="subpix", help="ArUco corner refinement"
    )
    e.add_argument("--skip-bad", action="store_true", help="an unreadable image gives an invalid row, not an error")
    e.add_argument("--force", action="store_true", help="overwrite an existing output")
    _add_calibration(e, required=False)
    e.set_defaults(func=_cmd_estimate)

    w = sub.add_parser("show", help="overlay PNG: detected markers, ids and the board estimate's dock axes")
    w.add_argument("image")
    w.add_argument("--out", required=True, help="PNG to write")
    w.add_argument("--force", action="store_true")
    _add_calibration(w, required=True)
    w.set_defaults(func=_cmd_show)

    lb = sub.add_parser("label", help="LiDAR labels for a recording: detect, pair with scans, write the dataset")
    lb.add_argument("recording", help="rosbag2 (directory, .mcap, .db3) or ROS 1 .bag")
    lb.add_argument("--layout", required=True, help="dock layout YAML")
    lb.add_argument("--out", required=True, help="dataset Parquet file to write")
    lb.add_argument("--camera", help="camera file, instead of the recording's CameraInfo")
    lb.add_argument("--robot", help="robot YAML, instead of the recording's /tf_static mounts")
    lb.add_argument("--force", action="store_true", help="overwrite an existing dataset")
    _add_topics(lb)
    lb.set_defaults(func=_cmd_label)

    tr = sub.add_parser("train", help="the papers' seven regressors per segment, best by MSE, into an ONNX bundle")
    tr.add_argument("dataset", help="dataset Parquet file from monodock label")
    tr.add_argument("--out", required=True, help="bundle directory to write")
    tr.add_argument("--trials", type=int, default=10, help="hyperparameter draws per model (default 10)")
    tr.add_argument(
        "--sets",
        default="m1m2m3,m2",
        help="marker sets to train, comma-separated, from m1m2m3, m1m2, m2m3, m2 (default m1m2m3,m2)",
    )
    tr.add_argument("--depth-label", choices=("point", "line"), default="point", help="point: the papers' (default)")
    tr.add_argument("--angle-label", choices=("line", "endpoints"), default="line", help="endpoints: the papers'")
    tr.add_argument(
        "--fusion-holdout",
        type=float,
        default=0.1,
        help="share of rows kept out of the regression to learn the fused method's tables from (0.1; 0: none)",
    )
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--jobs", type=int, help="worker processes (default: all cores)")
    tr.add_argument("--force", action="store_true", help="replace an existing bundle")
    tr.set_defaults(func=_cmd_train)

    ev = sub.add_parser(
        "evaluate",
        help="every method on a held-out recording against LiDAR labels and truth; --robustness: against "
        "one simulated nuisance or calibration error at a time",
    )
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
    g.add_argument("--frames", type=int, help="test poses, the same at every level (default 300)")
    g.add_argument(
        "--calibration-frames", type=int, help="LiDAR-labelled frames the fused tables are re-learned from (300)"
    )
    g.add_argument("--seed", type=int, help="seed of the poses and of every frame's draws (default 0)")
    g.add_argument(
        "--supersample", type=int, help="S: test frames' edge pixels get SxS area samples (default 16; lower is faster)"
    )
    g.add_argument("--jobs", type=int, help="render processes (default: cores, at most 4)")
    _add_topics(ev)
    ev.set_defaults(func=_cmd_evaluate)

    from monodock.calibrate.extrinsics import add_parser as add_extrinsics
    from monodock.calibrate.intrinsics import add_parser as add_intrinsics
    from monodock.cli.dock_sim import add_parser as add_dock_sim
    from monodock.io.live import add_parser as add_run

    cal = sub.add_parser("calibrate", help="camera intrinsics from a checkerboard; camera-LiDAR extrinsics")
    cal_sub = cal.add_subparsers(dest="calibrate_command", required=True, metavar="WHAT")
    add_intrinsics(cal_sub)
    add_extrinsics(cal_sub)
    add_run(sub)
    add_dock_sim(sub)

    d = sub.add_parser("demo", help="simulate, label, train, evaluate every method, and write the report")
    d.add_argument("--out", default="demo_report", help="report folder (default: demo_report)")
    d.add_argument("--train-stops", type=int, default=3000, help="stops of the data-collection drive (3000)")
    d.add_argument("--test-stops", type=int, default=500, help="stops of the held-out drive (500)")
    d.add_argument("--trials", type=int, default=4, help="hyperparameter draws per model (4)")
    d.add_argument("--dock-trials", type=int, default=1, help="closed-loop docking starts per case and method (1)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--jobs", type=int)
    d.add_argument("--force", action="store_true", help="replace an existing report folder")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; user errors print one line on stderr and return a non-zero code."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except MonodockError as exc:
        print(f"monodock {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        # A file the user named could not be read or written (permissions, disk full, a folder in the way).
        where = f" {exc.filename}" if exc.filename else ""
        print(f"monodock {args.command}: error:{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("monodock: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        print(
            f"monodock {args.command}: internal error: {type(exc).__name__}: {exc} (rerun with --debug)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
