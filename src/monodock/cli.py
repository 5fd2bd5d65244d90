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
    from monodock.camera import CameraModel
    from monodock.estimate import Estimator, FrameEstimates
    from monodock.layout import DockLayout
    from monodock.robot import RobotConfig
    from monodock.sim import Nuisances

__all__ = ["main"]


# --- shared options -----------------------------------------------------------------------------


def _add_calibration(p: argparse.ArgumentParser, required: bool) -> None:
    p.add_argument("--camera", required=required, help="camera file: ROS camera_info YAML or OpenCV FileStorage")
    p.add_argument("--layout", required=required, help="dock layout YAML")
    p.add_argument("--robot", required=required, help="robot YAML (camera and LiDAR mounts, front_offset)")


def _load_calibration(args: argparse.Namespace) -> tuple[CameraModel, DockLayout, RobotConfig]:
    from monodock.camera import CameraModel
    from monodock.layout import DockLayout
    from monodock.robot import RobotConfig

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


def _jobs(value: int | None) -> int:
    return value if value and value > 0 else max(1, min(4, os.cpu_count() or 1))


# --- simulate -----------------------------------------------------------------------------------


def _cmd_simulate(args: argparse.Namespace) -> int:
    from monodock.atomic import atomic_directory
    from monodock.estimate import Estimator
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
        poses = [sim.sample_pose(dist) for _ in range(args.frames)]
    except RuntimeError as exc:
        raise MonodockError(str(exc)) from None
    previews: list[tuple[str, bytes]] = []
    estimator = Estimator(camera, layout, robot, ("board",))

    def preview(rec: FrameRecord) -> None:
        if rec.index < args.preview:
            result = estimator.estimate(rec.name, rec.stamp, rec.frame.image)
            previews.append((rec.name, _overlay_png(rec.frame.image, result, estimator, rec.frame.truth.corners)))

    t0 = time.perf_counter()
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


def _overlay_png(
    image: np.ndarray,
    result: FrameEstimates,
    estimator: Estimator,
    truth_corners: dict[str, np.ndarray] | None = None,
) -> bytes:
    """The overlay of one estimated frame (its detection and board estimate), PNG-encoded."""
    import cv2

    from monodock.overlay import draw_overlay

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


def _cmd_estimate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from monodock.atomic import check_writable, write_text_atomic
    from monodock.errors import InputError
    from monodock.estimate import Estimator, estimates_csv
    from monodock.inputs import iter_frames

    camera, layout, robot = _load_calibration(args)
    check_writable(args.out, force=args.force)
    est = Estimator(camera, layout, robot, (args.method,), refinement=args.refinement)
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
    write_text_atomic(args.out, estimates_csv(results), force=args.force)
    valid = sum(1 for r in results for e in r.estimates.values() if e.valid)
    print(f"{args.method}: {valid}/{len(results)} frames with an estimate -> {args.out}")
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from monodock.atomic import check_writable, write_bytes_atomic
    from monodock.estimate import Estimator
    from monodock.inputs import read_image

    camera, layout, robot = _load_calibration(args)
    check_writable(args.out, force=args.force)
    image = read_image(args.image)
    estimator = Estimator(camera, layout, robot, ("board",))
    result = estimator.estimate(Path(args.image).name, math.nan, image)
    write_bytes_atomic(args.out, _overlay_png(image, result, estimator), force=args.force)
    print(f"board: {_summary(result)} -> {args.out}")
    return 0


# --- demo ---------------------------------------------------------------------------------------


