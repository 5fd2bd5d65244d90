"""``monodock dock-sim``: closed-loop docking in the simulator, camera in the loop, measured per case.

For each of the eight cases, N random starts inside that case's region; each start is docked once per method
(the same starts and the same wheel and camera draws for every method, so the methods compare pair by pair).
The robot sees only rendered frames and its odometry; the simulator's truth is used afterwards, to measure.
Besides where each run ended, every camera frame after the dock filter is seeded (Moving₃ and the settle at
the face) is recorded: the filtered DockPose (the filter's dock mapped to base_link with the odometry pose at
the frame's exposure), the frame's own estimate and the truth, for the filtered-vs-single-frame figures.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.controller import (
    DockingMission,
    MissionConfig,
    Observation,
    Perceive,
    State,
    blind_gap,
    make_perceive,
    run_mission,
)
from monodock.dock.interface import Odometry
from monodock.dock.planner import CASES, PlannerConfig, classify, point_a
from monodock.dock.pose_filter import FilterConfig, MeasurementNoise, OdometryNoise
from monodock.errors import InputError
from monodock.estimation.estimator import METHODS, Estimator
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from monodock.sim.nuisance import Nuisances
from monodock.sim.simulator import Simulator

__all__ = [
    "DockSimConfig",
    "FilterFrame",
    "TrialResult",
    "filter_accuracy",
    "make_perceive",
    "run_dock_sim",
    "sample_start",
    "summarize",
]

ALL_METHODS = ("regression", *METHODS, "fused")
# The methods that need the model bundle.
BUNDLE_METHODS = ("regression", "fused")


@dataclass(frozen=True)
class DockSimConfig:
    """What to run: cases, starts per case, methods, the start region, the simulated robot and the mission."""

    cases: tuple[int, ...] = tuple(CASES)
    trials: int = 25
    methods: tuple[str, ...] = ("regression",)
    seed: int = 0
    distance: tuple[float, float] = (1.0, 2.5)  # base_link's distance from the face along the axis, metres
    max_heading_deg: float = 30.0
    view_margin_px: float = 10.0
    supersample: int = 8
    jobs: int = 2
    mission: MissionConfig = field(default_factory=MissionConfig)
    drive: DiffDriveConfig = field(default_factory=DiffDriveConfig)
    layout: DockLayout = field(default_factory=DockLayout.default)
    camera: CameraModel = field(default_factory=CameraModel.default)
    robot: RobotConfig = field(default_factory=RobotConfig.default)
    nuisances: Nuisances = field(default_factory=Nuisances)
    bundle: Path | None = None  # the regression's model bundle

    def simulator(self, seed: int = 0) -> Simulator:
        # supersample is the renderer's edge sampling, not a nuisance: 8x8 resolves an edge to 1/64 px.
        return Simulator(
            layout=self.layout,
            camera=self.camera,
            robot=self.robot,
            nuisances=self.nuisances.updated(supersample=self.supersample),
            seed=seed,
        )


@dataclass(frozen=True)
class FilterFrame:
    """One camera frame after the filter was seeded: DockPoses (x m, y m, yaw rad) in base_link at its exposure.

    Attributes:
        truth: the true DockPose.
        filtered: the filter's, after this frame was offered to it.
        raw: the frame's own estimate; None when the method had none (the filter coasted).
        nees: the filter's normalised estimation error squared against the truth (3 dof).
    """

    truth: tuple[float, float, float]
    filtered: tuple[float, float, float]
    raw: tuple[float, float, float] | None
    nees: float


@dataclass(frozen=True)
class TrialResult:
    """One docking run: where it started, how the robot saw it end, and how it really ended."""

    case: int
    trial: int
    method: str
    start: Pose2D
    classified_case: int | None
    state: str
    reason: str
    success: bool
    retries: int
    time_s: float
    lateral_cm: float  # base_link's distance from the approach axis at the end, + left
    longitudinal_cm: float  # the front edge's gap to the face at the end; negative: drove on this far into it
    heading_deg: float
    impact_speed: float | None
    frames: int
    wall_s: float
    render_s: float  # of wall_s: rendering the camera frames
    perceive_s: float  # of wall_s: detection and the method's estimate
    path: tuple[tuple[float, float, float], ...]  # true (x, y, heading) in the dock frame, every 0.2 s
    log: tuple[tuple[float, str], ...]
    filter_frames: tuple[FilterFrame, ...] = ()


def case_distances(case: int, config: DockSimConfig) -> tuple[float, float]:
    """The range of base_link's distance from the face for the case's starts; InputError when it is empty."""
    spec = CASES[case]
    d_a = -point_a(config.mission.planner, config.robot.front_offset).x
    lo, hi = config.distance
    dlo, dhi = (max(lo, d_a), hi) if spec.zone == "before" else (lo, min(hi, d_a))
    if not dlo < dhi:
        raise InputError(
            f"case {case} ({spec.zone} Point A, {d_a:.2f} m from the face) has no starts {lo:g}-{hi:g} m away: "
            "change --standoff or --distance"
        )
    return dlo, dhi


def sample_start(
    case: int, sim: Simulator, planner: PlannerConfig, rng: np.random.Generator, config: DockSimConfig
) -> Pose2D:
    """A random robot pose (dock frame) inside the case's region, with marker 2 in the camera's view."""
    spec = CASES[case]
    dlo, dhi = case_distances(case, config)
    side = 1.0 if spec.side == "left" else -1.0
    turn = -side if spec.heading == "towards" else side
    a = point_a(planner, sim.robot.front_offset)
    for _ in range(20_000):
        d = float(rng.uniform(dlo, dhi))
        y = side * float(rng.uniform(0.0, 1.0))
        heading = turn * math.radians(float(rng.uniform(0.0, config.max_heading_deg)))
        start = Pose2D(-d, y, heading)
        if classify(start, a) != case:
            continue
        corners = sim.true_corners(DockPose.from_robot_in_dock(*start))["center"]
        if sim.in_view(corners, config.view_margin_px):
            return start
    raise InputError(f"case {case}: no start in its region keeps marker 2 in view; widen --distance")


# --- one run, in a worker -----------------------------------------------------------------------------


@dataclass
class _Environment:
    sim: Simulator
    blind: float
    perceive: dict[str, Perceive]


_ENV: dict[int, _Environment] = {}


def _environment(config: DockSimConfig) -> _Environment:
    """The simulator and estimators, built once per worker process."""
    key = id(config)
    if key not in _ENV:
        _ENV.clear()
        sim = config.simulator()
        extra: dict[str, Callable[[Any], Any]] = {}
        fused = None
        if any(m in BUNDLE_METHODS for m in config.methods):
            from monodock.estimation.bundle import load_bundle
            from monodock.estimation.fused import FusedEstimator
            from monodock.estimation.regression import RegressionEstimator

            assert config.bundle is not None
            bundle = load_bundle(config.bundle)
            regression = RegressionEstimator(bundle, sim.camera, sim.robot)
            extra["regression"] = regression.estimate
            if "fused" in config.methods:
                tables = bundle.fusion_tables()
                fused = FusedEstimator(sim.camera, sim.layout, sim.robot, tables, regression)
        # One estimator per method, so that a frame costs only its own method.
        perceive = {
            m: make_perceive(
                Estimator(
                    sim.camera,
                    sim.layout,
                    sim.robot,
                    (m,),
                    extra={k: v for k, v in extra.items() if k == m},
                    fused=fused if m == "fused" else None,
                ),
                m,
            )
            for m in config.methods
        }
        _ENV[key] = _Environment(sim, blind_gap(sim.camera, sim.layout, sim.robot), perceive)
    return _ENV[key]


@dataclass(frozen=True)
class _Task:
    case: int
    trial: int
    method: str
    start: Pose2D


def _run_trial(config: DockSimConfig, task: _Task) -> TrialResult:
    env = _environment(config)
    t0 = time.perf_counter()
    # The same draws for every method: wheel slip, camera phase and image noise start alike.
    rng = np.random.default_rng([config.seed, task.case, task.trial, 11])
    sim = env.sim
    robot = SimulatedRobot(sim, task.start, config.drive, rng)
    mission_config = dataclasses.replace(
        config.mission,
        measurement=MeasurementNoise.for_method(task.method),
        track=dataclasses.replace(config.mission.track, odometry=odometry_noise(config.drive)),
    )
    mission = DockingMission(mission_config, sim.robot, env.blind)
    perceive_s = 0.0
    inner = env.perceive[task.method]
    frames: list[FilterFrame] = []
    pending: list[Observation] = []

    def perceive(stamp: float, image: np.ndarray) -> Observation:
        nonlocal perceive_s
        t = time.perf_counter()
        observation = inner(stamp, image)
        perceive_s += time.perf_counter() - t
        if mission.state in (State.MOVING3, State.SETTLE):  # the filter was seeded at Calculate
            pending.append(observation)
        return observation

    def on_tick(m: DockingMission, _odom: Odometry) -> None:
        """After the mission took a frame in: the filter at the frame's exposure against the truth."""
        while pending:
            record = _filter_frame(m, robot, pending.pop())
            if record is not None:
                frames.append(record)

    result = run_mission(robot, perceive, mission, on_tick=on_tick)
    c = config.mission
    p = robot.pose
    lateral, gap, heading = p.y, robot.longitudinal_error(), p.theta
    success = (
        result.docked
        and abs(lateral) <= c.tolerance_lateral
        and abs(gap) <= c.tolerance_longitudinal
        and abs(heading) <= math.radians(c.tolerance_heading_deg)
    )
    path = tuple((s.pose.x, s.pose.y, s.pose.theta) for s in robot.truth[::10])
    return TrialResult(
        case=task.case,
        trial=task.trial,
        method=task.method,
        start=task.start,
        classified_case=result.case,
        state=result.state.value,
        reason=result.reason,
        success=success,
        retries=result.retries,
        time_s=result.duration,
        lateral_cm=lateral * 100,
        longitudinal_cm=gap * 100,
        heading_deg=math.degrees(heading),
        impact_speed=robot.impact_speed,
        frames=robot.frames_rendered,
        wall_s=time.perf_counter() - t0,
        render_s=robot.render_seconds,
        perceive_s=perceive_s,
        path=(*path, (p.x, p.y, p.theta)),
        log=tuple(result.log),
        filter_frames=tuple(frames),
    )


