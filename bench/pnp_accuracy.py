"""Accuracy of the SolvePnP baselines (single marker, 3-marker board) by depth, on default-nuisance frames.

A held-out set of ``--frames`` simulated frames (default nuisances: noise, blur, exposure jitter,
vignetting, clutter) at poses drawn from the default PoseDistribution (depth 25-250 cm from the camera,
lateral +-40 cm, yaw +-30 deg, marker 2 in view). Markers are detected with MarkerDetector(layout)
(sub-pixel corners), and the DockPose is estimated by

- ``pnp``: monodock.estimation.pnp.estimate_single_marker (marker 2, SOLVEPNP_IPPE_SQUARE), the papers' baseline;
- ``board``: monodock.estimation.pnp.estimate_board (every visible dock marker jointly).

Errors are against the simulator's true DockPose: depth = x, lateral = y (cm), yaw (deg, wrapped into
[-180, 180)). Rows are 25 cm bands of the papers' depth (true DockPose.x - camera_mount.x) plus 'all';
per method: frames, valid count, depth bias (signed mean), MAE and p95 of |error| for x, y and yaw
(over the valid estimates).

Run from the repo root:

    python bench/pnp_accuracy.py [--frames 1000] [--seed 1] [--out FILE.md] [--plot FILE.png]

--plot writes |depth|, |lateral| and |yaw| error against depth for both methods (the demo report's plot:
scatter, per-band medians, log y axis). Errors and bands come from monodock.evaluation.metrics, as in the demo.
Rendering dominates the run time and runs in 2
processes; each chunk of frames has its own Simulator seeded from (seed, chunk index), so the numbers do
not depend on the number of workers.
"""

from __future__ import annotations

import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from _common import bench_parser, chunk_seed, emit, environment, simulate_chunks
from monodock.core.pose import DockPose
from monodock.estimation.pnp import PoseEstimate, estimate_board, estimate_single_marker
from monodock.evaluation.metrics import method_tables, pose_errors
from monodock.perception.detect import MarkerDetector
from monodock.report.evaluation import band_markdown, error_plot
from monodock.sim import Simulator

METHODS: tuple[str, ...] = ("pnp", "board")
CHUNK = 20
PAPERS_NOTE = (
    "For reference, the papers' headline (Oh & Kim, Sensors 2025), mean errors over their test set: "
    "SolvePnP 58.54 cm depth, 6.64° angle; their regression 1.18 cm depth, 3.11° angle "
    "(their SolvePnP was given a wrong calibration, see docs/benchmarks.md; here every method has the true one)."
)


def _estimate_record(est: PoseEstimate) -> dict[str, Any]:
    if est.pose is None:
        return {"valid": False, "reason": est.reason, "markers": list(est.markers_seen)}
    return {
        "valid": True,
        "x": est.pose.x,
        "y": est.pose.y,
        "yaw": est.pose.yaw,
        "markers": list(est.markers_seen),
        "reprojection_px": est.reprojection_px,
        "tilt_deg": est.tilt_deg,
    }


def run_chunk(task: tuple[int, int, int]) -> list[dict[str, Any]]:
    """Simulate one chunk of default-nuisance frames; detect and estimate with both PnP methods."""
    seed, chunk, n = task
    sim = Simulator(seed=chunk_seed(seed, chunk))
    detector = MarkerDetector(sim.layout)
    out: list[dict[str, Any]] = []
    for k in range(n):
        frame = sim.frame(sim.sample_pose())
        det = detector.detect(frame.image)
        truth = frame.truth.pose
        out.append(
            {
                "chunk": chunk,
                "frame": k,
                "true": {"x": truth.x, "y": truth.y, "yaw": truth.yaw},
                "depth": truth.x - sim.robot.camera_mount.x,
                "seen": list(det.roles_seen),
                "pnp": _estimate_record(estimate_single_marker(det, sim.camera, sim.layout, sim.robot)),
                "board": _estimate_record(estimate_board(det, sim.camera, sim.layout, sim.robot)),
            }
        )
    return out


def _pose(rec: dict[str, Any]) -> DockPose | None:
    return DockPose(rec["x"], rec["y"], rec["yaw"]) if rec["valid"] else None


def main(argv: list[str] | None = None) -> int:
    p = bench_parser(__doc__, frames=1000, frames_help="held-out frames to simulate", seed=1)
    p.add_argument("--plot", help="write an error plot PNG here")
    args = p.parse_args(argv)

    records: list[dict[str, Any]] = simulate_chunks(run_chunk, args, "pnp_accuracy", CHUNK)

    # The same error and band code as `monodock demo`, so the two can never disagree.
    truth = [DockPose(r["true"]["x"], r["true"]["y"], r["true"]["yaw"]) for r in records]
    depth = np.array([r["depth"] for r in records])
    errs = {m: pose_errors(truth, [_pose(r[m]) for r in records]) for m in METHODS}
    rows = method_tables(depth, errs)

    env = environment()
    seen3 = sum(len(r["seen"]) == 3 for r in records)
    lines = [
        "### SolvePnP accuracy by depth (default nuisances, held-out frames)",
        "",
        f"`python bench/pnp_accuracy.py --frames {args.frames} --seed {args.seed}` — "
        f"{env['date_utc']} UTC, OpenCV {env['opencv']}. Depth band = true DockPose.x - camera_mount.x "
        f"(cm); errors over valid estimates; all 3 markers detected in {seen3} of {len(records)} frames.",
        "",
        band_markdown(rows),
        "",
        PAPERS_NOTE,
    ]
    report = "\n".join(lines)
    if args.plot:
        error_plot(depth, errs, Path(args.plot))
        print(f"wrote {args.plot}", file=sys.stderr)
    raw = {
        "benchmark": "pnp_accuracy",
        "args": vars(args),
        "environment": env,
        "table": [asdict(r) for r in rows],
        "records": records,
    }
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
