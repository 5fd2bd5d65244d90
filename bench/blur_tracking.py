"""Blur tracking: frames with a valid pose under heavy motion blur, the detector alone against the detector plus the
markers found where the dock track predicts them (monodock.perception.predicted; issue 28, item 4).

Drives: straight-line approaches at 15 Hz, the camera from 2.5 m to 0.3 m before the dock face (at 0.25 m/s, 132
frames), from a lateral offset up to +-0.3 m and a dock yaw up to +-20 deg that fall linearly to 0 at the end; the
simulator's default nuisances (noise, exposure jitter, defocus, clutter with other ids) and a 6 px motion blur on
every frame (the heaviest level of `monodock evaluate --robustness`'s motion-blur axis; its direction drawn per
frame). Two set-ups: the default (640x480, DICT_4X4_50, 10 cm) and bench/setups/wide/ (1280x720 wide lens,
DICT_5X5_100, 12 cm, pitched camera), which the predicted-corner fit was not built on.

The prior of each frame is the tracked run's own: the newest valid estimate (of the first method) carried to the
frame by odometry (the simulator's true motion between the frames with 2 % of the distance and 0.5 deg a metre of
noise on each step), its covariance growing with the frames since. Never the truth. Before the first valid pose
there is no prior: the first frames are the detector's alone.

Per method, over all frames: % frames with a valid pose (detector alone; detector + fit); the mean absolute errors
(x, y mm; yaw deg) against the truth on the frames the detector alone finds (alone, and with the fit, which may add
markers to such a frame) and on the frames only the fit recovers; the markers recovered, and the false accepts: a
recovered marker with a corner more than 2 px from its true corner.

Run from the repo root:

    python bench/blur_tracking.py [--frames 4] [--seed 0] [--workers 2] [--blur 6] [--glare 0] [--out FILE.md]

``--glare P``: a specular highlight (``Nuisances.glare_probability``: a saturating spot over part of one marker in
view) on a share P of the frames; ``--blur 0 --glare 1`` measures glare alone.

``--frames`` is the number of drives a set-up (each 132 frames).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from _common import bench_parser, emit, environment, fmt, markdown_table, parallel_map
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.estimation.factory import make_estimator
from monodock.perception.predicted import Prior
from monodock.sim import Nuisances, Simulator

METHODS = ("fused", "board")
RATE_HZ = 15.0
SPEED = 0.25
DEPTHS = (2.5, 0.3)
MAX_LATERAL = 0.3
MAX_YAW_DEG = 20.0
ODOM_NOISE = (0.02, math.radians(0.5))  # of the distance; rad a metre
FALSE_PX = 2.0
SETUPS = ("default", "wide")


@dataclass(frozen=True)
class Task:
    setup: str
    drive: int
    seed: int
    blur: float
    glare: float = 0.0


def calibration(setup: str) -> tuple[CameraModel, DockLayout, RobotConfig]:
    if setup == "default":
        return CameraModel.default(), DockLayout.default(), RobotConfig.default()
    d = Path(__file__).resolve().parent / "setups" / setup
    return CameraModel.load(d / "camera.yaml"), DockLayout.load(d / "layout.yaml"), RobotConfig.load(d / "robot.yaml")


def frames_of(_: Task) -> int:
    return round((DEPTHS[0] - DEPTHS[1]) / SPEED * RATE_HZ)


def robot_in_dock(p: DockPose) -> Pose2D:
    return Pose2D(p.x, p.y, p.yaw).inverse()


def run_drive(task: Task) -> list[dict[str, Any]]:
    camera, layout, robot = calibration(task.setup)
    nuisances = Nuisances(motion_blur_px=task.blur, glare_probability=task.glare)
    sim = Simulator(layout, camera, robot, nuisances, seed=task.seed)
    est = make_estimator(methods=METHODS, camera=camera, layout=layout, robot=robot)
    rng = np.random.default_rng([task.seed, 7])
    mx = robot.camera_mount.x
    y0 = float(rng.uniform(-MAX_LATERAL, MAX_LATERAL))
    yaw0 = math.radians(float(rng.uniform(-MAX_YAW_DEG, MAX_YAW_DEG)))
    n = frames_of(task)
    rows: list[dict[str, Any]] = []
    fix: DockPose | None = None  # the tracked run's newest estimate, carried by odometry to the current frame
    since = 0
    prev: Pose2D | None = None
    for k in range(n):
        s = k / (n - 1)
        truth = DockPose(mx + DEPTHS[0] + s * (DEPTHS[1] - DEPTHS[0]), y0 * (1 - s), yaw0 * (1 - s))
        here = robot_in_dock(truth)
        if fix is not None and prev is not None:
            step = prev.inverse().compose(here)  # the robot's true motion since the last frame, in its frame
            d = math.hypot(step.x, step.y)
            noisy = Pose2D(
                step.x * (1 + rng.normal(0, ODOM_NOISE[0])),
                step.y + d * rng.normal(0, ODOM_NOISE[0]),
                step.theta + d * rng.normal(0, ODOM_NOISE[1]),
            )
            carried = noisy.inverse().compose(Pose2D(fix.x, fix.y, fix.yaw))
            fix = DockPose(carried.x, carried.y, carried.theta)
        prev = here
        frame = sim.frame(truth, stamp=k / RATE_HZ, rng=np.random.default_rng([task.seed, k]))
        prior = None
        if fix is not None:
            sig_xy, sig_yaw = 0.01 + 0.005 * since, math.radians(1.0 + 0.5 * since)
            prior = Prior(fix, np.diag([sig_xy**2, sig_xy**2, sig_yaw**2]))
        alone = est.estimate("", k / RATE_HZ, frame.image)
        t0 = time.perf_counter()
        tracked = est.estimate("", k / RATE_HZ, frame.image, prior=prior) if prior is not None else alone
        dt = time.perf_counter() - t0
        det = tracked.detection
        assert det is not None
        errs = [
            float(np.max(np.linalg.norm(det.observations[r].corners - frame.truth.corners[r], axis=1)))
            for r in det.recovered
        ]
        row: dict[str, Any] = {"setup": task.setup, "drive": task.drive, "recovered_px": errs, "time": dt}
        for m in METHODS:
            for tag, fe in (("alone", alone), ("tracked", tracked)):
                p = fe.estimates[m].pose
                row[f"{m}_{tag}"] = (
                    None
                    if p is None
                    else (p.x - truth.x, p.y - truth.y, math.degrees(math.remainder(p.yaw - truth.yaw, 2 * math.pi)))
                )
        first = tracked.estimates[METHODS[0]].pose
        if first is not None:
            fix, since = first, 0
        else:
            since += 1
        rows.append(row)
    return rows


def mae(errs: list[tuple[float, float, float]]) -> str:
    if not errs:
        return "—"
    a = np.abs(np.asarray(errs))
    return f"{fmt(1000 * a[:, 0].mean(), 1)} / {fmt(1000 * a[:, 1].mean(), 1)} / {fmt(a[:, 2].mean(), 2)}"


def _once_seen(rows: list[dict[str, Any]], key: str) -> float:
    """% of frames with a pose among those from each drive's first valid one on."""
    valid = total = 0
    for drive in sorted({r["drive"] for r in rows}):
        v = [r[key] is not None for r in rows if r["drive"] == drive]
        if True in v:
            v = v[v.index(True) :]
            valid, total = valid + sum(v), total + len(v)
    return 100 * valid / total if total else math.nan


