"""What the Cramér–Rao bound says each set-up change buys: marker size, spacing, camera resolution.

For the default layout, camera and robot, monodock.estimation.crlb.what_if bounds the DockPose error of any unbiased
estimator from the markers' corners, by 25 cm depth band (25-250 cm from the camera), on a grid of poses per
band (5 depths x 9 lateral offsets in +-40 cm x 7 yaws in +-30 deg; a pose counts when the current set-up
sees marker 2 fully, 3 px from the border, as the simulator's default PoseDistribution requires), for:
the current set-up; markers x1.5 and x2; side-marker spacing x1.5; camera resolution x2 (1280x960, focal
x2, same lens); and a combination that fits the default 60 cm charger face (markers x1.5, side markers out
to the face's edges, the x2 camera). Each variant uses the markers it sees fully at each pose.

Corner noise (the model documented in monodock.estimation.crlb): sigma = c * sqrt((1/L1 + 1/L2) / 2) px for a corner
whose two edges are L1 and L2 px long (c/sqrt(L) on a square marker), and at least ``--small-sigma`` px when
the edges (harmonic mean) are under ``--small-side`` px, where OpenCV's SUBPIX corners stop following the
edge-fit law. ``--measure-c`` measures c and the small-marker sigma first: it renders ``--frames``
default-nuisance frames, detects the markers (MarkerDetector, SUBPIX), and fits the random part of the
corner errors against the simulator's true corners (per corner: the perpendicular error and the outward
error less its mean in the corner's size band, since the inward shrink is a bias, not noise; unoccluded
markers, corners > 3 px off left out). The overall figures are also given for the pure edge-fit model.

Figures are the root-mean-square over each band's poses of the bound's standard deviation (x and y in cm,
yaw in degrees) and their ratios to the current set-up (below 1 is better). ``--timing`` also times
monodock.estimation.planar.solve_planar on one pinned core: noisy (sigma 0.3 px) true corners of 3-marker frames from
a start 1 cm / 1 deg off, best of ``--repeat`` calls per frame.

Run from the repo root:

    python bench/crlb_whatif.py [--corner-c C] [--measure-c --frames 200 --seed 3] [--timing]
                                [--plot FILE.png] [--out FILE.md]
"""

from __future__ import annotations

import os

# One thread everywhere (the timing is per core), set before numpy and OpenCV are imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from functools import partial  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from _common import bench_parser, chunk_seed, emit, environment, fmt, markdown_table, pin_one_cpu, simulate_chunks  # noqa: E402
from monodock.core.camera import CameraModel  # noqa: E402
from monodock.core.layout import ROLES, DockLayout  # noqa: E402
from monodock.core.pose import DockPose  # noqa: E402
from monodock.core.robot import RobotConfig  # noqa: E402
from monodock.estimation.corner_noise import (  # noqa: E402
    DEFAULT_CORNER_C,
    DEFAULT_SMALL_SIDE_PX,
    DEFAULT_SMALL_SIGMA_PX,
    CornerNoise,
    corner_sides_px,
)
from monodock.estimation.planar import solve_planar  # noqa: E402
from monodock.estimation.planar_starts import planar_candidates  # noqa: E402
from monodock.evaluation.what_if import WhatIfResult, what_if  # noqa: E402
from monodock.perception.detect import MarkerDetector  # noqa: E402
from monodock.sim import PoseDistribution, Simulator  # noqa: E402

CHUNK = 10
GROSS_PX = 3.0
# Corner size bands for measuring c: the harmonic mean of a corner's two edge lengths, px, [lo, hi).
SIZE_BANDS: tuple[tuple[float, float], ...] = (
    (0.0, 26.0),
    (26.0, 31.0),
    (31.0, 34.0),
    (34.0, 40.0),
    (40.0, 50.0),
    (50.0, 65.0),
    (65.0, 85.0),
    (85.0, 120.0),
    (120.0, math.inf),
)


