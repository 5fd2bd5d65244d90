"""Corner accuracy of OpenCV's ArUco detector against the simulator's exact corners, on clean renders.

Renders ``--frames`` random poses (Simulator.sample_pose() over the default PoseDistribution) with no
nuisance at all (Nuisances.clean(): the exact area-sampled render, quantised to 8 bits), and detects the
dock markers in the *same* images with each corner refinement 'none', 'subpix' and 'contour' of
monodock.detect.MarkerDetector. For every corner of a detected dock marker that lies fully in the image:

- error = detected - true (FrameTruth.corners[role], ArUco order TL, TR, BR, BL), pixels;
- outward = unit vector from the true marker centre in the image (the intersection of the true corners'
  diagonals) to the true corner; the signed outward error is error . outward (negative: inside the marker);
- perpendicular = error . (-o_y, o_x), the outward direction o turned 90 degrees clockwise on screen.

Reports per method (and per marker side-length band in pixels): markers in view, detection rate,
corners measured, RMS of the 2D error, mean and RMS of the outward error, mean of the perpendicular error.
Corners more than ``--gross`` px off (a mis-detection, not a corner bias) are counted and left out of
the statistics.

Run from the repo root:

    python bench/corner_accuracy.py [--frames 200] [--seed 0] [--out FILE.md]

Rendering dominates the run time and runs in 2 processes; each chunk of frames has its own Simulator
seeded from (seed, chunk index), so the numbers do not depend on the number of workers.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from _common import (
    bench_parser,
    chunk_seed,
    emit,
    environment,
    fmt,
    markdown_table,
    simulate_chunks,
)
from monodock.detect import MarkerDetector
from monodock.features import marker_features
from monodock.layout import ROLES
from monodock.sim import Nuisances, Simulator

METHODS: tuple[str, ...] = ("none", "subpix", "contour")
# Marker side length bands in pixels: [lo, hi).
BANDS: tuple[tuple[str, float, float], ...] = (
    ("< 30 px", 0.0, 30.0),
    ("30-60 px", 30.0, 60.0),
    ("60-120 px", 60.0, 120.0),
    ("≥ 120 px", 120.0, np.inf),
)
CHUNK = 10


def run_chunk(task: tuple[int, int, int]) -> list[dict[str, Any]]:
    """Render one chunk of clean frames and measure every in-view dock marker with each refinement.

    Returns one record per (frame, in-view marker): its true side length and, per method, whether it was
    detected and its per-corner errors, outward and perpendicular components.
    """
    seed, chunk, n = task
    sim = Simulator(nuisances=Nuisances.clean(), seed=chunk_seed(seed, chunk))
    detectors = {m: MarkerDetector(sim.layout, refinement=m) for m in METHODS}
    records: list[dict[str, Any]] = []
    for k in range(n):
        frame = sim.frame(sim.sample_pose())
        detections = {m: d.detect(frame.image) for m, d in detectors.items()}
        for role in ROLES:
            if not frame.truth.in_view[role]:
                continue
            true = frame.truth.corners[role]
            f = marker_features(true)
            outward = true - f.centre
            outward /= np.linalg.norm(outward, axis=1, keepdims=True)
            perp = np.stack([-outward[:, 1], outward[:, 0]], axis=1)
            rec: dict[str, Any] = {
                "chunk": chunk,
                "frame": k,
                "role": role,
                "side_px": float(np.mean([f.top, f.bottom, f.left, f.right])),
                "methods": {},
            }
            for m, det in detections.items():
                obs = det.observations.get(role)
                if obs is None:
                    rec["methods"][m] = None
                    continue
                err = obs.corners - true
                rec["methods"][m] = {
                    "err": err.tolist(),
                    "outward": np.sum(err * outward, axis=1).tolist(),
                    "perp": np.sum(err * perp, axis=1).tolist(),
                }
            records.append(rec)
    return records


def _stats(records: list[dict[str, Any]], method: str, gross: float) -> dict[str, float]:
    markers = len(records)
    found = [r["methods"][method] for r in records if r["methods"][method] is not None]
    if found:
        err = np.concatenate([np.asarray(m["err"]) for m in found])
        out = np.concatenate([np.asarray(m["outward"]) for m in found])
        perp = np.concatenate([np.asarray(m["perp"]) for m in found])
    else:
        err, out, perp = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    norm = np.linalg.norm(err, axis=1)
    ok = norm <= gross
    err, out, perp, norm = err[ok], out[ok], perp[ok], norm[ok]

    def safe(fn: Any, a: np.ndarray) -> float:
        return float(fn(a)) if a.size else float("nan")

    return {
        "markers": markers,
        "detected": len(found),
        "detection_rate": len(found) / markers if markers else float("nan"),
        "corners": int(ok.sum()),
        "gross": int((~ok).sum()),
        "rms_2d": safe(lambda a: np.sqrt(np.mean(a**2)), norm),
        "median_2d": safe(np.median, norm),
        "outward_mean": safe(np.mean, out),
        "outward_rms": safe(lambda a: np.sqrt(np.mean(a**2)), out),
        "perp_mean": safe(np.mean, perp),
        "perp_rms": safe(lambda a: np.sqrt(np.mean(a**2)), perp),
    }


def _row(label: list[str], s: dict[str, float]) -> list[str]:
    return [
        *label,
        str(s["markers"]),
        fmt(100 * s["detection_rate"], 1),
        str(s["corners"]),
        fmt(s["rms_2d"], 3),
        fmt(s["outward_mean"], 3),
        fmt(s["outward_rms"], 3),
        fmt(s["perp_mean"], 3),
        str(s["gross"]),
    ]


COLUMNS = [
    "markers in view",
    "detected %",
    "corners",
    "RMS 2D px",
    "outward mean px",
    "outward RMS px",
    "perp. mean px",
    "gross",
]


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=200, frames_help="random poses to render", seed=0)
    p.add_argument("--gross", type=float, default=3.0, help="corner errors above this (px) are mis-detections")
    args = p.parse_args(argv)

    records: list[dict[str, Any]] = simulate_chunks(run_chunk, args, "corner_accuracy", CHUNK)

    overall = {m: _stats(records, m, args.gross) for m in METHODS}
    by_band: dict[str, dict[str, dict[str, float]]] = {}
    for name, lo, hi in BANDS:
        sel = [r for r in records if lo <= r["side_px"] < hi]
        by_band[name] = {m: _stats(sel, m, args.gross) for m in METHODS}

    env = environment()
    lines = [
        "### Corner accuracy: OpenCV ArUco vs the simulator's true corners (clean renders)",
        "",
        f"`python bench/corner_accuracy.py --frames {args.frames} --seed {args.seed}` — "
        f"{env['date_utc']} UTC, OpenCV {env['opencv']}, "
        f"{len(records)} in-view dock markers in {args.frames} frames. "
        "Outward = along the true centre→corner direction (negative: inside the marker); "
        f"corners > {args.gross:g} px off are counted as gross and left out.",
        "",
        markdown_table(["refinement", *COLUMNS], [_row([m], overall[m]) for m in METHODS]),
        "",
        "By marker side length in the image:",
        "",
        markdown_table(
            ["side", "refinement", *COLUMNS],
            [_row([name, m], by_band[name][m]) for name, _, _ in BANDS for m in METHODS],
            "ll" + "r" * len(COLUMNS),
        ),
    ]
    report = "\n".join(lines)
    raw = {
        "benchmark": "corner_accuracy",
        "args": vars(args),
        "environment": env,
        "overall": overall,
        "by_side_band": by_band,
        "records": records,
    }
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