def _cmd_demo(args: argparse.Namespace) -> int:
    from monodock.atomic import atomic_directory
    from monodock.estimate import Estimator
    from monodock.metrics import pose_errors
    from monodock.report import error_plot, method_tables, write_html_report
    from monodock.sim import Nuisances, PoseDistribution, Simulator
    from monodock.sim.export import FrameRecord, write_frame_folder

    if args.frames < 1:
        raise MonodockError("--frames must be at least 1")
    t0 = time.perf_counter()
    sim = Simulator(nuisances=Nuisances(), seed=args.seed)
    dist = PoseDistribution()
    poses = [sim.sample_pose(dist) for _ in range(args.frames)]
    depth = np.array([p.x - sim.robot.camera_mount.x for p in poses])
    picks = {
        int(np.argmin(np.abs(depth - target))): label for label, target in (("near", 0.4), ("mid", 1.2), ("far", 2.3))
    }
    estimator = Estimator(sim.camera, sim.layout, sim.robot, ("pnp", "board"))
    results: list[FrameEstimates] = []
    overlays: list[tuple[str, str, bytes]] = []

    def estimate(rec: FrameRecord) -> None:
        results.append(estimator.estimate(rec.name, rec.stamp, rec.frame.image))
        if rec.index in picks:
            label = picks[rec.index]
            caption = (
                f"{label}: depth {depth[rec.index]:.2f} m; truth {rec.frame.truth.pose}; board {_summary(results[-1])}"
            )
            png = _overlay_png(rec.frame.image, results[-1], estimator, rec.frame.truth.corners)
            overlays.append((f"overlay_{label}.png", caption, png))

    with atomic_directory(args.out, force=args.force) as out:
        print(f"simulating {args.frames} frames (default nuisances) ...", file=sys.stderr)
        infos = write_frame_folder(out / "sim", sim, poses, seed=args.seed, jobs=_jobs(args.jobs), on_frame=estimate)
        truth = [i.truth.pose for i in infos]
        errors = {m: pose_errors(truth, [r.estimates[m].pose for r in results]) for m in ("pnp", "board")}
        rows = method_tables(depth, errors)
        error_plot(depth, errors, out / "errors_vs_depth.png")
        for name, _, png in overlays:
            (out / name).write_bytes(png)
        settings = {
            "frames": args.frames,
            "seed": args.seed,
            "camera": f"{sim.camera.width}x{sim.camera.height}",
            "layout": f"{sim.layout.dictionary}, marker {sim.layout.marker_size * 100:.0f} cm",
            "pose distribution": (
                f"depth {dist.depth} m from the camera, lateral {dist.lateral} m, yaw {dist.yaw_deg} deg"
            ),
            "nuisances": str(sim.nuisances),
        }
        notes = [
            "pnp: marker 2 alone, SOLVEPNP_IPPE_SQUARE, the IPPE ambiguity resolved by reprojection error and "
            "the dock standing upright on the robot's floor.",
            "board: the corners of all visible markers jointly, iterative PnP refined by Levenberg-Marquardt.",
            "The regression of the papers, the fused estimator and docking join this report in later releases.",
        ]
        write_html_report(
            out,
            title="monodock demo: SolvePnP baselines on the simulator",
            settings=settings,
            rows=rows,
            plot="errors_vs_depth.png",
            overlays=[(name, caption) for name, caption, _ in sorted(overlays)],
            notes=notes,
        )
    overall = {r.method: r for r in rows if r.band == "all"}
    for m, r in overall.items():
        print(
            f"{m:6s} valid {r.valid}/{r.frames}  depth MAE {r.depth_mae_cm:.2f} cm  lateral MAE "
            f"{r.lateral_mae_cm:.2f} cm  yaw MAE {r.yaw_mae_deg:.2f} deg"
        )
    print(f"report: {Path(args.out) / 'report.html'}  ({time.perf_counter() - t0:.0f} s)")
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
    s.add_argument("--jobs", type=int, help="worker processes (default: cores, at most 4)")
    s.add_argument("--force", action="store_true", help="replace an existing output folder")
    _add_calibration(s, required=False)
    _add_nuisances(s)
    s.set_defaults(func=_cmd_simulate)

    e = sub.add_parser("estimate", help="estimate the DockPose in images, folders or videos")
    e.add_argument("inputs", nargs="+", metavar="INPUT", help="image files, folders of images, or videos")
    e.add_argument(
        "--method",
        choices=("pnp", "board"),
        default="board",
        help="pnp: marker 2 alone (IPPE_SQUARE), the papers' baseline; board: all visible markers (default)",
    )
    e.add_argument("--out", required=True, help="EST.csv to write")
    e.add_argument(
        "--refinement", choices=("none", "subpix", "contour"), default="subpix", help="ArUco corner refinement"
    )
    e.add_argument("--skip-bad", action="store_true", help="an unreadable image gives an invalid row, not an error")
    e.add_argument("--force", action="store_true", help="overwrite an existing output")
    _add_calibration(e, required=True)
    e.set_defaults(func=_cmd_estimate)

    w = sub.add_parser("show", help="overlay PNG: detected markers, ids and the board estimate's dock axes")
    w.add_argument("image")
    w.add_argument("--out", required=True, help="PNG to write")
    w.add_argument("--force", action="store_true")
    _add_calibration(w, required=True)
    w.set_defaults(func=_cmd_show)

    d = sub.add_parser("demo", help="simulate, estimate with every method, and write the report")
    d.add_argument("--out", default="demo_report", help="report folder (default: demo_report)")
    d.add_argument("--frames", type=int, default=300)
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