# --- measuring c ----------------------------------------------------------------------------------------


def measure_chunk(task: tuple[int, int, int]) -> list[dict[str, Any]]:
    """Render one chunk of default-nuisance frames; per corner of each unoccluded detected marker: its
    effective edge length and its outward and perpendicular errors against the true corner."""
    seed, chunk, n = task
    sim = Simulator(seed=chunk_seed(seed, chunk))
    detector = MarkerDetector(sim.layout)
    out: list[dict[str, Any]] = []
    for _ in range(n):
        frame = sim.frame(sim.sample_pose())
        det = detector.detect(frame.image)
        for role in ROLES:
            obs = det.observations.get(role)
            if obs is None or not frame.truth.in_view[role] or frame.truth.visible_fraction[role] < 1.0:
                continue
            true = frame.truth.corners[role]
            centre = _diagonal_intersection(true)
            outward = true - centre
            outward /= np.linalg.norm(outward, axis=1, keepdims=True)
            perp = np.stack([-outward[:, 1], outward[:, 0]], axis=1)
            err = obs.corners - true
            sides = corner_sides_px(true)
            length = 2.0 / (1.0 / sides[:, 0] + 1.0 / sides[:, 1])
            for k in range(4):
                out.append(
                    {
                        "length": float(length[k]),
                        "outward": float(err[k] @ outward[k]),
                        "perp": float(err[k] @ perp[k]),
                    }
                )
    return out


def _diagonal_intersection(c: np.ndarray) -> np.ndarray:
    """Where the quadrilateral's diagonals cross (the marker centre's image)."""
    p, r = c[0], c[2] - c[0]
    q, s = c[1], c[3] - c[1]
    t = float(np.cross(q - p, s) / np.cross(r, s))
    return np.asarray(p + t * r)


def fit_noise(records: list[dict[str, Any]], small_side: float) -> tuple[float, float, list[dict[str, float]]]:
    """c and the small-marker sigma from the corners' random errors (outward error less its size band's mean,
    and the perpendicular error; per axis): c² = Σ e² / Σ 1/L pooled over corners whose edges are at least
    1.1 × ``small_side`` px (clear of the transition), small sigma = RMS over corners under ``small_side``;
    and per size band: corners, mean length, outward bias, sigma and the c that band alone gives."""
    L = np.array([r["length"] for r in records])
    out = np.array([r["outward"] for r in records])
    perp = np.array([r["perp"] for r in records])
    ok = np.hypot(out, perp) <= GROSS_PX
    L, out, perp = L[ok], out[ok], perp[ok]
    sq = np.full_like(L, np.nan)
    rows = []
    for lo, hi in SIZE_BANDS:
        m = (lo <= L) & (hi > L)
        if m.sum() < 8:
            continue
        centred = out[m] - out[m].mean()
        sq[m] = 0.5 * (perp[m] ** 2 + centred**2)
        sigma = math.sqrt(float(sq[m].mean()))
        rows.append(
            {
                "lo": lo,
                "hi": hi,
                "corners": int(m.sum()),
                "length": float(L[m].mean()),
                "bias": float(out[m].mean()),
                "sigma": sigma,
                "c": sigma / math.sqrt(float(np.mean(1.0 / L[m]))),
            }
        )
    big = np.isfinite(sq) & (1.1 * small_side <= L)
    small = np.isfinite(sq) & (small_side > L)
    c = math.sqrt(float(sq[big].sum() / np.sum(1.0 / L[big]))) if big.any() else math.nan
    small_sigma = math.sqrt(float(sq[small].mean())) if small.any() else 0.0
    return c, small_sigma, rows


# --- timing ---------------------------------------------------------------------------------------------


