"""Accuracy of the LiDAR labels against the simulator's truth: the marker-2 line (before) and the face line (after).

A held-out set of ``--frames`` simulated frames (default nuisances and the default LiDAR: 1 cm range noise,
0.5 degree beams, 1 % dropouts) at poses drawn from the default PoseDistribution (depth 25-250 cm from the
camera, lateral +-40 cm, yaw +-30 deg, marker 2 in view). Marker 2 is detected with MarkerDetector(layout)
(sub-pixel corners) and each frame is labelled by monodock.learning.label.label_frame from those corners and the
paired scan, as ``monodock label`` does. Label against truth, per 25 cm band of the papers' depth (true
DockPose.x - camera_mount.x) and overall:

- ``papers``: depth = x of the return nearest marker 2's centre plane, angle = from the outermost returns
  across marker 2 (the papers have no lateral label);
- ``marker-2 line`` (before): a total-least-squares line through the returns across marker 2; depth and
  lateral where it crosses marker 2's centre plane, angle from its direction;
- ``face line`` (after, the default labels): the line over the whole charger face segment found in the scan
  (grown from the returns across marker 2, outliers rejected), read the same way.

Errors are label - truth: depth and lateral in cm, angle in degrees (wrapped); bias = signed mean, MAE and
p95 of |error|, over the frames with a valid label. ``--all-markers`` also seeds the face with the returns
across markers 1 and 3 when they are detected (``label_frame(..., other_corners=...)``).

Run from the repo root:

    python bench/label_accuracy.py [--frames 400] [--seed 3] [--all-markers] [--out FILE.md]

Rendering dominates the run time and runs in 2 processes; each chunk of frames has its own Simulator
seeded from (seed, chunk index), so the numbers do not depend on the number of workers.
"""

from __future__ import annotations

import itertools
import math
import sys
from collections import Counter
from typing import Any

import numpy as np
from numpy.typing import NDArray

from _common import bench_parser, chunk_seed, emit, environment, fmt, markdown_table, simulate_chunks
from monodock.learning.label import label_frame
from monodock.perception.detect import MarkerDetector
from monodock.sim import Simulator

CHUNK = 20
EDGES = tuple(np.round(np.arange(0.25, 2.51, 0.25), 2))
# (name, depth key, lateral key, angle key) of each label in a record.
METHODS: tuple[tuple[str, str, str | None, str], ...] = (
    ("papers", "x", None, "yaw_endpoints"),
    ("marker-2 line (before)", "x_line_marker", "y_marker", "yaw_marker"),
    ("face line (after)", "x_line", "y", "yaw"),
)


def run_chunk(task: tuple[int, int, int, bool]) -> list[dict[str, Any]]:
    """Simulate one chunk of default-nuisance frames; detect marker 2 and label each frame."""
    seed, chunk, n, all_markers = task
    sim = Simulator(seed=chunk_seed(seed, chunk))
    detector = MarkerDetector(sim.layout)
    out: list[dict[str, Any]] = []
    for k in range(n):
        frame = sim.frame(sim.sample_pose())
        det = detector.detect(frame.image)
        truth = frame.truth.pose
        rec: dict[str, Any] = {
            "chunk": chunk,
            "frame": k,
            "true": {"x": truth.x, "y": truth.y, "yaw": truth.yaw},
            "depth": truth.x - sim.robot.camera_mount.x,
            "seen": sorted(det.observations),
            "label": None,
        }
        if "center" in det.observations:
            others = [o.corners for r, o in det.observations.items() if r != "center"] if all_markers else []
            lab = label_frame(
                det.observations["center"].corners, frame.scan, sim.camera, sim.robot, other_corners=others
            )
            rec["label"] = {
                "valid": lab.valid,
                "reason": lab.reason,
                **{k: getattr(lab, k) for k in ("x", "x_line_marker", "y_marker", "x_line", "y")},
                **{k: getattr(lab, k) for k in ("yaw_endpoints", "yaw_marker", "yaw")},
                "points": lab.points,
                "face_points": lab.face_points,
                "face_span": lab.face_span,
                "face_rms": lab.face_rms,
                "face_rejected": lab.face_rejected,
            }
        out.append(rec)
    return out


def _stats(e: NDArray[np.float64]) -> tuple[float, float, float]:
    """(bias, MAE, p95 of |e|) of the finite errors; NaN when none."""
    e = e[np.isfinite(e)]
    if e.size == 0:
        return math.nan, math.nan, math.nan
    return float(e.mean()), float(np.abs(e).mean()), float(np.percentile(np.abs(e), 95))


