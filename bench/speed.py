"""Per-frame cost on one core: marker detection + features, single-marker PnP, board PnP, and the renderer.

First renders ``--frames`` default-nuisance 640x480 frames at random poses (in 2 processes, outside any
timing). Then, in this process, pinned to one CPU with OpenCV and the BLAS/OpenMP pools limited to one
thread, times per frame with time.perf_counter, each call repeated ``--repeat`` times and the minimum kept:

(a) detection + features: MarkerDetector(layout).detect (sub-pixel corners) + features.feature_vector,
    also split into its two parts;
(b) single-marker PnP: pnp.estimate_single_marker, on the frames where marker 2 was detected;
(c) board PnP: pnp.estimate_board, on the frames where at least one dock marker was detected;
(d) for information, the simulator: Simulator.frame (render + nuisances + LiDAR scan + truth) on
    ``--render-frames`` (default 20) further poses, one call each;
(e) the refined corners alone: refine.refine_detection on the detection;
(f) the fused method end to end: Estimator(methods=("fused",)).estimate on the image (detection, refined
    corners, the regression where it can help, the planar fit and the fusion). With ``--model BUNDLE`` the
    bundle's regression and tables (its camera, layout and mounts must be the simulator's defaults); without,
    the geometry alone with default tables;
(e1), (f1) the refined corners, and the planar fit plus fusion (FusedEstimator.estimate), each timed right
    after an untimed detection of the same image: as they run in (f), with the detection's memory traffic
    between calls, which makes every call (numpy, OpenCV, the interpreter's own) dearer than in (e)'s loop of
    repeats.

Reports median and p90 milliseconds per frame, and ratios of medians measured in the same run.

Run from the repo root:

    python bench/speed.py [--frames 200] [--seed 0] [--model BUNDLE] [--out FILE.md]
"""

from __future__ import annotations

import os

# One thread everywhere, set before numpy and OpenCV are imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from _common import bench_parser, chunk_seed, emit, environment, fmt, markdown_table, pin_one_cpu, simulate_chunks  # noqa: E402
from monodock.estimation.bundle import load_bundle  # noqa: E402
from monodock.estimation.estimator import Estimator  # noqa: E402
from monodock.estimation.factory import make_estimator  # noqa: E402
from monodock.estimation.fused import FusionTables  # noqa: E402
from monodock.estimation.methods import FusedMethod, MethodSetup, build_methods  # noqa: E402
from monodock.estimation.pnp import estimate_board, estimate_single_marker  # noqa: E402
from monodock.perception.detect import Detection, MarkerDetector  # noqa: E402
from monodock.perception.features import feature_vector  # noqa: E402
from monodock.perception.refine import refine_detection  # noqa: E402
from monodock.sim import Simulator  # noqa: E402

CHUNK = 20


def _fused_estimator(model: str | None, camera: Any, layout: Any, robot: Any) -> Estimator:
    """The fused method as ``monodock estimate --method fused`` runs it (geometry alone without a bundle)."""
    if model is None:
        geometry = MethodSetup(camera, layout, robot, tables=FusionTables(0.22))
        return Estimator(camera, layout, robot, build_methods(("fused",), geometry))
    bundle = load_bundle(Path(model))
    if bundle.layout() != layout or bundle.robot() != robot:
        raise SystemExit(f"{model}: the bundle is not for the simulator's default layout and mounts")
    return make_estimator(method="fused", bundle=bundle, camera=camera, layout=layout, robot=robot)


def render_chunk(task: tuple[int, int, int]) -> list[np.ndarray]:
    """The images of one chunk of default-nuisance frames at random poses."""
    seed, chunk, n = task
    sim = Simulator(seed=chunk_seed(seed, chunk))
    return [sim.frame(sim.sample_pose()).image for _ in range(n)]