def odometry_noise(drive: DiffDriveConfig) -> OdometryNoise:
    """The filter's odometry noise for the simulated base: its own wheel model (track, scale and step noise)."""
    return dataclasses.replace(
        FilterConfig().odometry,
        track_width=drive.track_width,
        wheel_scale_sd=drive.wheel_scale_sd,
        wheel_noise_sd=drive.wheel_noise_sd,
        noise_period=drive.physics_dt,
    )


def _filter_frame(mission: DockingMission, robot: SimulatedRobot, observation: Observation) -> FilterFrame | None:
    """One frame's record: the filtered, raw and true DockPose at its exposure (None when it cannot be placed)."""
    odom = mission.history.at(observation.stamp)
    true_pose = next((pose for stamp, pose in robot.exposures if stamp == observation.stamp), None)
    if mission.track.mean is None or odom is None or true_pose is None:
        return None
    filtered, cov = mission.track.dock_pose(odom)
    truth = robot.dock_pose(true_pose)
    err = np.array([filtered.x - truth.x, filtered.y - truth.y, wrap_angle(filtered.yaw - truth.yaw)])
    try:
        nees = float(err @ np.linalg.solve(cov, err))
    except np.linalg.LinAlgError:
        nees = math.nan
    raw = observation.pose
    return FilterFrame(
        truth=(truth.x, truth.y, truth.yaw),
        filtered=(filtered.x, filtered.y, filtered.yaw),
        raw=None if raw is None else (raw.x, raw.y, raw.yaw),
        nees=nees,
    )


