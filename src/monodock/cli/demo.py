"""``monodock demo``: the whole pipeline on the simulator, as a report.

simulate a data-collection drive (rosbag2) → label it with the LiDAR → train the papers' models → simulate a
held-out drive (another seed, default nuisances) → dock in closed loop → evaluate every method against the LiDAR
labels and the simulator's truth, and reproduce the papers' SolvePnP failure with a wrong marker size and focal
length → the report. ``run_demo`` runs one function per stage.
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monodock.cli.options import SubParsers, add_cluster, add_command, add_jobs, add_seed, int_in, jobs
from monodock.core.atomic import atomic_directory, check_writable
from monodock.core.camera import CameraModel
from monodock.core.projection import project_to_image, scan_in_base
from monodock.errors import MonodockError
from monodock.estimation.bundle import Bundle, load_bundle
from monodock.estimation.estimator import FrameEstimates
from monodock.estimation.factory import make_estimator
from monodock.estimation.methods import MethodSetup, PoseMethod, build_methods
from monodock.estimation.overlay import draw_overlay
from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim, summarize
from monodock.evaluation.heldout import HeldoutResult, HeldoutSummary, evaluate_heldout
from monodock.evaluation.selftrain import SelfTrainConfig, simulate_and_train
from monodock.learning.dataset import Dataset, LabelRun, label_errors, label_recording, write_dataset
from monodock.learning.label import points_across_marker
from monodock.learning.pipeline import TrainOptions, train_bundle
from monodock.learning.train import TrainingResult
from monodock.perception.features import DEFAULT_MARKER_SETS
from monodock.report.demo import DemoPage, DockingRun, FrameView, LidarOverlay, lidar_settings, write_demo_report
from monodock.report.docking import write_dock_files
from monodock.report.html import plain
from monodock.report.training import write_training_report
from monodock.sim import Nuisances, SimFrame, Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording

__all__ = ["STAGES", "DemoConfig", "DemoResult", "demo_settings", "run_demo"]

# The methods of the first screen's camera frame, and of the closed-loop docking.
FRAME_METHODS = ("regression", "pnp", "board", "fused")
DOCK_METHODS = ("regression", "board", "fused")
# Depths from the camera (m) of the LiDAR overlays.
OVERLAY_DEPTHS = (("near", 0.4), ("mid", 1.2), ("far", 2.3))
# The first screen's frame: the most square-on stop within 20 cm of this depth from the camera (m).
FRAME_DEPTH = 1.2


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo; the defaults take about four minutes on two cores (most of it training the models).

    ``train``: the data-collection drive and the papers' models trained on it, as any self-trained bundle; its seed
    is the demo's (the held-out drive's and the docking's derive from it).
    """

    train: SelfTrainConfig = field(default_factory=SelfTrainConfig)
    test_stops: int = 500
    jobs: int = 2
    focal_errors: tuple[float, ...] = (1.05, 1.5)
    dock_trials: int = 1  # closed-loop docking runs per case and method

    @property
    def seed(self) -> int:
        """The demo's seed: the training drive's."""
        return self.train.seed


@dataclass(frozen=True)
class DemoResult:
    """What ``run_demo`` returns: the evaluation's summary (as written to summary.json), the wall time, and
    each stage's wall time in seconds (STAGES' names, in order)."""

    summary: HeldoutSummary
    seconds: float
    stages: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class _Trained:
    """The training stage's products: the labelled training drive, its counts, the trained bundle."""

    dataset: Dataset
    run: LabelRun
    result: TrainingResult
    bundle: Bundle
    seconds: float


@dataclass(frozen=True)
class _HeldOut:
    """The held-out drive: its simulator and seed, its labelled dataset, the methods and the pictures."""

    sim: Simulator
    seed: int
    dataset: Dataset
    learnt: dict[str, PoseMethod]  # the regression and fused, as the frame estimator runs them
    frame: FrameView | None
    overlays: tuple[LidarOverlay, ...]


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# The stages as their times are logged ("stage NAME done in S s", read by bench/demo_speed.py).
STAGES = ("drive, labels, training", "held-out drive", "docking", "evaluation", "report")


@contextlib.contextmanager
def _took(stage: str, times: list[tuple[str, float]]) -> Iterator[None]:
    """Log how long a stage took (where a demo's minutes go), and add it to ``times``."""
    started = time.perf_counter()
    yield
    times.append((stage, time.perf_counter() - started))
    _log(f"stage {stage} done in {times[-1][1]:.1f} s")


def _lidar_overlay(frame: SimFrame, sim: Simulator, estimates: FrameEstimates) -> bytes:
    """The papers' Fig. 8c/9: LiDAR points projected on the image, the label's points across marker 2."""
    det = estimates.detection
    assert det is not None
    pts = scan_in_base(frame.scan, sim.robot)
    px = project_to_image(pts, sim.camera, sim.robot)
    sel = (
        points_across_marker(det.observations["center"].corners, pts, sim.camera, sim.robot)
        if "center" in det.observations
        else None
    )
    pic = draw_overlay(
        frame.image,
        det,
        sim.layout,
        sim.camera,
        sim.robot,
        estimates.estimates["regression"],
        frame.truth.corners,
        lidar_px=px,
        lidar_selected=sel,
    )
    ok, buf = cv2.imencode(".png", pic)
    assert ok
    return bytes(buf.tobytes())


