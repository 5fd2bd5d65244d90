"""The simulator's frame cost against marker detection on the same frames, where the time goes, and how exact.

For each set-up (the default 640x480 camera, and bench/setups/wide: 1280x720 behind a wide lens with its own
layout and mounts), in this process, pinned to one CPU with OpenCV limited to one thread, on ``--frames``
random poses (after an untimed warm-up that compiles the kernels):

(a) per frame, one call each, interleaved so that load on the machine hits every column alike: the compiled
    renderer (radiance), the camera image (radiance + sensor nuisances, ``Simulator.render``), the whole
    simulated frame (image + LiDAR scan + truth, ``Simulator.frame``), and marker detection with sub-pixel
    corners on that image (``MarkerDetector.detect``); medians and ratios of medians;
(b) the image's stages (culling, corner rays, edge pixels, sensor) and the frame's other parts (LiDAR, truth);
(c) on the first ``--reference-frames`` poses, the numpy reference renderer (``sim.reference``): its time, and
    the agreement of the two images: the largest difference off the edge pixels (pixels whose corners, or a
    neighbour's, see different albedos), the mean difference on them, and on 100 edge pixels per frame each
    renderer's error against 128 x 128 stratified random rays per pixel (World.cast).

Run from the repo root:

    python bench/render_speed.py [--frames 40] [--reference-frames 4] [--seed 0] [--out FILE.md]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from _common import bench_parser, emit, environment, fmt, markdown_table, pin_one_cpu  # noqa: E402
from monodock.core.camera import CameraModel  # noqa: E402
from monodock.core.layout import ROLES, DockLayout  # noqa: E402
from monodock.core.robot import RobotConfig  # noqa: E402
from monodock.perception.detect import MarkerDetector  # noqa: E402
from monodock.sim.nuisance import apply_nuisances  # noqa: E402
from monodock.sim.reference import edge_pixels, pixel_means_by_rays  # noqa: E402
from monodock.sim.reference import render_radiance as reference_radiance  # noqa: E402
from monodock.sim.render import RenderStats, render_radiance  # noqa: E402
from monodock.sim.simulator import Simulator  # noqa: E402

WIDE = Path(__file__).parent / "setups" / "wide"


def _setups() -> dict[str, Simulator]:
    wide = Simulator(
        layout=DockLayout.load(WIDE / "layout.yaml"),
        camera=CameraModel.load(WIDE / "camera.yaml"),
        robot=RobotConfig.load(WIDE / "robot.yaml"),
    )
    return {"640x480 (default)": Simulator(), "1280x720 (wide)": wide}


def _median_ms(values: list[float]) -> float:
    return 1e3 * float(np.median(values))


def _time_poses(
    name: str, sim: Any, poses: list[Any], detector: MarkerDetector, seed: int
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Seconds per pose: the radiance, the image, the whole frame and detection; and each stage of a frame."""
    times: dict[str, list[float]] = {"radiance": [], "image": [], "frame": [], "detection": []}
    stages: dict[str, list[float]] = {}
    for k, pose in enumerate(poses):
        T = sim.world_T_optical(pose)
        stats = RenderStats()
        t = time.perf_counter()
        radiance = render_radiance(sim.world, sim.camera, T, supersample=sim.nuisances.supersample, stats=stats)
        times["radiance"].append(time.perf_counter() - t)
        t = time.perf_counter()
        apply_nuisances(radiance, sim.nuisances, np.random.default_rng(k))
        sensor = time.perf_counter() - t
        for stage, seconds in (
            ("culling", stats.culling_s),
            ("pixel corners", stats.corners_s),
            ("edge pixels", stats.edges_s),
            ("sensor nuisances", sensor),
            ("flat tiles %", 100.0 * stats.flat_tiles),
        ):
            stages.setdefault(stage, []).append(seconds)
        t = time.perf_counter()
        image = sim.render(pose, rng=np.random.default_rng([seed, k]))
        times["image"].append(time.perf_counter() - t)
        t = time.perf_counter()
        sim.frame(pose, rng=np.random.default_rng([seed, k]))
        times["frame"].append(time.perf_counter() - t)
        t = time.perf_counter()
        detector.detect(image)
        times["detection"].append(time.perf_counter() - t)
        t = time.perf_counter()
        sim.scan(pose, rng=np.random.default_rng(k))
        stages.setdefault("LiDAR scan", []).append(time.perf_counter() - t)
        t = time.perf_counter()
        sim.true_corners(pose)
        [sim._visible_fraction(sim.world, pose, r) for r in ROLES]
        stages.setdefault("truth", []).append(time.perf_counter() - t)
        print(f"\r{name}: {k + 1}/{len(poses)}", end="", file=sys.stderr)
    print(file=sys.stderr)
    return times, stages


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=40, frames_help="random poses timed per set-up", seed=0)
    p.add_argument("--reference-frames", type=int, default=4, help="poses also rendered by the reference (4)")
    args = p.parse_args(argv)
    if not 1 <= args.reference_frames <= args.frames:
        p.error(f"--reference-frames must be 1-{args.frames} (--frames), got {args.reference_frames}")
    pinned = pin_one_cpu()

    speed_rows, stage_rows, exact_rows = [], [], []
    raw: dict[str, Any] = {"environment": environment(), "pinned": pinned, "setups": {}}
    for name, sim in _setups().items():
        rng = np.random.default_rng(args.seed)
        poses = [sim.sample_pose(rng=rng) for _ in range(args.frames)]
        detector = MarkerDetector(sim.layout)
        detector.detect(sim.frame(poses[0], rng=np.random.default_rng(0)).image)  # warm-up: compiles, caches
        times, stages = _time_poses(name, sim, poses, detector, args.seed)

        # Exactness and the reference's time, on the first poses.
        ref_times, off_edge_max, edge_mean, new_err, ref_err, edge_share = [], [], [], [], [], []
        for k, pose in enumerate(poses[: args.reference_frames]):
            T = sim.world_T_optical(pose)
            new = render_radiance(sim.world, sim.camera, T, supersample=sim.nuisances.supersample)
            t = time.perf_counter()
            ref = reference_radiance(sim.world, sim.camera, T, supersample=sim.nuisances.supersample)
            ref_times.append(time.perf_counter() - t)
            edges = edge_pixels(sim.world, sim.camera, T)
            diff = np.abs(new.astype(np.float64) - ref) * 255
            off_edge_max.append(float(diff[~edges].max()))
            edge_mean.append(float(diff[edges].mean()))
            edge_share.append(100.0 * float(edges.mean()))
            pick = np.random.default_rng([args.seed, k]).choice(np.argwhere(edges), 100, replace=False)
            truth = pixel_means_by_rays(sim.world, sim.camera, T, pick, rng=np.random.default_rng(k))
            new_err += list(np.abs(new[pick[:, 0], pick[:, 1]] - truth) * 255)
            ref_err += list(np.abs(ref[pick[:, 0], pick[:, 1]] - truth) * 255)

        med = {key: _median_ms(v) for key, v in times.items()}
        ref_ms = _median_ms(ref_times) if ref_times else float("nan")
        speed_rows.append(
            [
                name,
                fmt(med["detection"]),
                fmt(med["radiance"]),
                fmt(med["image"]),
                fmt(med["frame"]),
                fmt(med["image"] / med["detection"], 1),
                fmt(med["frame"] / med["detection"], 1),
                fmt(ref_ms, 0),
                fmt(ref_ms / med["radiance"], 0),
            ]
        )
        stage_ms = {key: (float(np.median(v)) if key.endswith("%") else _median_ms(v)) for key, v in stages.items()}
        stage_rows.append([name] + [fmt(stage_ms[key], 0 if key.endswith("%") else 2) for key in stage_ms])
        exact_rows.append(
            [
                name,
                str(len(ref_times)),
                fmt(max(off_edge_max), 4),
                fmt(float(np.mean(edge_share)), 1),
                fmt(float(np.mean(edge_mean)), 3),
                fmt(float(np.mean(new_err)), 3),
                fmt(float(np.percentile(new_err, 95)), 3),
                fmt(float(np.mean(ref_err)), 3),
                fmt(float(np.percentile(ref_err, 95)), 3),
            ]
        )
        raw["setups"][name] = {
            "median_ms": med,
            "reference_radiance_ms": ref_ms,
            "stages_ms": stage_ms,
            "off_edge_max_dn": off_edge_max,
            "edge_mean_abs_dn": edge_mean,
            "edge_share_pct": edge_share,
            "error_vs_dense_dn": {"compiled": new_err, "reference": ref_err},
        }
        stage_header = ["set-up", *stages.keys()]

    env = raw["environment"]
    report = "\n\n".join(
        [
            f"### Simulator frame cost against detection\n\n`python bench/render_speed.py --frames {args.frames} "
            f"--reference-frames {args.reference_frames} --seed {args.seed}` — {env['date_utc']} UTC, "
            f"{env['machine']}, pinned: {pinned}; medians over {args.frames} random poses, one call each, "
            "milliseconds; ratios of medians from this run.",
            markdown_table(
                [
                    "set-up",
                    "detection ms",
                    "radiance ms",
                    "image ms",
                    "frame ms",
                    "image / detection",
                    "frame / detection",
                    "reference radiance ms",
                    "reference / compiled",
                ],
                speed_rows,
            ),
            "Where an image's and a frame's time goes (medians, ms; flat tiles: share of 16 x 16 tiles filled "
            "without casting):",
            markdown_table(stage_header, stage_rows),
            "Exactness against the numpy reference and against 128 x 128 stratified rays per pixel "
            "(digital numbers, 0-255; edge pixels: corners or a neighbour's corners see different albedos):",
            markdown_table(
                [
                    "set-up",
                    "frames",
                    "max abs diff off edges",
                    "edge pixels %",
                    "mean abs diff on edges",
                    "compiled err mean",
                    "compiled err p95",
                    "reference err mean",
                    "reference err p95",
                ],
                exact_rows,
            ),
        ]
    )
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