def run_dock_sim(config: DockSimConfig, *, progress: bool = True) -> list[TrialResult]:
    """Every case × trial × method, in ``config.jobs`` worker processes; results in a fixed order."""
    from tqdm import tqdm

    from monodock.core.parallel import map_with_state

    if any(m in BUNDLE_METHODS for m in config.methods) and config.bundle is None:
        raise InputError("the regression and fused methods need a model bundle")
    sim = config.simulator(config.seed)
    planner = config.mission.planner
    tasks: list[_Task] = []
    for case in config.cases:
        rng = np.random.default_rng([config.seed, case, 5])
        for trial in range(config.trials):
            start = sample_start(case, sim, planner, rng, config)
            tasks.extend(_Task(case, trial, m, start) for m in config.methods)
    results = map_with_state(_run_trial, config, tasks, jobs=config.jobs, chunksize=1)
    bar = tqdm(results, total=len(tasks), desc="docking runs", unit="run", disable=not progress)
    return list(bar)


# --- the numbers ---------------------------------------------------------------------------------------


def _stats(values: Sequence[float]) -> dict[str, float | None]:
    """mean, median, p95 and max of absolute values (None when there are none)."""
    a = np.abs(np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64))
    if a.size == 0:
        return {"mean": None, "median": None, "p95": None, "max": None}
    return {
        "mean": float(a.mean()),
        "median": float(np.median(a)),
        "p95": float(np.percentile(a, 95)),
        "max": float(a.max()),
    }