def time_solver(seed: int, frames: int, repeat: int) -> dict[str, Any]:
    """Per-call time of solve_planar (3 markers, good start) and planar_candidates, pinned to one core."""
    pinned = pin_one_cpu()
    sim = Simulator(seed=chunk_seed(seed, 10**6))
    rng = np.random.default_rng(seed)
    dist = PoseDistribution(require_in_view=ROLES)
    args = (sim.camera, sim.layout, sim.robot)
    cases: dict[str, list[float]] = {"solve_3": [], "solve_1": [], "candidates_1": [], "candidates_3": []}
    iterations: list[int] = []
    for _ in range(frames):
        truth = sim.sample_pose(dist, rng=rng)
        noisy = {r: c + rng.normal(0.0, 0.3, (4, 2)) for r, c in sim.true_corners(truth).items()}
        start = DockPose(truth.x + 0.01, truth.y - 0.01, truth.yaw + math.radians(1.0))
        one = {"center": noisy["center"]}
        calls: dict[str, Callable[[], object]] = {
            "solve_3": partial(solve_planar, noisy, *args, start=start),
            "solve_1": partial(solve_planar, one, *args, start=start),
            "candidates_1": partial(planar_candidates, one, *args),
            "candidates_3": partial(planar_candidates, noisy, *args),
        }
        for name, fn in calls.items():
            fn()  # warm-up (caches)
            best = math.inf
            for _ in range(repeat):
                t0 = time.perf_counter()
                fn()
                best = min(best, time.perf_counter() - t0)
            cases[name].append(1e3 * best)
        iterations.append(solve_planar(noisy, *args, start=start).iterations)
    stats = {k: {"median_ms": float(np.median(v)), "p90_ms": float(np.percentile(v, 90))} for k, v in cases.items()}
    return {"pinned": pinned, "stats": stats, "iterations_mean": float(np.mean(iterations)), "frames": frames}


# --- report ---------------------------------------------------------------------------------------------


UNITS = (100.0, 100.0, 180.0 / math.pi)  # x, y: m -> cm; yaw: rad -> deg


def _band_label(lo: float, hi: float) -> str:
    return f"{round(100 * lo)}-{round(100 * hi)} cm"


def tables(res: WhatIfResult) -> list[str]:
    """The current set-up's bound by band, the overall figures per variant, and per-band ratios."""
    cur = [
        [_band_label(*b), str(res.poses[0, i]), *(fmt(res.sd[0, i, k] * UNITS[k], 3) for k in range(3))]
        for i, b in enumerate(res.bands)
    ]
    cur.append(["all", str(res.poses[0].sum()), *(fmt(res.overall[0, k] * UNITS[k], 3) for k in range(3))])
    ratio = res.overall_ratio()
    overall = [
        [
            v,
            *(fmt(res.overall[i, k] * UNITS[k], 3) for k in range(3)),
            *(fmt(ratio[i, k], 2) for k in range(3)),
        ]
        for i, v in enumerate(res.variants)
    ]
    r = res.ratio()
    per_band = [
        [_band_label(*b), *("/".join(fmt(r[v, i, k], 2) for k in range(3)) for v in range(1, len(res.variants)))]
        for i, b in enumerate(res.bands)
    ]
    return [
        markdown_table(["depth band", "poses", "x sd cm", "y sd cm", "yaw sd deg"], cur),
        markdown_table(["variant", "x sd cm", "y sd cm", "yaw sd deg", "x ratio", "y ratio", "yaw ratio"], overall),
        markdown_table(["depth band", *(f"{v}: x/y/yaw" for v in res.variants[1:])], per_band),
    ]


