"""``monodock simulate``: rendered frames with LiDAR scans and ground truth, as a folder or a rosbag2 drive."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from monodock.cli.options import (
    SubParsers,
    add_calibration,
    add_camera_rate,
    add_cluster,
    add_command,
    add_jobs,
    add_seed,
    float_in,
    int_in,
    jobs,
    load_calibration,
    range_option,
)
from monodock.core.atomic import atomic_directory, check_writable
from monodock.errors import MonodockError
from monodock.estimation.estimator import Estimator
from monodock.estimation.overlay import estimates_png
from monodock.sim import Nuisances, PoseDistribution, RoomGeometry, SimFrame, Simulator
from monodock.sim.continuous import DRIVES, commissioning_route, record_drive, teach_route, teach_start
from monodock.sim.diffdrive import SimulatedRobot
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.export import FrameRecord, write_frame_folder
from monodock.sim.recording import write_recording
from monodock.sim.render import MAX_SUPERSAMPLE
from monodock.sim.survey_views import VIEW_KINDS, write_view_folder

__all__ = ["MAX_FRAMES", "add_parser", "run"]

# The most frames (or stops) one simulate writes.
MAX_FRAMES = 100_000


def add_parser(subparsers: SubParsers) -> None:
    """Add ``simulate``."""
    s = add_command(subparsers, "simulate", run)
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument(
        "--frames",
        type=int_in(1, MAX_FRAMES),
        default=200,
        help=f"frames (with --format rosbag2: stops), 1-{MAX_FRAMES} (default 200)",
    )
    add_seed(s)
    range_option(s, "--depth", (0.25, 2.5), "depth from the camera, metres", (0.0, 20.0), low_open=True)
    range_option(s, "--lateral", (-0.4, 0.4), "DockPose y, metres", (-10.0, 10.0))
    # Yaws are refused outside +-180 degrees rather than wrapped: a range like 170 190 would wrap into two.
    range_option(s, "--yaw", (-30.0, 30.0), "DockPose yaw, degrees", (-180.0, 180.0))
    s.add_argument(
        "--preview",
        type=int_in(0, MAX_FRAMES),
        nargs="?",
        const=5,
        default=0,
        metavar="N",
        help=f"also write overlay PNGs of the first N frames (default 5) to OUT/preview, 0-{MAX_FRAMES}",
    )
    s.add_argument(
        "--format",
        choices=("folder", "rosbag2"),
        default="folder",
        help="folder: PNGs, scans.npz and ground_truth.csv (default); rosbag2: a stop-and-go data-collection "
        "recording (Image, CameraInfo, LaserScan, /tf_static, ground truth on /monodock/ground_truth)",
    )
    s.add_argument(
        "--views",
        choices=VIEW_KINDS,
        help="survey photographs instead of frames (folder format): handheld (a person walking round the dock) or "
        "robot (its camera on the floor); --frames views, for monodock calibrate layout",
    )
    s.add_argument(
        "--drive",
        choices=("stops", *DRIVES),
        default="stops",
        help="with --format rosbag2: stops (the papers' stop-and-go data collection, default), commissioning (a "
        "minute's continuous drive and turns before the dock, with odometry, for calibrate mount) or teach (on "
        "the contacts, charging, then a metre's back-off, for monodock teach)",
    )
    s.add_argument(
        "--wheel-scale",
        type=float_in(0.8, 1.25),
        nargs=2,
        metavar=("LEFT", "RIGHT"),
        help="continuous drives: each wheel's ground speed against its encoder, 0.8-1.25 (default: drawn per run, "
        "0.5 %% sd); the same robot in several drives takes the same",
    )
    s.add_argument(
        "--frame-every",
        type=int_in(1, 100),
        default=3,
        help="continuous drives: record every n-th camera frame, 1-100 (default 3: 5 Hz of a 15 Hz camera)",
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
    add_camera_rate(g, "camera frame rate, Hz, 1-240 (default 15)")
    g.add_argument(
        "--lidar-rate", type=float_in(1.0, 100.0), default=10.0, help="LiDAR scan rate, Hz, 1-100 (default 10)"
    )
    add_jobs(s)
    add_cluster(s)
    s.add_argument("--force", action="store_true", help="replace an existing output folder")
    add_calibration(s, required=False)
    add_nuisances(s)


def add_nuisances(p: argparse.ArgumentParser) -> None:
    """The simulator's nuisance knobs (``sim.Nuisances``)."""
    g = p.add_argument_group("nuisances (defaults: a cheap indoor webcam)")
    g.add_argument("--clean", action="store_true", help="no nuisance at all: the exact render")
    knob = g.add_argument
    knob("--read-noise", type=float_in(0, 255), help="sensor read noise, 8-bit digital numbers, 0-255")
    knob("--shot-noise", type=float_in(0, 100), help="photon noise variance per digital number, 0-100")
    knob("--defocus", type=float_in(0, 50), help="lens blur sigma, pixels, 0-50")
    knob("--motion-blur", type=float_in(0, 200), help="motion streak length, pixels, 0-200")
    knob("--exposure", type=float_in(0, 100, low_open=True), help="exposure gain, in (0, 100]")
    knob("--exposure-jitter", type=float_in(0, 2), help="per-frame log-normal spread of the exposure, 0-2")
    knob("--gamma", type=float_in(0.1, 10), help="display gamma (1: linear), 0.1-10")
    knob("--vignetting", type=float_in(0, 1), help="relative fall-off at the image corners, 0-1")
    knob("--occluder-probability", type=float_in(0, 1), help="chance per frame of an object hiding a marker, 0-1")
    g.add_argument("--no-clutter", action="store_true", help="no posters or foreign markers around the charger")
    g.add_argument(
        "--supersample",
        type=int_in(1, MAX_SUPERSAMPLE),
        help=f"S, 1-{MAX_SUPERSAMPLE}: pixels where three surfaces meet get SxS samples (default 16; other edges "
        "are exact)",
    )
    g.add_argument(
        "--side-walls",
        type=float_in(0.0, 50.0, low_open=True),
        metavar="DIST",
        help="side walls DIST metres either side of the dock, in (0, 50]",
    )