def summarise(rows: list[dict[str, Any]], setup: str) -> tuple[list[list[str]], dict[str, Any]]:
    mine = [r for r in rows if r["setup"] == setup]
    out, raw = [], {}
    rec = [e for r in mine for e in r["recovered_px"]]
    false = sum(e > FALSE_PX for e in rec)
    med, worst = (float(np.median(rec)), max(rec)) if rec else (math.nan, math.nan)
    for m in METHODS:
        a = [r[f"{m}_alone"] for r in mine]
        t = [r[f"{m}_tracked"] for r in mine]
        found = [i for i, e in enumerate(a) if e is not None]
        recovered = [i for i, e in enumerate(t) if e is not None and a[i] is None]
        lost = sum(1 for i in found if t[i] is None)
        n = len(mine)
        va, vt = 100 * len(found) / n, 100 * sum(e is not None for e in t) / n
        # Once the dock has been seen: the frames from each drive's first valid pose on (the fit needs a track).
        seen_a, seen_t = _once_seen(mine, f"{m}_alone"), _once_seen(mine, f"{m}_tracked")
        out.append(
            [
                setup,
                m,
                str(n),
                f"{va:.1f}",
                f"{vt:.1f}",
                f"{seen_a:.1f} / {seen_t:.1f}",
                mae([a[i] for i in found]),
                mae([t[i] for i in found if t[i] is not None]),
                mae([t[i] for i in recovered]),
                f"{len(rec)} ({fmt(med, 2)} / {fmt(worst, 2)})",
                str(false),
            ]
        )
        raw[m] = {
            "frames": n,
            "valid_alone": va,
            "valid_tracked": vt,
            "seen_alone": seen_a,
            "seen_tracked": seen_t,
            "lost": lost,
            "recovered_frames": len(recovered),
        }
    raw["recovered_markers"] = len(rec)
    raw["false_accepts"] = false
    raw["fit_ms_mean"] = 1000 * float(np.mean([r["time"] for r in mine]))
    return out, raw


