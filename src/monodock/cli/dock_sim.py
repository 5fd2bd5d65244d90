"""The ``monodock dock-sim`` command line."""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path
from typing import Any

from monodock.cli.options import (
    SubParsers,
    add_camera_rate,
    add_cluster,
    add_command,
    add_jobs,
    add_seed,
    comma_list,
    float_in,
    int_in,
)
from monodock.core import settings
from monodock.core.atomic import atomic_directory, check_writable
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig, load_docking_config
from monodock.dock.planner import CASES, PLANNERS
from monodock.errors import InputError
from monodock.estimation.bundle import load_bundle
from monodock.evaluation.dock_faults import FAULTS
from monodock.evaluation.dock_sim import (
    ALL_METHODS,
    BUNDLE_METHODS,
    STARTS,
    DockSimConfig,
    case_distances,
    run_dock_sim,
    summarize,
)
from monodock.evaluation.selftrain import SelfTrainConfig, cached_bundle
from monodock.report.dock_tables import console_table, fault_table
from monodock.report.docking import write_dock_report
from monodock.sim.diffdrive import DiffDriveConfig
from monodock.sim.render import MAX_SUPERSAMPLE

__all__ = ["add_parser", "run"]


def _cases(value: str) -> tuple[int, ...]:

    if value == "all":
        return tuple(CASES)
    try:
        cases = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"cases must be 'all' or numbers 1-8 separated by commas, got '{value}'"
        ) from None
    bad = [c for c in cases if c not in CASES]
    if bad or not cases:
        raise argparse.ArgumentTypeError(f"there are eight cases, 1-8; got {value}")
    return tuple(dict.fromkeys(cases))


def _rate(value: str) -> float:
    try:
        r = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{value}'") from None
    if not 0.0 <= r <= 1.0:
        raise argparse.ArgumentTypeError(f"must be within 0-1, got {value}")
    return r