def plot(res: WhatIfResult, path: Path) -> None:
    """Bound sd against depth, one line per variant, for x, y and yaw (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = [50 * (lo + hi) for lo, hi in res.bands]  # cm
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for k, (ax, name) in enumerate(zip(axes, ("x (depth) sd, cm", "y (lateral) sd, cm", "yaw sd, deg"), strict=True)):
        for v, label in enumerate(res.variants):
            ax.plot(centres, res.sd[v, :, k] * UNITS[k], marker="o", ms=3, label=label)
        ax.set_yscale("log")
        ax.set_xlabel("depth from camera, cm")
        ax.set_title(name)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Cramér–Rao bound on the DockPose by depth (RMS over poses in each 25 cm band)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=200, frames_help="frames rendered by --measure-c", seed=3)
    p.add_argument("--corner-c", type=float, default=DEFAULT_CORNER_C, help=f"c, px^1.5 (default {DEFAULT_CORNER_C})")
    p.add_argument("--floor", type=float, default=0.02, help="smallest corner sigma, px (default 0.02)")
    p.add_argument(
        "--small-side",
        type=float,
        default=DEFAULT_SMALL_SIDE_PX,
        help=f"edge length below which corners are small-marker corners, px (default {DEFAULT_SMALL_SIDE_PX})",
    )
    p.add_argument(
        "--small-sigma",
        type=float,
        default=DEFAULT_SMALL_SIGMA_PX,
        help=f"sigma of small-marker corners, px; 0 = pure c/sqrt(L) (default {DEFAULT_SMALL_SIGMA_PX})",
    )
    p.add_argument("--measure-c", action="store_true", help="measure c and the small sigma on rendered frames first")
    p.add_argument("--timing", action="store_true", help="also time the planar solver on one core")
    p.add_argument("--timing-frames", type=int, default=100, help="poses to time on (default 100)")
    p.add_argument("--repeat", type=int, default=20, help="timed calls per pose, fastest kept (default 20)")
    p.add_argument("--plot", help="write a PNG of bound sd against depth per variant")
    args = p.parse_args(argv)
    if not args.corner_c > 0 or min(args.floor, args.small_side, args.small_sigma) < 0:
        p.error("--corner-c must be positive, --floor, --small-side and --small-sigma not negative")
    if args.timing_frames < 1 or args.repeat < 1:
        p.error("--timing-frames and --repeat must be at least 1")

    env = environment()
    lines: list[str] = []
    raw: dict[str, Any] = {"benchmark": "crlb_whatif", "args": vars(args), "environment": env}
    c, small_sigma = args.corner_c, args.small_sigma
    if args.measure_c:
        records = simulate_chunks(measure_chunk, args, "measure c", CHUNK)
        c, small_sigma, rows = fit_noise(records, args.small_side)
        raw["measured_noise"] = {"c": c, "small_sigma": small_sigma, "bands": rows, "corners": len(records)}
        lines += [
            "### Corner noise, measured",
            "",
            f"`python bench/crlb_whatif.py --measure-c --frames {args.frames} --seed {args.seed}` — "
            f"{env['date_utc']} UTC, OpenCV {env['opencv']}: {len(records)} corners of unoccluded detected "
            "markers on default-nuisance frames (MarkerDetector, SUBPIX), against the true corners. L: the "
            "harmonic mean of the corner's two edge lengths; outward bias: the mean error along centre→corner "
            "(negative: inside, a bias the bound leaves out); sigma: per axis, that bias removed. "
            f"Fit: **c = {c:.2f} px^1.5** on corners with L ≥ {1.1 * args.small_side:.0f} px, **small-marker "
            f"sigma = {small_sigma:.2f} px** under {args.small_side:g} px.",
            "",
            markdown_table(
                ["L band", "corners", "mean L px", "outward bias px", "sigma px", "c = sigma·sqrt(L)"],
                [
                    [
                        f"{r['lo']:.0f}-{r['hi']:.0f} px" if math.isfinite(r["hi"]) else f"≥ {r['lo']:.0f} px",
                        str(r["corners"]),
                        fmt(r["length"], 1),
                        fmt(r["bias"], 3),
                        fmt(r["sigma"], 3),
                        fmt(r["c"], 2),
                    ]
                    for r in rows
                ],
            ),
            "",
        ]

    camera, layout, robot = CameraModel.default(), DockLayout.default(), RobotConfig.default()
    print("bounding the variants (the x2 camera's field takes a few seconds to set up) ...", file=sys.stderr)
    t0 = time.perf_counter()
    noise = CornerNoise(c=c, floor_px=args.floor, small_side_px=args.small_side, small_sigma_px=small_sigma)
    res = what_if(camera, layout, robot, noise=noise)
    seconds = time.perf_counter() - t0
    pure = what_if(camera, layout, robot, noise=CornerNoise(c=c, floor_px=args.floor, small_sigma_px=0.0))
    raw["what_if"] = {
        "variants": res.variants,
        "bands": res.bands,
        "sd": res.sd,
        "poses": res.poses,
        "overall": res.overall,
        "seconds": seconds,
        "pure_edge_fit": {"sd": pure.sd, "overall": pure.overall},
    }
    t_current, t_overall, t_bands = tables(res)
    _, pure_overall, _ = tables(pure)
    cmd = "python bench/crlb_whatif.py" + (
        f" --measure-c --frames {args.frames} --seed {args.seed}"
        if args.measure_c
        else "".join(
            f" --{name.replace('_', '-')} {getattr(args, name)}"
            for name, default in (
                ("corner_c", DEFAULT_CORNER_C),
                ("small_side", DEFAULT_SMALL_SIDE_PX),
                ("small_sigma", DEFAULT_SMALL_SIGMA_PX),
            )
            if getattr(args, name) != default
        )
    )
    lines += [
        "### Cramér–Rao bound on the DockPose: which change buys how much",
        "",
        f"`{cmd}` — {env['date_utc']} UTC, OpenCV {env['opencv']}, {seconds:.1f} s. Default layout (10 cm "
        f"markers, sides at ±20 cm), camera (640x480, f 615 px) and robot; corner sigma = {c:.2f}/sqrt(L) px "
        f"(floor {args.floor} px), at least {small_sigma:.2f} px for corners with edges under {args.small_side:g} "
        "px. RMS over each band's poses of the bound's standard deviation.",
        "",
        "Current set-up:",
        "",
        t_current,
        "",
        "Every variant over all bands (ratio: to the current set-up; below 1 is better):",
        "",
        t_overall,
        "",
        "Ratio to the current set-up per band (x/y/yaw):",
        "",
        t_bands,
        "",
        f"For comparison, the pure edge-fit model (sigma = {c:.2f}/sqrt(L) at every size, no small-marker term):",
        "",
        pure_overall,
    ]
    if args.timing:
        timing = time_solver(args.seed, args.timing_frames, args.repeat)
        raw["timing"] = timing
        st = timing["stats"]
        labels = {
            "solve_3": "solve_planar, 3 markers, start 1 cm / 1° off",
            "solve_1": "solve_planar, marker 2 alone, start 1 cm / 1° off",
            "candidates_1": "planar_candidates, marker 2 alone (IPPE starts)",
            "candidates_3": "planar_candidates, 3 markers (IPPE starts)",
        }
        lines += [
            "",
            "### Planar solver cost on one core",
            "",
            f"`python bench/crlb_whatif.py --timing --timing-frames {args.timing_frames} --repeat {args.repeat} "
            f"--seed {args.seed}` — {timing['frames']} poses with all three "
            f"markers in view, true corners + 0.3 px noise, timing pinned to {timing['pinned']}, best of "
            f"{args.repeat} calls per pose; solve_planar used {timing['iterations_mean']:.2f} projections on "
            "average (3 markers).",
            "",
            markdown_table(
                ["call", "median ms", "p90 ms"],
                [[labels[k], fmt(v["median_ms"], 3), fmt(v["p90_ms"], 3)] for k, v in st.items()],
            ),
        ]
    if args.plot:
        plot(res, Path(args.plot))
        print(f"wrote {args.plot}", file=sys.stderr)
    emit("\n".join(lines), raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