def main() -> int:
    p = bench_parser(__doc__ or "", frames=4, frames_help="drives a set-up (132 frames each)", seed=0)
    p.add_argument("--blur", type=float, default=6.0, help="motion blur, px (default 6)")
    p.add_argument("--glare", type=float, default=0.0, help="share of frames with a highlight on a marker, 0-1 (0)")
    args = p.parse_args()
    if not args.blur >= 0:
        print(f"--blur must be 0 or more px, got {args.blur}", file=sys.stderr)
        return 2
    if not 0.0 <= args.glare <= 1.0:
        print(f"--glare must be within 0-1, got {args.glare}", file=sys.stderr)
        return 2
    tasks = [
        Task(s, d, int(np.random.SeedSequence([args.seed, i, d]).generate_state(1)[0]), args.blur, args.glare)
        for i, s in enumerate(SETUPS)
        for d in range(args.frames)
    ]
    rows: list[dict[str, Any]] = []
    for part in parallel_map(run_drive, tasks, frames_of, workers=args.workers, desc="frames"):
        rows += part
    table, raw = [], {"environment": environment(), "blur_px": args.blur, "glare": args.glare, "drives": args.frames}
    for s in SETUPS:
        t, r = summarise(rows, s)
        table += t
        raw[s] = r
    header = [
        "set-up",
        "method",
        "frames",
        "valid % detector",
        "valid % + fit",
        "valid % once seen, detector / + fit",
        "err detector's frames, alone (x mm / y mm / yaw °)",
        "same frames, + fit",
        "err recovered frames",
        "markers recovered (median / max corner err px)",
        "false accepts (> 2 px)",
    ]
    report = (
        f"### Blur tracking: {args.blur:g} px motion blur"
        + (f", a specular highlight on {100 * args.glare:g} % of the frames" if args.glare else "")
        + f", {args.frames} approach drives a set-up, seed {args.seed}\n\n"
        + markdown_table(header, table, "ll" + "r" * 9)
        + "\n\nMean time of the tracked frame's estimate (detector, fit and methods): "
        + ", ".join(f"{s} {raw[s]['fit_ms_mean']:.0f} ms" for s in SETUPS)
        + "\n"
    )
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