def _errors(records: list[dict[str, Any]], key: str | None, truth_key: str) -> NDArray[np.float64]:
    """Label - truth per record (NaN without a valid label); cm for x/y, degrees for yaw."""
    out = np.full(len(records), np.nan)
    if key is None:
        return out
    for i, r in enumerate(records):
        lab = r["label"]
        if lab is None or not lab["valid"]:
            continue
        e = lab[key] - r["true"][truth_key]
        out[i] = math.degrees((e + math.pi) % (2 * math.pi) - math.pi) if truth_key == "yaw" else 100.0 * e
    return out


def tables(records: list[dict[str, Any]]) -> tuple[list[list[str]], list[dict[str, Any]]]:
    """The table rows (method x band) and the same numbers as dicts."""
    depth = np.array([r["depth"] for r in records])
    bands = [(lo, hi, f"{lo * 100:.0f}-{hi * 100:.0f} cm") for lo, hi in itertools.pairwise(EDGES)]
    bands.append((-math.inf, math.inf, "all"))
    rows: list[list[str]] = []
    raw: list[dict[str, Any]] = []
    for name, kx, ky, kyaw in METHODS:
        ex, ey, eyaw = _errors(records, kx, "x"), _errors(records, ky, "y"), _errors(records, kyaw, "yaw")
        for lo, hi, band in bands:
            # Bands are [lo, hi); the last one also takes its upper edge.
            m = (depth >= lo) & ((depth < hi) | ((hi == EDGES[-1]) & (depth <= hi)))
            if not m.any():
                continue
            sx, sy, syaw = _stats(ex[m]), _stats(ey[m]), _stats(eyaw[m])
            valid = int(np.isfinite(ex[m]).sum())
            rows.append([name, band, str(int(m.sum())), str(valid), *(fmt(v) for v in (*sx, *sy, *syaw))])
            raw.append(
                {"method": name, "band": band, "frames": int(m.sum()), "valid": valid}
                | {f"depth_{s}_cm": v for s, v in zip(("bias", "mae", "p95"), sx, strict=True)}
                | {f"lateral_{s}_cm": v for s, v in zip(("bias", "mae", "p95"), sy, strict=True)}
                | {f"angle_{s}_deg": v for s, v in zip(("bias", "mae", "p95"), syaw, strict=True)}
            )
    return rows, raw


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=400, frames_help="held-out frames to simulate", seed=3)
    p.add_argument("--all-markers", action="store_true", help="seed the face with markers 1 and 3 too")
    args = p.parse_args(argv)

    records: list[dict[str, Any]] = simulate_chunks(_Chunk(args.all_markers), args, "label_accuracy", CHUNK)

    rows, raw_rows = tables(records)
    labels = [r["label"] for r in records if r["label"] is not None]
    valid = [lab for lab in labels if lab["valid"]]
    reasons = Counter(lab["reason"].split(" (", maxsplit=1)[0] for lab in labels if not lab["valid"])
    env = environment()
    header = [
        "label",
        "depth band",
        "frames",
        "valid",
        "depth bias cm",
        "depth MAE cm",
        "depth p95 cm",
        "lateral bias cm",
        "lateral MAE cm",
        "lateral p95 cm",
        "angle bias °",
        "angle MAE °",
        "angle p95 °",
    ]
    flags = " --all-markers" if args.all_markers else ""
    med = {k: float(np.median([lab[k] for lab in valid])) if valid else math.nan for k in ("points", "face_points")}
    lines = [
        "### LiDAR label accuracy: marker-2 line (before) vs whole-face line (after)",
        "",
        f"`python bench/label_accuracy.py --frames {args.frames} --seed {args.seed}{flags}` — {env['date_utc']} UTC, "
        f"default nuisances and LiDAR (1 cm range noise, 0.5° beams, 1 % dropouts). Depth band = true "
        f"DockPose.x - camera_mount.x. Marker 2 detected in {len(labels)} of {len(records)} frames, "
        f"{len(valid)} valid labels"
        + (f" (invalid: {', '.join(f'{k} ×{v}' for k, v in reasons.items())})" if reasons else "")
        + f". Median returns across marker 2: {fmt(med['points'], 0)}; on the face line: "
        f"{fmt(med['face_points'], 0)}, spanning {fmt(float(np.median([lab['face_span'] for lab in valid])))} m; "
        f"{fmt(float(np.mean([lab['face_rejected'] for lab in valid])))} returns rejected per face on average.",
        "",
        markdown_table(header, rows),
    ]
    raw = {
        "benchmark": "label_accuracy",
        "args": vars(args),
        "environment": env,
        "table": raw_rows,
        "records": records,
    }
    emit("\n".join(lines), raw, args.out)
    return 0


class _Chunk:
    """run_chunk with the --all-markers flag bound (a picklable callable for the worker processes)."""

    def __init__(self, all_markers: bool) -> None:
        self.all_markers = all_markers

    def __call__(self, task: tuple[int, int, int]) -> list[dict[str, Any]]:
        return run_chunk((*task, self.all_markers))


if __name__ == "__main__":
    sys.exit(main())