def add_parser(subparsers: SubParsers) -> None:
    """Add ``dock-sim`` to the ``monodock`` sub-command parsers."""
    d = add_command(subparsers, "dock-sim", run)
    d.add_argument("--cases", type=_cases, help="'all' (default) or e.g. 1,3,5 (not with --starts room)")
    d.add_argument(
        "--starts",
        choices=STARTS,
        default="cases",
        help="where runs start: 'cases' (default: --trials per case inside --distance and --max-heading) or 'room' "
        "(--trials starts 0.5-5 m from the face centre, within 60 deg of the dock's axis, any heading)",
    )
    d.add_argument("--trials", type=int_in(1, 10_000), default=25, help="random starts per case, 1-10000 (25)")
    d.add_argument(
        "--method",
        type=comma_list("method", ALL_METHODS),
        default=("regression",),
        help="regression (default), board, pnp, fused, or several separated by commas (e.g. regression,fused): "
        "the first is summary.json's overall/cases, all are under 'methods'",
    )
    d.add_argument(
        "--model",
        help="the bundle of the regression and fused methods; without it, one trained on the simulator's own "
        "robot and kept in the cache",
    )
    d.add_argument("--out", help="write summary.json, runs.csv, plots and report.html into this folder")
    d.add_argument("--force", action="store_true", help="replace an existing --out folder")
    add_seed(d)
    add_jobs(d)
    add_cluster(d)
    d.add_argument(
        "--config",
        help="docking config YAML: the mission's gains, speeds, tolerances, time-outs and retries (docs/docking.md)",
    )
    d.add_argument(
        "--planner",
        type=comma_list("planner", PLANNERS),
        help="monodock (Point A at the stand-off, reached without a jump at any boundary), papers (Point A on the "
        "heading line, straight there), or both separated by a comma (each from the same starts); default: the "
        "config's, monodock",
    )
    d.add_argument(
        "--faults",
        type=comma_list("fault", tuple(FAULTS), everything=True),
        help="run these faults from every start, for the fault table: 'all' or some of "
        + ", ".join(FAULTS)
        + " ('none' is the nominal run)",
    )
    d.add_argument(
        "--redock", action="store_true", help="after each docking, undock to the staging pose and dock again"
    )
    d.add_argument(
        "--exposure",
        type=float_in(0.0, 1.0, high_open=True),
        default=0.008,
        help="camera exposure, s, less than one frame: motion blur from the robot's motion (0.008)",
    )
    d.add_argument("--frame-drop-rate", type=_rate, default=0.0, help="chance that a frame never arrives, 0-1 (0)")
    d.add_argument(
        "--latency-spike-rate", type=_rate, default=0.0, help="chance that a frame arrives 0.3 s late, 0-1 (0)"
    )
    d.add_argument("--no-rear-sensor", action="store_true", help="the robot has no rear range sensor")
    d.add_argument(
        "--no-charging-signal",
        action="store_true",
        help="the robot cannot tell whether it charges: docked is its own estimate inside the tolerances",
    )
    d.add_argument(
        "--standoff",
        type=float_in(0.0, 10.0, low_open=True),
        help="Point A: floor between front edge and face, m, in (0, 10] (the config's: 1.0)",
    )
    d.add_argument(
        "--distance",
        type=float_in(0.0, 20.0, low_open=True),
        nargs=2,
        metavar=("MIN", "MAX"),
        help="starts: base_link's distance from the face, m, each in (0, 20], MIN < MAX (1.0 2.5)",
    )
    d.add_argument(
        "--max-heading",
        type=float_in(0.0, 60.0, low_open=True),
        help="starts: heading within ± this, degrees, in (0, 60] (30)",
    )
    d.add_argument(
        "--max-retries",
        type=int_in(0, 100),
        help="back off to Point A and try again up to N times, 0-100 (the config's: 2)",
    )
    d.add_argument(
        "--contact-sensor",
        action="store_true",
        help="the charger reports contact and the robot stops on it (default: it stops on its own estimate)",
    )
    add_camera_rate(d, "camera frames per second, 1-240 (15)")
    d.add_argument(
        "--supersample",
        type=int_in(1, MAX_SUPERSAMPLE),
        default=16,
        help=f"S, 1-{MAX_SUPERSAMPLE}: pixels where three surfaces meet get SxS samples (16; other edges are exact)",
    )
    d.add_argument(
        "--cache", help="cache folder for the self-trained bundle (default $MONODOCK_CACHE or ~/.cache/monodock)"
    )
    d.add_argument(
        "--train-stops",
        type=int_in(100, 100_000),
        default=3000,
        help="stops of the self-trained bundle's drive, 100-100000 (3000)",
    )
    d.add_argument("--camera", help="simulate this camera (ROS camera_info YAML); default: the built-in webcam")
    d.add_argument("--layout", help="simulate this dock layout; default: the papers'")
    d.add_argument("--robot", help="simulate this robot (mounts, front_offset); default: the papers'")