def nuisances(args: argparse.Namespace) -> Nuisances:
    """The Nuisances of the options (``add_nuisances``)."""
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
        changes["supersample"] = args.supersample
    return n.updated(**changes)


def run(args: argparse.Namespace) -> int:
    """render camera frames, LiDAR scans and ground truth to a folder"""
    camera, layout, robot = load_calibration(args)
    # Before any rendering: the outputs must be free (or --force), and none of them an input.
    check_writable(args.out, force=args.force, inputs=(args.camera, args.layout, args.robot))
    if args.format == "rosbag2" and args.preview:
        check_writable(_preview_folder(args.out), force=args.force, inputs=(args.camera, args.layout, args.robot))
    dist = PoseDistribution(depth=tuple(args.depth), lateral=tuple(args.lateral), yaw_deg=tuple(args.yaw))
    for name, (lo, hi) in (("depth", args.depth), ("lateral", args.lateral), ("yaw", args.yaw)):
        if not lo <= hi:
            raise MonodockError(f"--{name}: the first value must not exceed the second ({lo} > {hi})")
    room = RoomGeometry()
    if args.side_walls is not None:
        room = RoomGeometry(side_walls=args.side_walls)
    sim = Simulator(layout=layout, camera=camera, robot=robot, nuisances=nuisances(args), room=room, seed=args.seed)
    if args.views and args.format != "folder":
        raise MonodockError("--views writes a folder: drop --format rosbag2")
    if args.drive != "stops" and args.format != "rosbag2":
        raise MonodockError(f"--drive {args.drive} writes a recording: add --format rosbag2")
    try:
        folder = args.format == "folder" and not args.views
        poses = [sim.sample_pose(dist) for _ in range(args.frames)] if folder else []
    except RuntimeError as exc:
        raise MonodockError(str(exc)) from None
    previews: list[tuple[str, bytes]] = []
    estimator = Estimator(camera, layout, robot, ("board",))

    def preview(rec: FrameRecord) -> None:
        if rec.index < args.preview:
            result = estimator.estimate(rec.name, rec.stamp, rec.frame.image)
            previews.append((rec.name, estimates_png(rec.frame.image, result, estimator, rec.frame.truth.corners)))

    t0 = time.perf_counter()
    if args.views:
        n = write_view_folder(args.out, sim, args.views, args.frames, args.seed, force=args.force)
        print(f"wrote {n} {args.views} survey views to {args.out} in {time.perf_counter() - t0:.1f} s")
        return 0
    if args.format == "rosbag2" and args.drive != "stops":
        return _simulate_drive(args, sim)
    if args.format == "rosbag2":
        return _simulate_recording(args, sim, estimator, dist)
    infos = write_frame_folder(
        args.out, sim, poses, seed=args.seed, jobs=jobs(args.jobs), force=args.force, on_frame=preview
    )
    dt = time.perf_counter() - t0
    print(f"wrote {len(infos)} frames to {args.out} in {dt:.1f} s ({dt / len(infos) * 1000:.0f} ms/frame)")
    if previews:
        with atomic_directory(Path(args.out) / "preview", force=True) as tmp:
            for name, png in previews:
                (tmp / name).write_bytes(png)
        print(f"preview overlays: {Path(args.out) / 'preview'}")
    return 0


def _simulate_drive(args: argparse.Namespace, sim: Simulator) -> int:
    """``simulate --format rosbag2 --drive commissioning|teach``: a continuous drive with odometry."""
    rng = np.random.default_rng([args.seed, 5])
    if args.drive == "commissioning":
        start, legs = commissioning_route(rng)
    else:
        start, legs = teach_start(sim.robot.front_offset, rng), teach_route()
    wheels = tuple(args.wheel_scale) if args.wheel_scale else None
    robot = SimulatedRobot(sim, start, rng=np.random.default_rng([args.seed, 6]), wheel_scale=wheels)
    t0 = time.perf_counter()
    summary = record_drive(args.out, robot, legs, frame_every=args.frame_every, storage=args.storage, force=args.force)
    print(
        f"wrote a {summary.duration_s:.0f} s {args.drive} drive ({summary.images} images, {summary.odometry} "
        f"odometry messages, {summary.bytes / 1e6:.0f} MB) to {args.out} in {time.perf_counter() - t0:.1f} s"
    )
    return 0


def _preview_folder(out: str) -> Path:
    """Where ``--format rosbag2 --preview`` puts its overlays: beside the recording."""
    return Path(str(out).rstrip("/") + "_preview")


def _simulate_recording(args: argparse.Namespace, sim: Simulator, estimator: Estimator, dist: PoseDistribution) -> int:
    """``simulate --format rosbag2``: a stop-and-go data-collection drive written as a rosbag2 recording."""
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
            previews.append((name, estimates_png(frame.image, result, estimator, frame.truth.corners)))

    t0 = time.perf_counter()
    summary = write_recording(
        args.out,
        sim,
        stops,
        seed=args.seed,
        jobs=jobs(args.jobs),
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
        target = _preview_folder(args.out)
        with atomic_directory(target, force=args.force) as tmp:
            for name, png in previews:
                (tmp / name).write_bytes(png)
        print(f"preview overlays: {target}")
    return 0