def _simulate_and_train(tmp: Path, work: Path, config: DemoConfig) -> _Trained:
    """Stages 1-3: the data-collection drive, its LiDAR labels and the papers' models, into tmp/bundle."""
    started = time.perf_counter()
    dataset, run, result = simulate_and_train(
        work, tmp / "bundle", Simulator(seed=config.seed), config.train, jobs=config.jobs, steps="[1-3/6] "
    )
    seconds = time.perf_counter() - started
    write_dataset(tmp / "train.parquet", dataset)
    write_training_report(tmp / "bundle" / "report", result, title="monodock demo: training report")
    return _Trained(dataset, run, result, load_bundle(tmp / "bundle"), seconds)


def _held_out_drive(tmp: Path, work: Path, config: DemoConfig, trained: _Trained) -> _HeldOut:
    """Stage 4: a drive of another seed with the default nuisances, labelled; the pictures of a few frames."""
    _log(f"[4/6] simulating a held-out drive: {config.test_stops} stops, another seed, default nuisances ...")
    seed = config.seed + 1000
    sim = Simulator(nuisances=Nuisances(), seed=seed)
    stops = plan_drive(sim, DriveConfig(stops=config.test_stops), np.random.default_rng([seed, 2]))
    estimator = make_estimator(
        methods=FRAME_METHODS, bundle=trained.bundle, camera=sim.camera, layout=sim.layout, robot=sim.robot
    )
    learnt = {m: estimator.pose_methods[m] for m in ("regression", "fused")}
    depth = np.array([s.pose.x - sim.robot.camera_mount.x for s in stops])
    picks = {int(np.argmin(np.abs(depth - d))): name for name, d in OVERLAY_DEPTHS}
    # Square on: off the axis and turned away as little as possible (30 cm weighs as much as 30 degrees).
    off_axis = np.array([abs(s.pose.y) / 0.3 + abs(s.pose.yaw_deg) / 30.0 for s in stops])
    front = int(np.argmin(np.where(np.abs(depth - FRAME_DEPTH) < 0.2, off_axis, np.inf)))
    overlays: list[LidarOverlay] = []
    views: list[FrameView] = []

    def on_frame(index: int, frame: SimFrame) -> None:
        if index not in picks and index != front:
            return
        estimates = estimator.estimate(str(index), 0.0, frame.image)
        if index in picks:
            name = picks[index]
            caption = f"{name}: depth {depth[index]:.2f} m from the camera; truth {frame.truth.pose}"
            overlays.append(LidarOverlay(f"overlay_{name}.png", caption, _lidar_overlay(frame, sim, estimates)))
        if index == front and estimates.detection is not None:
            views.append(
                FrameView(
                    frame.image,
                    estimates.detection,
                    estimates.estimates,
                    frame.truth.pose,
                    frame.truth.corners,
                    sim.camera,
                    sim.layout,
                    sim.robot,
                )
            )

    write_recording(work / "test_drive", sim, stops, seed=seed, jobs=config.jobs, on_frame=on_frame)
    dataset, _, _ = label_recording(work / "test_drive", sim.layout, jobs=config.jobs)
    write_dataset(tmp / "test.parquet", dataset)
    return _HeldOut(sim, seed, dataset, learnt, views[0] if views else None, tuple(overlays))


def _docking(tmp: Path, config: DemoConfig) -> DockingRun:
    """Stage 5: closed-loop docking from every case with the regression, board PnP and fused; files in docking/."""
    _log(f"[5/6] closed-loop docking: {config.dock_trials} start(s) per case, regression, board PnP, fused ...")
    dock_config = DockSimConfig(
        trials=config.dock_trials, methods=DOCK_METHODS, seed=config.seed, jobs=config.jobs, bundle=tmp / "bundle"
    )
    (tmp / "docking").mkdir()
    results = tuple(run_dock_sim(dock_config))
    write_dock_files(tmp / "docking", results, dock_config, jobs=config.jobs)
    return DockingRun(dock_config, results, summarize(results, dock_config))


def _focal_error_bundles(
    work: Path, config: DemoConfig, trained: _Trained, held: _HeldOut
) -> dict[tuple[str, float], Callable[[CameraModel], dict[str, PoseMethod]]]:
    """The regression trained through a camera file whose focal length is off, per factor of the study."""
    out: dict[tuple[str, float], Callable[[CameraModel], dict[str, PoseMethod]]] = {}
    camera = trained.dataset.camera()
    for f in config.focal_errors:
        wrong_camera = camera.focal_scaled(f)
        path = work / f"bundle_focal_{f:g}"
        options = TrainOptions(
            trials=1, seed=config.seed, jobs=config.jobs, camera=wrong_camera, source="simulated training drive"
        )
        wrong = load_bundle(train_bundle(trained.dataset, path, options).path)

        def factory(c: CameraModel, b: Bundle = wrong) -> dict[str, PoseMethod]:
            return build_methods(("regression",), MethodSetup(c, held.sim.layout, held.sim.robot, b))

        out[("focal length", f)] = factory
    return out