def after_detection(detect: Callable[[], Any], fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """The fastest of ``repeat`` calls of ``fn``, each right after an untimed ``detect()``, in seconds."""
    best = float("inf")
    result = None
    for _ in range(repeat):
        detect()
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def best_of(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """The fastest of ``repeat`` calls, in seconds, and the last result."""
    best = float("inf")
    result = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def _busy_seconds() -> float | None:
    """CPU seconds all processes on the machine have used since boot (Linux /proc/stat), or None."""
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    # user nice system idle iowait irq softirq steal ...: everything but idle and iowait is busy.
    busy = sum(int(v) for i, v in enumerate(fields[1:9]) if i not in (3, 4))
    return busy / os.sysconf("SC_CLK_TCK")


def _own_seconds() -> float:
    t = os.times()
    return t.user + t.system


def _stat(ms: list[float]) -> dict[str, float]:
    a = np.asarray(ms)
    if a.size == 0:
        return {"n": 0, "median_ms": float("nan"), "p90_ms": float("nan"), "min_ms": float("nan")}
    return {
        "n": int(a.size),
        "median_ms": float(np.median(a)),
        "p90_ms": float(np.percentile(a, 90)),
        "min_ms": float(a.min()),
    }


def _time_frame(
    img: np.ndarray, detector: MarkerDetector, fused: Estimator, repeat: int, times: dict[str, list[float]]
) -> int:
    """Time every stage on one frame (the fastest of ``repeat`` calls each) into ``times``; the markers seen."""
    camera, layout, robot = fused.camera, fused.layout, fused.robot
    t, _ = best_of(lambda: feature_vector(detector.detect(img), camera), repeat)
    times["detect_features"].append(1e3 * t)
    t, det = best_of(lambda: detector.detect(img), repeat)
    times["detect"].append(1e3 * t)
    assert isinstance(det, Detection)
    t, _ = best_of(lambda: feature_vector(det, camera), repeat)
    times["features"].append(1e3 * t)
    if det.seen("center"):
        t, _ = best_of(lambda: estimate_single_marker(det, camera, layout, robot), repeat)
        times["pnp"].append(1e3 * t)
    if det.roles_seen:
        t, _ = best_of(lambda: estimate_board(det, camera, layout, robot), repeat)
        times["board"].append(1e3 * t)
        t, _ = best_of(lambda: refine_detection(img, det, camera, modules=layout.modules), repeat)
        times["refine"].append(1e3 * t)
        t, refined = after_detection(
            lambda: detector.detect(img), lambda: refine_detection(img, det, camera, modules=layout.modules), repeat
        )
        times["refine_after"].append(1e3 * t)
        method = fused.pose_methods["fused"]
        assert isinstance(method, FusedMethod)
        t, _ = after_detection(lambda: detector.detect(img), lambda: method.fused.estimate(det, refined), repeat)
        times["combine_after"].append(1e3 * t)
    t, _ = best_of(lambda: fused.estimate("", 0.0, img), repeat)
    times["fused"].append(1e3 * t)
    return len(det.roles_seen)


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=200, frames_help="pre-rendered frames to time on", seed=0)
    p.add_argument("--repeat", type=int, default=5, help="calls per frame; the fastest counts (default 5)")
    p.add_argument("--render-frames", type=int, default=20, help="frames to time the renderer on (default 20)")
    p.add_argument("--model", help="model bundle for the fused method's regression and tables")
    args = p.parse_args(argv)
    if args.repeat < 1 or args.render_frames < 0:
        p.error("--repeat must be at least 1, --render-frames at least 0")

    images: list[np.ndarray] = simulate_chunks(render_chunk, args, "pre-render", CHUNK)

    # Timing from here on: one thread, one CPU.
    pinned = pin_one_cpu()

    sim = Simulator(seed=chunk_seed(args.seed, 10**6))
    camera, layout, robot = sim.camera, sim.layout, sim.robot
    detector = MarkerDetector(layout)
    fused = _fused_estimator(args.model, camera, layout, robot)
    for _ in range(3):  # warm-up: lazy initialisation, caches
        fused.estimate("", 0.0, images[0])
        d0 = detector.detect(images[0])
        feature_vector(d0, camera)
        estimate_board(d0, camera, layout, robot)
        estimate_single_marker(d0, camera, layout, robot)

    from tqdm import tqdm

    busy0, own0, wall0 = _busy_seconds(), _own_seconds(), time.perf_counter()
    keys = ("detect_features", "detect", "features", "pnp", "board", "refine", "refine_after", "combine_after", "fused")
    times: dict[str, list[float]] = {k: [] for k in keys}
    markers_seen: list[int] = []
    for img in tqdm(images, desc="timing", unit="frame", file=sys.stderr, dynamic_ncols=True):
        markers_seen.append(_time_frame(img, detector, fused, args.repeat, times))

    render_ms: list[float] = []
    bar = tqdm(range(args.render_frames), desc="renderer", unit="frame", file=sys.stderr, dynamic_ncols=True)
    for _ in bar:
        pose = sim.sample_pose()
        t0 = time.perf_counter()
        sim.frame(pose)
        render_ms.append(1e3 * (time.perf_counter() - t0))
    times["render"] = render_ms
    busy1, own1, wall1 = _busy_seconds(), _own_seconds(), time.perf_counter()
    others = (
        max(0.0, (busy1 - busy0) - (own1 - own0)) / (wall1 - wall0)
        if busy0 is not None and busy1 is not None
        else float("nan")
    )

    stats = {k: _stat(v) for k, v in times.items()}
    labels = {
        "detect_features": "(a) detection + features",
        "detect": "(a1) detection only (MarkerDetector.detect)",
        "features": "(a2) features only (feature_vector)",
        "pnp": "(b) single-marker PnP (IPPE_SQUARE)",
        "board": "(c) board PnP (iterative + IPPE starts, LM)",
        "render": "(d) simulator: Simulator.frame",
        "refine": "(e) refined corners (refine_detection)",
        "refine_after": "(e1) refined corners, right after a detection",
        "combine_after": "(f1) planar fit + fusion (FusedEstimator.estimate), right after a detection",
        "fused": "(f) fused, end to end from the image" + ("" if args.model else " (geometry only: no --model)"),
    }
    rows = [[labels[k], str(stats[k]["n"]), fmt(stats[k]["median_ms"], 3), fmt(stats[k]["p90_ms"], 3)] for k in labels]
    med = {k: s["median_ms"] for k, s in stats.items()}
    ratios = {
        "board PnP / (detection + features)": med["board"] / med["detect_features"],
        "single-marker PnP / (detection + features)": med["pnp"] / med["detect_features"],
        "board PnP / single-marker PnP": med["board"] / med["pnp"],
        "features / detection": med["features"] / med["detect"],
        "simulator frame / (detection + features)": med["render"] / med["detect_features"],
        "refined corners / detection": med["refine"] / med["detect"],
        "refined corners right after a detection / in a loop": med["refine_after"] / med["refine"],
        "fused end to end / detection (target ≤ 1.1)": med["fused"] / med["detect"],
    }
    env = environment()
    counts = np.bincount(markers_seen, minlength=4)
    lines = [
        "### Per-frame cost on one core (640x480, default nuisances)",
        "",
        f"`python bench/speed.py --frames {args.frames} --seed {args.seed}` — {env['date_utc']} UTC, "
        f"OpenCV {env['opencv']}, {env['machine']}, timing pinned to {pinned}, 1 thread, "
        f"best of {args.repeat} calls per frame; other processes used {fmt(others)} CPU cores on average "
        "while it timed (0 = a quiet machine). "
        "Dock markers detected per frame: " + ", ".join(f"{i}: {counts[i]}" for i in range(4)) + ".",
        "",
        markdown_table(["stage", "frames", "median ms", "p90 ms"], rows),
        "",
        markdown_table(["ratio (medians, same run)", "value"], [[k, fmt(v, 3)] for k, v in ratios.items()]),
    ]
    report = "\n".join(lines)
    raw = {
        "benchmark": "speed",
        "args": vars(args),
        "environment": env,
        "pinned": pinned,
        "other_processes_cores": others,
        "stats": stats,
        "ratios": ratios,
        "markers_seen_histogram": counts.tolist(),
        "times_ms": times,
    }
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
