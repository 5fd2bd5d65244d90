"""Detection range: the chance that ArUco decodes a dock marker with its right id, against its pixels per code cell.

The detection model a dock designer needs (issue 28): how many pixels a code cell must cover in the image for
monodock's detector (monodock.perception.detect.MarkerDetector, as monodock.estimation.estimator.Estimator
builds it: SUBPIX refinement, OpenCV's default DetectorParameters otherwise) to find a marker, measured on the
simulator's exact renders of the default 640x480 camera (f = 615 px).

Four settings: the default dock (DICT_4X4_50, ids 1-3, 10 cm) and the same dock in DICT_5X5_100 (ids 40-42 as in
bench/setups/wide/layout.yaml; same 10 cm markers and places), each with the default nuisances (Nuisances(): a
cheap indoor webcam, defocus 0.6 px, noise, exposure jitter, clutter with ArUco markers of other ids) and with
heavy motion blur on top (``--motion-blur``, default 6 px: the heaviest level of `monodock evaluate --robustness`'s
motion-blur axis; its direction drawn per frame).

Poses: distance log-uniform in [``--min-distance``, ``--max-distance``] (default 1-8 m), the robot facing the dock
with a lateral offset up to 0.25 x distance, and the dock's yaw (the bearing from the dock's axis, so the markers'
obliquity) uniform in +-``--max-yaw`` (default 60 deg). Every dock marker with its four true corners 4 px or more
inside the image is one trial (``Simulator.render`` is the image ``Simulator.frame`` returns; the markers lie flat
on the charger face, so nothing hides them).

Pixels per cell: sqrt(projected area of the true quad) / layout.modules (6 for 4x4, 7 for 5x5: cells across with
the black border). The square root of the area is the geometric mean of the marker's width and height, so
px/cell squared is the image area of one cell; the mean of the four edges over-weights the long side of a
foreshortened marker. Both, and the shortest edge / modules, are fitted, and their log-likelihoods compared.

Outcome per marker, from the quads and ids the detector's own cv2.aruco.ArucoDetector returns: "right" when a quad
with the marker's id has its centre within 0.35 side of the true centre; "wrong" when a quad there carries
another id (a mis-decode, which the pose would trust); else "miss".

Fit: logistic in log(px/cell) by maximum likelihood (p = 1 / (1 + exp(-(a + b ln x)))), with the px/cell at 50, 90
and 99 % and a bootstrap 95 % interval over markers (frames' markers are not independent, so it is optimistic).
"empirical" thresholds: the upper edge of the highest 0.25 bin of >= 10 markers below the rate (every such bin above
it is at or above the rate).

Run from the repo root:

    python bench/detection_range.py [--frames 3000] [--seed 0] [--quick] [--plot docs/detection_range.png]
                                    [--motion-blur PX] [--out FILE.md]

``--frames`` is per setting; ``--quick`` is 300 a setting and 50 bootstrap resamples. Renders run in 2 processes,
each chunk seeded from (seed, setting, chunk), so the numbers do not depend on the number of workers.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from _common import bench_parser, chunk_seed, chunks, emit, environment, fmt, markdown_table, parallel_map
from monodock.core.layout import DockLayout, MarkerSpec
from monodock.core.pose import DockPose
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.sim import Nuisances, Simulator

CHUNK = 25
BIN = 0.25
TOP = 10.0  # the bin table's last row holds every marker from here up
MIN_BIN_COUNT = 10
LEVELS = (0.5, 0.9, 0.99)
METRICS = ("area", "mean", "short")
METRIC_NAMES = {
    "area": "sqrt(area) / modules",
    "mean": "mean edge / modules",
    "short": "shortest edge / modules",
}
BORDER_MARGIN_PX = 4.0


@dataclass(frozen=True)
class Setting:
    key: str
    dictionary: str
    blur_px: float


def layout_of(dictionary: str) -> DockLayout:
    """The default dock, or the same dock in DICT_5X5_100 with the wide set-up's ids."""
    if dictionary == "DICT_4X4_50":
        return DockLayout.default()
    d = DockLayout.default()
    ids = {"left": 40, "center": 41, "right": 42}
    markers = tuple(MarkerSpec(m.role, ids[m.role], m.y, m.z) for m in d.markers)
    return DockLayout(dictionary, d.marker_size, markers)


