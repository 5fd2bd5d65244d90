"""Live estimation speed: sustained frames per second and per-frame latency of ``monodock run``'s loop.

Renders ``--frames`` default-nuisance 640x480 frames at random poses (in ``--workers`` processes, outside any
timing) into an MJPG .avi, then runs monodock.io.live.run_live on it with the board PnP (and with the regression
when ``--model BUNDLE`` is given), writing CSV rows to a file as ``monodock run --out`` does. Reports what the
run itself measured: sustained fps (rows / wall time, including decoding the video and writing the rows) and
the latency from each frame's arrival to its row, median and p95.

Run from the repo root:

    python bench/live_speed.py [--frames 300] [--model BUNDLE] [--seed 0] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from _common import bench_parser, chunk_seed, emit, environment, fmt, markdown_table, simulate_chunks
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import make_estimator
from monodock.io.frames import open_frames
from monodock.io.live import LiveStats, run_live
from monodock.sim import Simulator

CHUNK = 20
FPS = 15.0


def render_chunk(task: tuple[int, int, int]) -> list[np.ndarray]:
    """The images of one chunk of default-nuisance frames at random poses."""
    seed, chunk, n = task
    sim = Simulator(seed=chunk_seed(seed, chunk))
    return [sim.frame(sim.sample_pose()).image for _ in range(n)]


def write_video(path: Path, images: list[np.ndarray], size: tuple[int, int]) -> None:
    """The frames as an MJPG .avi at FPS, as a webcam recording would be."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), FPS, size)
    if not writer.isOpened():
        sys.exit("cannot write an MJPG .avi with this OpenCV")
    for image in images:
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()


def measure(video: Path, estimator: Estimator, method: str, out: Path) -> LiveStats:
    """One run_live over the video, rows to a CSV file."""
    with open_frames(str(video), skip_bad=True) as source, out.open("w", encoding="utf-8", newline="") as sink:
        return run_live(source, estimator, method, sink=sink)


def main() -> None:
    """Render, run, report."""
    p: argparse.ArgumentParser = bench_parser(__doc__ or "", frames=300, frames_help="frames in the video", seed=0)
    p.add_argument("--model", help="model bundle: also time the regression")
    args = p.parse_args()
    sim = Simulator()
    images = simulate_chunks(render_chunk, args, "render", CHUNK)
    runs: dict[str, LiveStats] = {}
    with tempfile.TemporaryDirectory() as tmp:
        video = Path(tmp) / "drive.avi"
        write_video(video, images, sim.camera.size)
        board = Estimator(sim.camera, sim.layout, sim.robot, ("board",))
        measure(video, board, "board", Path(tmp) / "warmup.csv")  # first calls load OpenCV's code paths
        runs["board"] = measure(video, board, "board", Path(tmp) / "board.csv")
        if args.model:
            est = make_estimator(bundle=args.model, method="regression", camera=sim.camera, robot=sim.robot)
            runs["regression"] = measure(video, est, "regression", Path(tmp) / "regression.csv")
    rows = [
        [
            method,
            str(s.frames),
            str(s.valid),
            fmt(s.fps, 1),
            fmt(s.latency_median_ms),
            fmt(s.latency_p95_ms),
        ]
        for method, s in runs.items()
    ]
    env = environment()
    report = "\n".join(
        [
            f"# Live estimation speed ({args.frames} frames, 640x480 MJPG, seed {args.seed})",
            "",
            markdown_table(["method", "frames", "valid", "sustained fps", "latency median ms", "latency p95 ms"], rows),
            "",
            "fps: rows / wall time of run_live (video decoding, detection, estimate, CSV row flushed). "
            "Latency: frame arrival to its row.",
            "",
            ", ".join(f"{k} {v}" for k, v in env.items()),
        ]
    )
    raw = {"environment": env, "frames": args.frames, "runs": {k: vars(v) for k, v in runs.items()}}
    emit(report, raw, args.out)


if __name__ == "__main__":
    main()