def run(args: argparse.Namespace) -> int:
    """closed-loop docking in the simulator, camera in the loop: every case, many starts, every method"""
    if args.out:
        inputs = (args.config, args.model, args.camera, args.layout, args.robot, args.cache)
        check_writable(args.out, force=args.force, inputs=inputs)
    mission = load_docking_config(args.config) if args.config else DockingConfig()
    if args.max_retries is not None:
        if args.max_retries < 0:
            raise InputError(f"--max-retries must not be negative, got {args.max_retries}")
        mission = settings.replace(mission, max_retries=args.max_retries)
    if args.planner is not None:
        mission = dataclasses.replace(mission, planner=dataclasses.replace(mission.planner, kind=args.planner[0]))
    if args.standoff is not None:
        if not args.standoff > 0:
            raise InputError(f"--standoff must be positive, got {args.standoff:g}")
        mission = dataclasses.replace(mission, planner=dataclasses.replace(mission.planner, standoff=args.standoff))
    _starts_envelope(args)
    if not 0 < args.distance[0] < args.distance[1]:
        raise InputError(f"--distance needs 0 < MIN < MAX, got {args.distance[0]:g} {args.distance[1]:g}")
    if not 0 < args.max_heading <= 60:
        raise InputError(f"--max-heading must be in (0, 60] degrees, got {args.max_heading:g}")
    if not args.camera_rate > 0:
        raise InputError(f"--camera-rate must be positive, got {args.camera_rate}")
    if not 0 <= args.exposure < 1.0 / args.camera_rate:
        raise InputError(f"--exposure must be within 0 and one frame (1/--camera-rate), got {args.exposure:g}")
    jobs = args.jobs if args.jobs and args.jobs > 0 else max(1, min(4, os.cpu_count() or 1))
    config = DockSimConfig(
        cases=args.cases,
        trials=args.trials,
        methods=args.method,
        planners=args.planner or (),
        faults=args.faults or (),
        redock=args.redock,
        seed=args.seed,
        distance=(args.distance[0], args.distance[1]),
        starts=args.starts,
        max_heading_deg=args.max_heading,
        supersample=args.supersample,
        jobs=jobs,
        mission=mission,
        drive=DiffDriveConfig(
            contact_sensor=args.contact_sensor,
            camera_rate=args.camera_rate,
            exposure_time=args.exposure,
            frame_drop_rate=args.frame_drop_rate,
            latency_spike_rate=args.latency_spike_rate,
            rear_sensor=not args.no_rear_sensor,
            charging_signal=not args.no_charging_signal,
        ),
        layout=DockLayout.load(args.layout) if args.layout else DockLayout.default(),
        camera=CameraModel.load(args.camera) if args.camera else CameraModel.default(),
        robot=RobotConfig.load(args.robot) if args.robot else RobotConfig.default(),
    )
    for case in config.cases if config.starts == "cases" else ():
        case_distances(case, config)  # before any training: a start region may be empty
    if any(m in BUNDLE_METHODS for m in config.methods):
        config = dataclasses.replace(config, bundle=_regression_bundle(args, config, jobs))
    t0 = time.perf_counter()
    results = run_dock_sim(config)
    wall = time.perf_counter() - t0
    summary = summarize(results, config)
    if args.out:
        with atomic_directory(args.out, force=args.force) as tmp:
            write_dock_report(tmp, results, summary, config)
    print(console_table(summary))
    if config.faults:
        print(fault_table(summary, config))
    n = max(1, len(results))
    per_run = sum(r.wall_s for r in results) / n
    render = sum(r.render_s for r in results) / n
    perceive = sum(r.perceive_s for r in results) / n
    print(
        f"{len(results)} runs in {wall:.0f} s: {per_run:.1f} s of one core per run, of which rendering {render:.1f} s "
        f"and estimation {perceive:.1f} s"
    )
    if args.out:
        print(f"report: {Path(args.out) / 'report.html'}")
    return 0


def _starts_envelope(args: argparse.Namespace) -> None:
    """Fill in the per-case envelope's defaults; ``--starts room`` refuses them (it sets its own)."""
    if args.starts == "room":
        for option, value in (
            ("--cases", args.cases),
            ("--distance", args.distance),
            ("--max-heading", args.max_heading),
        ):
            if value is not None:
                raise InputError(f"--starts room sets its own envelope (0.5-5 m, 60 deg, any heading); drop {option}")
    args.cases = args.cases if args.cases is not None else tuple(CASES)
    args.distance = args.distance if args.distance is not None else (1.0, 2.5)
    args.max_heading = args.max_heading if args.max_heading is not None else 30.0


def _regression_bundle(args: argparse.Namespace, config: Any, jobs: int) -> Path:
    """The --model bundle (checked against the simulated layout), or the cached self-trained one."""

    if args.model:
        bundle = load_bundle(Path(args.model))
        layout = bundle.layout()
        if layout != config.layout:
            raise InputError(f"{args.model} was trained for another dock layout than the one simulated")
        return Path(args.model)
    if args.train_stops < 100:
        raise InputError(f"--train-stops must be at least 100, got {args.train_stops}")
    cache = Path(args.cache) if args.cache else None
    return cached_bundle(config.simulator(), SelfTrainConfig(stops=args.train_stops), jobs=jobs, cache=cache)