def settings(blur: float) -> tuple[Setting, ...]:
    return (
        Setting("4x4 default", "DICT_4X4_50", 0.0),
        Setting(f"4x4 + blur {blur:g} px", "DICT_4X4_50", blur),
        Setting("5x5 default", "DICT_5X5_100", 0.0),
        Setting(f"5x5 + blur {blur:g} px", "DICT_5X5_100", blur),
    )


def _edges(c: np.ndarray) -> np.ndarray:
    return np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)


def _area(c: np.ndarray) -> float:
    x, y = c[:, 0], c[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def sample_pose(rng: np.random.Generator, args: Any) -> DockPose:
    r = math.exp(rng.uniform(math.log(args.min_distance), math.log(args.max_distance)))
    yaw = math.radians(rng.uniform(-args.max_yaw, args.max_yaw))
    return DockPose(r, rng.uniform(-0.25, 0.25) * r, yaw)


def run_chunk(task: tuple[int, int, int, int, Setting, Any]) -> list[dict[str, Any]]:
    """Render one chunk of one setting; one record per in-view dock marker."""
    seed, s_index, chunk, n, setting, args = task
    layout = layout_of(setting.dictionary)
    nuisances = Nuisances().updated(motion_blur_px=setting.blur_px)
    sim = Simulator(layout=layout, nuisances=nuisances, seed=chunk_seed(seed, 1000 * s_index + chunk))
    detector = MarkerDetector(layout)  # as the Estimator builds it
    # The detector's own cv2.aruco.ArucoDetector: every quad with its id, the dock's or not, to see wrong ids.
    aruco = detector._detector
    modules = layout.modules
    out: list[dict[str, Any]] = []
    for k in range(n):
        rng = np.random.default_rng([seed, s_index, chunk, k])
        pose = sample_pose(rng, args)
        true = sim.true_corners(pose)
        visible = [r for r in layout.roles if sim.in_view(true[r], BORDER_MARGIN_PX)]
        if not visible:
            continue
        image = sim.render(pose, rng=rng)
        quads, ids, _ = aruco.detectMarkers(as_gray(image))
        found = [] if ids is None else list(zip(ids.ravel().tolist(), (q.reshape(4, 2) for q in quads), strict=True))
        for role in visible:
            c = true[role]
            side = math.sqrt(_area(c))
            centre = c.mean(axis=0)
            near = [i for i, q in found if np.linalg.norm(q.mean(axis=0) - centre) < 0.35 * side]
            want = layout.marker(role).id
            outcome = "right" if want in near else ("wrong" if near else "miss")
            e = _edges(c)
            out.append(
                {
                    "setting": setting.key,
                    "chunk": chunk,
                    "frame": k,
                    "role": role,
                    "distance": pose.x,
                    "yaw_deg": math.degrees(pose.yaw),
                    "area": side / modules,
                    "mean": float(e.mean()) / modules,
                    "short": float(e.min()) / modules,
                    "outcome": outcome,
                    "wrong_ids": [i for i in near if i != want],
                }
            )
    return out


def _nll(theta: np.ndarray, lx: np.ndarray, y: np.ndarray) -> float:
    z = theta[0] + theta[1] * lx
    # -log p = log(1 + exp(-z)); -log(1 - p) = log(1 + exp(z))
    return float(np.sum(np.where(y, np.logaddexp(0.0, -z), np.logaddexp(0.0, z))))


def fit_logistic(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """(a, b) of p = expit(a + b ln x) by maximum likelihood, and the log-likelihood."""
    from scipy.optimize import minimize

    lx = np.log(x)
    res = minimize(
        _nll,
        np.array([-5.0, 5.0]),
        args=(lx, y),
        method="Nelder-Mead",
        options={"xatol": 1e-6, "fatol": 1e-8, "maxiter": 4000},
    )
    return res.x, -float(res.fun)


def threshold(theta: np.ndarray, p: float) -> float:
    a, b = theta
    if b <= 0:
        return float("nan")
    return math.exp((math.log(p / (1 - p)) - a) / b)


def empirical(x: np.ndarray, y: np.ndarray, p: float) -> float:
    """The upper edge of the highest bin (of enough markers) detecting less than ``p``: every bin above is at ``p``."""
    edges = np.arange(math.floor(x.min() / BIN) * BIN, x.max() + BIN, BIN)
    for lo in edges[::-1]:
        sel = (x >= lo) & (x < lo + BIN)
        if sel.sum() >= MIN_BIN_COUNT and y[sel].mean() < p:
            return float(lo + BIN)
    return float(edges[0])


def analyse(records: list[dict[str, Any]], boot: int, seed: int) -> dict[str, Any]:
    y = np.array([r["outcome"] == "right" for r in records])
    out: dict[str, Any] = {
        "markers": len(records),
        "right": int(y.sum()),
        "wrong": sum(r["outcome"] == "wrong" for r in records),
        "fits": {},
    }
    for metric in METRICS:
        x = np.array([r[metric] for r in records])
        theta, ll = fit_logistic(x, y)
        out["fits"][metric] = {"a": theta[0], "b": theta[1], "loglik": ll}
    x = np.array([r["area"] for r in records])
    theta = np.array([out["fits"]["area"]["a"], out["fits"]["area"]["b"]])
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(boot):
        i = rng.integers(0, len(x), len(x))
        t, _ = fit_logistic(x[i], y[i])
        draws.append([threshold(t, p) for p in LEVELS])
    d = np.array(draws) if draws else np.full((1, len(LEVELS)), np.nan)
    out["thresholds"] = {
        str(p): {
            "fit": threshold(theta, p),
            "lo": float(np.nanpercentile(d[:, j], 2.5)),
            "hi": float(np.nanpercentile(d[:, j], 97.5)),
            "empirical": empirical(x, y, p),
        }
        for j, p in enumerate(LEVELS)
    }
    return out


def bin_table(by_setting: dict[str, list[dict[str, Any]]]) -> tuple[list[str], list[list[str]], dict[str, Any]]:
    xs = np.concatenate([[r["area"] for r in recs] for recs in by_setting.values()])
    lo = math.floor(xs.min() / BIN) * BIN
    edges = np.round(np.arange(lo, TOP + BIN / 2, BIN), 6)
    rows, raw = [], {}
    for b0 in edges:
        b1 = b0 + BIN if b0 < TOP else math.inf
        row = [f"{b0:.2f}-{b1:.2f}" if b0 < TOP else f"≥ {b0:.2f}"]
        for key, recs in by_setting.items():
            sel = [r for r in recs if b0 <= r["area"] < b1]
            n, k = len(sel), sum(r["outcome"] == "right" for r in sel)
            w = sum(r["outcome"] == "wrong" for r in sel)
            raw.setdefault(key, []).append({"lo": b0, "n": n, "right": k, "wrong": w})
            row.append(f"{fmt(100 * k / n, 1)} ({n})" + (f" {w} wrong" if w else "") if n else "—")
        rows.append(row)
    return ["px/cell (sqrt area)", *(f"{k} % (n)" for k in by_setting)], rows, raw


def plot(
    path: str, by_setting: dict[str, list[dict[str, Any]]], stats: dict[str, Any], raw_bins: dict[str, Any]
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    grid = np.linspace(0.5, 10, 400)
    for (key, _), colour in zip(by_setting.items(), ("C0", "C1", "C2", "C3"), strict=False):
        bins = [b for b in raw_bins[key] if b["n"] >= 5 and b["lo"] < TOP]
        ax.plot([b["lo"] + BIN / 2 for b in bins], [b["right"] / b["n"] for b in bins], "o", ms=3, color=colour)
        f = stats[key]["fits"]["area"]
        ax.plot(grid, 1 / (1 + np.exp(-(f["a"] + f["b"] * np.log(grid)))), "-", color=colour, label=key)
    for p in LEVELS:
        ax.axhline(p, color="0.8", lw=0.8, zorder=0)
    ax.set_xlabel("pixels per code cell: sqrt(projected area) / cells across (6 for 4x4, 7 for 5x5)")
    ax.set_ylabel("detected with the right id")
    ax.set_title("ArUco detection vs pixels per cell (simulator, 640x480; dots: 0.25 bins, lines: logistic fits)")
    ax.title.set_fontsize(9)
    ax.set_xlim(0.5, 10)
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=3000, frames_help="frames per setting", seed=0)
    p.add_argument("--quick", action="store_true", help="300 frames a setting, 50 bootstrap resamples")
    p.add_argument("--motion-blur", type=float, default=6.0, metavar="PX", help="heavy blur streak, px (default 6)")
    p.add_argument("--min-distance", type=float, default=1.0, help="metres (default 1)")
    p.add_argument("--max-distance", type=float, default=8.0, help="metres (default 8)")
    p.add_argument("--max-yaw", type=float, default=60.0, help="degrees (default 60)")
    p.add_argument("--bootstrap", type=int, default=200, help="resamples for the thresholds' intervals (default 200)")
    p.add_argument("--plot", metavar="PNG", help="detection rate vs px/cell, one curve per setting")
    args = p.parse_args(argv)
    if args.quick:
        args.frames, args.bootstrap = 300, 50
    t0 = time.perf_counter()
    todo = settings(args.motion_blur)
    tasks = [(args.seed, i, c, n, s, args) for i, s in enumerate(todo) for c, n in chunks(args.frames, CHUNK)]
    records: list[dict[str, Any]] = []
    for part in parallel_map(run_chunk, tasks, lambda t: t[3], workers=args.workers, desc="detection_range"):
        records += part
    by_setting = {s.key: [r for r in records if r["setting"] == s.key] for s in todo}
    stats = {k: analyse(v, args.bootstrap, args.seed) for k, v in by_setting.items()}
    header, rows, raw_bins = bin_table(by_setting)
    wall = time.perf_counter() - t0

    def cell(t: dict[str, float]) -> str:
        return f"{fmt(t['fit'])} [{fmt(t['lo'])}, {fmt(t['hi'])}]; {fmt(t['empirical'])}"

    threshold_rows = [
        [k, str(s["markers"]), str(s["wrong"]), *(cell(s["thresholds"][str(q)]) for q in LEVELS)]
        for k, s in stats.items()
    ]
    metric_rows = [
        [
            k,
            *(fmt(stats[k]["fits"][m]["loglik"], 1) for m in METRICS),
            fmt(stats[k]["fits"]["short"]["loglik"] - stats[k]["fits"]["area"]["loglik"], 1),
        ]
        for k in stats
    ]
    wrong = [r for r in records if r["outcome"] == "wrong"]
    env = environment()
    cmd = f"python bench/detection_range.py --frames {args.frames} --seed {args.seed}" + (
        f" --motion-blur {args.motion_blur:g}" if args.motion_blur != 6.0 else ""
    )
    lines = [
        "### Detection range: pixels per code cell",
        "",
        f"`{cmd}` — {env['date_utc']} UTC, OpenCV {env['opencv']}, {args.frames} frames a setting, "
        f"{len(records)} in-view markers, {wall / 60:.1f} min on {args.workers} processes. Distance "
        f"{args.min_distance:g}-{args.max_distance:g} m log-uniform, yaw ±{args.max_yaw:g}°, default camera "
        "(640x480, f 615 px), 10 cm markers, Nuisances() (+ motion blur, direction per frame).",
        "",
        "px/cell needed (sqrt(area)/modules), logistic fit in ln(px/cell) [bootstrap 95 %]; empirical (the top "
        f"of the highest 0.25 bin of ≥ {MIN_BIN_COUNT} markers below that rate):",
        "",
        markdown_table(["setting", "markers", "wrong id", *(f"{100 * q:g} %" for q in LEVELS)], threshold_rows),
        "",
        "Which size predicts detection: log-likelihood of the logistic fit on each (higher is better):",
        "",
        markdown_table(["setting", *(METRIC_NAMES[m] for m in METRICS), "short − area"], metric_rows),
        "",
        "Detected with the right id, % (markers), by px/cell bin:",
        "",
        markdown_table(header, rows),
        "",
        f"Wrong ids (a quad at a dock marker decoded as another id): {len(wrong)}"
        + "".join(
            f"\n- {r['setting']}: {r['role']} read as {r['wrong_ids']} at {r['area']:.2f} px/cell, "
            f"{r['distance']:.2f} m, yaw {r['yaw_deg']:.0f}°"
            for r in wrong[:20]
        ),
    ]
    report = "\n".join(lines)
    if args.plot:
        plot(args.plot, by_setting, stats, raw_bins)
        print(f"wrote {args.plot}", file=sys.stderr)
    raw = {
        "benchmark": "detection_range",
        "args": vars(args),
        "environment": env,
        "wall_s": wall,
        "stats": stats,
        "bins": raw_bins,
        "records": records,
    }
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