def _group(results: Sequence[TrialResult]) -> dict[str, Any]:
    runs = len(results)
    successes = sum(r.success for r in results)
    failures = Counter(
        (r.reason.split(":")[0] if r.state == "failed" else "docked outside the tolerances")
        for r in results
        if not r.success
    )
    return {
        "runs": runs,
        "successes": successes,
        "success_rate": successes / runs if runs else None,
        "final_lateral_cm": _stats([r.lateral_cm for r in results]),
        "final_longitudinal_cm": _stats([r.longitudinal_cm for r in results]),
        "final_heading_deg": _stats([r.heading_deg for r in results]),
        "time_s": _stats([r.time_s for r in results]),
        "retries": {"total": sum(r.retries for r in results), "max": max((r.retries for r in results), default=0)},
        "impact_speed_mps": _stats([r.impact_speed for r in results if r.impact_speed is not None]),
        "case_agreement": sum(r.classified_case == r.case for r in results) / runs if runs else None,
        "failures": dict(failures),
    }


FILTER_BANDS_CM = tuple(range(25, 251, 25))  # camera depth band edges of the filter figures


def _mae(frames: Sequence[FilterFrame], which: str) -> dict[str, float] | None:
    """Mean absolute errors of the filtered or raw DockPoses: depth and lateral in cm, yaw in degrees."""
    pairs = [(getattr(f, which), f.truth) for f in frames if getattr(f, which) is not None]
    if not pairs:
        return None
    err = np.array([[e[0] - t[0], e[1] - t[1], wrap_angle(e[2] - t[2])] for e, t in pairs])
    mae = np.abs(err).mean(axis=0)
    return {"depth_cm": float(mae[0] * 100), "lateral_cm": float(mae[1] * 100), "yaw_deg": math.degrees(mae[2])}


def _filter_block(frames: Sequence[FilterFrame]) -> dict[str, Any]:
    seen = [f for f in frames if f.raw is not None]
    coasting = [f for f in frames if f.raw is None]
    nees = [f.nees for f in frames if math.isfinite(f.nees)]
    return {
        "frames": len(seen),
        "filtered": _mae(seen, "filtered"),
        "single_frame": _mae(seen, "raw"),
        "coasting_frames": len(coasting),
        "coasting": _mae(coasting, "filtered"),
        "nees_mean": float(np.mean(nees)) if nees else None,
    }


def filter_accuracy(results: Sequence[TrialResult], camera_x: float) -> dict[str, Any]:
    """The dock filter against single frames, by 25 cm band of the true depth from the camera (25-250 cm).

    ``camera_x`` is the camera mount's x in base_link: the depth from the camera is DockPose.x minus it.
    Per band: MAE of depth (x), lateral (y) and yaw, filtered and single-frame, over the frames that had an
    estimate (like with like); frames without one (coasting) apart; and the filter's mean NEES against the
    truth (3 for a consistent covariance). ``all`` pools 25-250 cm; ``under_25cm`` is the blind zone.
    """
    frames = [f for r in results for f in r.filter_frames]

    def depth_cm(f: FilterFrame) -> float:
        return (f.truth[0] - camera_x) * 100

    edges = FILTER_BANDS_CM
    bands = []
    for lo, hi in itertools.pairwise(edges):
        block = _filter_block([f for f in frames if lo <= depth_cm(f) < hi])
        bands.append({"depth_cm": [lo, hi], **block})
    return {
        "bands": bands,
        "all": _filter_block([f for f in frames if edges[0] <= depth_cm(f) < edges[-1]]),
        "under_25cm": _filter_block([f for f in frames if depth_cm(f) < edges[0]]),
    }


def summarize(results: Sequence[TrialResult], config: DockSimConfig) -> dict[str, Any]:
    """The summary.json contract: ``overall`` and ``cases`` of the first method; every method under ``methods``."""
    methods: dict[str, Any] = {}
    for m in config.methods:
        rs = [r for r in results if r.method == m]
        methods[m] = {
            "overall": _group(rs),
            "cases": {str(c): _group([r for r in rs if r.case == c]) for c in config.cases},
        }
    first = methods[config.methods[0]]
    c = config.mission
    return {
        "method": config.methods[0],
        "overall": first["overall"],
        "cases": first["cases"],
        "methods": methods,
        "filter": {
            m: filter_accuracy([r for r in results if r.method == m], config.robot.camera_mount.x)
            for m in config.methods
        },
        "settings": {
            "trials_per_case": config.trials,
            "seed": config.seed,
            "distance_m": list(config.distance),
            "max_heading_deg": config.max_heading_deg,
            "standoff_m": c.planner.standoff,
            "tolerances": {
                "lateral_cm": c.tolerance_lateral * 100,
                "longitudinal_cm": c.tolerance_longitudinal * 100,
                "heading_deg": c.tolerance_heading_deg,
            },
            "camera_rate_hz": config.drive.camera_rate,
            "supersample": config.supersample,
        },
        "speed": {
            "runs": len(results),
            "wall_s_per_run": float(np.mean([r.wall_s for r in results])) if results else None,
            "render_s_per_run": float(np.mean([r.render_s for r in results])) if results else None,
            "perceive_s_per_run": float(np.mean([r.perceive_s for r in results])) if results else None,
            "frames_per_run": float(np.mean([r.frames for r in results])) if results else None,
        },
    }