def _study(work: Path, config: DemoConfig, trained: _Trained, held: _HeldOut) -> HeldoutResult:
    """Stage 6: every method on the held-out drive, the physical limit and the SolvePnP-failure study."""
    _log("[6/6] evaluating; training the focal-length-error bundles for the SolvePnP-failure study ...")
    miscalibrated = _focal_error_bundles(work, config, trained, held)
    return evaluate_heldout(held.dataset, held.learnt, miscalibrated=miscalibrated)


def demo_settings(config: DemoConfig, sim: Simulator, test_seed: int) -> dict[str, object]:
    """What the demo ran, as a person would write it in a YAML file (``sim``: the held-out drive's simulator)."""
    return {
        "training drive": {
            "stops": config.train.stops,
            "seed": config.seed,
            "edge supersampling": f"{config.train.supersample}x{config.train.supersample}",
            "depth_cm": [25, 250],
            "lateral_cm": [-40, 40],
            "yaw_deg": [-30, 30],
        },
        "held-out drive": {"stops": config.test_stops, "seed": test_seed, "nuisances": plain(sim.nuisances)},
        "LiDAR": lidar_settings(sim.lidar),
        "camera": {"size_px": [sim.camera.width, sim.camera.height], "fx_px": sim.camera.fx},
        "layout": {
            "dictionary": sim.layout.dictionary,
            "marker_size_cm": round(sim.layout.marker_size * 100, 6),
            "ids": [m.id for m in sim.layout.markers],
        },
        "training": {
            "hyperparameter draws per model": config.train.trials,
            "split": "80/20, best by test MSE",
            "marker sets": list(DEFAULT_MARKER_SETS),
        },
    }


def _report(
    tmp: Path, config: DemoConfig, trained: _Trained, held: _HeldOut, docking: DockingRun, result: HeldoutResult
) -> HeldoutSummary:
    """The report, its figures and summary.json into ``tmp``; returns the summary."""
    summary = result.summary(docking={m: b.overall for m, b in docking.summary.methods.items()})
    page = DemoPage(
        heldout=result,
        summary=summary,
        docking=docking,
        frame=held.frame,
        lidar_overlays=held.overlays,
        training=trained.result,
        label_run=trained.run,
        label_errors=tuple(label_errors(trained.dataset)),
        settings=demo_settings(config, held.sim, held.seed),
        trials=config.train.trials,
        train_seconds=trained.seconds,
    )
    write_demo_report(tmp, page)
    return summary


def run_demo(out: str | Path, config: DemoConfig, *, force: bool = False) -> DemoResult:
    """Run the demo into ``out`` (atomically): train, a held-out drive, docking, the study, the report."""
    t0 = time.perf_counter()
    times: list[tuple[str, float]] = []
    train, heldout, dock, evaluation, report = STAGES
    with atomic_directory(out, force=force) as tmp:
        work = tmp / "recordings"
        work.mkdir()
        with _took(train, times):
            trained = _simulate_and_train(tmp, work, config)
        with _took(heldout, times):
            held = _held_out_drive(tmp, work, config, trained)
        with _took(dock, times):
            docking = _docking(tmp, config)
        with _took(evaluation, times):
            result = _study(work, config, trained, held)
        with _took(report, times):
            summary = _report(tmp, config, trained, held, docking, result)
        shutil.rmtree(work)
    return DemoResult(summary, time.perf_counter() - t0, tuple(times))


# --- the command ---------------------------------------------------------------------------------------

_DEFAULT = DemoConfig()
# The demo's sizes, whole numbers from 1, their defaults DemoConfig's: flag, the most, the default, what it counts.
_SIZES = (
    ("--train-stops", 100_000, _DEFAULT.train.stops, "stops of the data-collection drive"),
    ("--test-stops", 100_000, _DEFAULT.test_stops, "stops of the held-out drive"),
    ("--trials", 1000, _DEFAULT.train.trials, "hyperparameter draws per model"),
    ("--dock-trials", 1000, _DEFAULT.dock_trials, "closed-loop docking starts per case and method"),
)


def add_parser(subparsers: SubParsers) -> None:
    """Add ``demo``."""
    d = add_command(subparsers, "demo", run)
    d.add_argument("--out", default="demo_report", help="report folder (default: demo_report)")
    for flag, most, default, what in _SIZES:
        d.add_argument(flag, type=int_in(1, most), default=default, help=f"{what}, 1-{most} ({default})")
    add_seed(d)
    add_jobs(d)
    add_cluster(d)
    d.add_argument("--force", action="store_true", help="replace an existing report folder")


def run(args: argparse.Namespace) -> int:
    """simulate, label, train, evaluate every method, and write the report"""
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
        train=SelfTrainConfig(stops=args.train_stops, trials=args.trials, seed=args.seed),
        test_stops=args.test_stops,
        jobs=jobs(args.jobs),
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