def runs_csv(results: Sequence[TrialResult]) -> str:
    """One row per run."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        [
            "case",
            "trial",
            "method",
            "start_x_m",
            "start_y_m",
            "start_heading_deg",
            "classified_case",
            "state",
            "success",
            "retries",
            "time_s",
            "lateral_cm",
            "longitudinal_cm",
            "heading_deg",
            "impact_speed_mps",
            "frames",
            "wall_s",
            "render_s",
            "perceive_s",
            "reason",
        ]
    )
    for r in results:
        w.writerow(
            [
                r.case,
                r.trial,
                r.method,
                f"{r.start.x:.4f}",
                f"{r.start.y:.4f}",
                f"{math.degrees(r.start.theta):.2f}",
                r.classified_case or "",
                r.state,
                str(r.success).lower(),
                r.retries,
                f"{r.time_s:.2f}",
                f"{r.lateral_cm:.3f}",
                f"{r.longitudinal_cm:.3f}",
                f"{r.heading_deg:.3f}",
                "" if r.impact_speed is None else f"{r.impact_speed:.4f}",
                r.frames,
                f"{r.wall_s:.2f}",
                f"{r.render_s:.2f}",
                f"{r.perceive_s:.2f}",
                r.reason,
            ]
        )
    return buf.getvalue()


def filter_table(summary: dict[str, Any]) -> str:
    """Markdown: per method and depth band, the filter's MAE against single frames'."""
    lines = [
        "| method | depth from camera cm | frames | depth MAE cm (filtered / frame) "
        "| lateral MAE cm (filtered / frame) | yaw MAE ° (filtered / frame) "
        "| coasting frames (MAE depth / lateral / yaw) | NEES |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]

    def pair(block: dict[str, Any], key: str) -> str:
        f, r = block["filtered"], block["single_frame"]
        return "–" if f is None or r is None else f"{f[key]:.2f} / {r[key]:.2f}"

    for m, acc in summary.get("filter", {}).items():
        rows = [(f"{b['depth_cm'][0]}-{b['depth_cm'][1]}", b) for b in acc["bands"]]
        rows += [("25-250 (all)", acc["all"]), ("under 25 (blind)", acc["under_25cm"])]
        for name, b in rows:
            if not b["frames"] and not b["coasting_frames"]:
                continue
            c = b["coasting"]
            coast = f"{b['coasting_frames']}" + (
                "" if c is None else f" ({c['depth_cm']:.2f} / {c['lateral_cm']:.2f} / {c['yaw_deg']:.2f})"
            )
            nees = "–" if b["nees_mean"] is None else f"{b['nees_mean']:.1f}"
            lines.append(
                f"| {m} | {name} | {b['frames']} | {pair(b, 'depth_cm')} | {pair(b, 'lateral_cm')} | "
                f"{pair(b, 'yaw_deg')} | {coast} | {nees} |"
            )
    return "\n".join(lines) + "\n"


def comparison_table(summary: dict[str, Any]) -> str:
    """Markdown: per case and overall, each method's success and median / p95 / max final errors."""
    methods = list(summary["methods"])
    head = (
        "| case | method | success | lateral cm (median / p95 / max) | gap cm (median / p95 / max) "
        "| heading ° (median / p95 / max) | time s (median) | retries |"
    )
    lines = [head, "|---|---|---:|---:|---:|---:|---:|---:|"]

    def fmt(s: dict[str, float | None]) -> str:
        return " / ".join("–" if s[k] is None else f"{s[k]:.2f}" for k in ("median", "p95", "max"))

    for case in [*summary["cases"], "all"]:
        for m in methods:
            g = summary["methods"][m]["overall"] if case == "all" else summary["methods"][m]["cases"][case]
            time_med = g["time_s"]["median"]
            lines.append(
                f"| {case} | {m} | {g['successes']}/{g['runs']} | {fmt(g['final_lateral_cm'])} | "
                f"{fmt(g['final_longitudinal_cm'])} | {fmt(g['final_heading_deg'])} | "
                f"{'–' if time_med is None else f'{time_med:.1f}'} | {g['retries']['total']} |"
            )
    return "\n".join(lines) + "\n"
