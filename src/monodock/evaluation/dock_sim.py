"""``monodock dock-sim``: closed-loop docking in the simulator, camera in the loop, measured per case.

For each of the eight cases, N random starts inside that case's region; each start is docked once per method
(the same starts and the same wheel and camera draws for every method, so the methods compare pair by pair).
The robot sees only rendered frames and its odometry; the simulator's truth is used afterwards, to measure.
Besides where each run ended, every camera frame after the dock filter is seeded (Moving₃ and the settle at
the face) is recorded: the filtered DockPose (the filter's dock mapped to base_link with the odometry pose at
the frame's exposure), the frame's own estimate and the truth, for the filtered-vs-single-frame figures.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from monodock.compute import map_with_state
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.projection import blind_gap
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig
from monodock.dock.controller import DockingMission
from monodock.dock.interface import Odometry
from monodock.dock.planner import CASES, PlannerConfig, classify, point_a
from monodock.dock.pose_filter import FilterConfig, MeasurementNoise, OdometryNoise
from monodock.dock.run import run_mission, verdict
from monodock.dock.states import State
from monodock.dock.tracking import Observation, Perceive, make_perceive
from monodock.errors import InputError
from monodock.estimation.bundle import load_bundle
from monodock.estimation.consistency import camera_disagreement
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import make_estimator
from monodock.estimation.methods import METHOD_NAMES, NEEDS_BUNDLE, USES_BUNDLE
from monodock.evaluation.dock_faults import FaultInjector
from monodock.evaluation.dock_results import (
    DockSimSettings,
    DockSimSummary,
    FilterFrame,
    MethodRuns,
    RunSpeed,
    TrialResult,
    filter_accuracy,
)
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from monodock.sim.nuisance import Nuisances
from monodock.sim.simulator import Simulator

__all__ = [
    "ALL_METHODS",
    "BUNDLE_METHODS",
    "ROOM_BEARING_DEG",
    "ROOM_DISTANCE",
    "STARTS",
    "DockSimConfig",
    "case_distances",
    "room_tasks",
    "run_dock_sim",
    "sample_room_start",
    "sample_start",
    "summarize",
]

ALL_METHODS = METHOD_NAMES

# The methods that need the model bundle.
BUNDLE_METHODS = tuple(m for m in METHOD_NAMES if m in USES_BUNDLE)


@dataclass(frozen=True)
class DockSimConfig:
    """What to run: cases, starts per case, methods, the start region, the simulated robot and the mission."""

    cases: tuple[int, ...] = tuple(CASES)
    trials: int = 25
    methods: tuple[str, ...] = ("regression",)
    planners: tuple[str, ...] = ()  # PLANNERS to run from the same starts; () = the mission config's planner
    faults: tuple[str, ...] = ()  # FAULTS to run from the same starts; () = none
    redock: bool = False  # after each docking: undock to the staging pose and dock again
    seed: int = 0
    distance: tuple[float, float] = (1.0, 2.5)  # base_link's distance from the face along the axis, metres
    starts: str = "cases"  # "cases": per case, inside --distance and --max-heading; "room": ROOM_* (any heading)
    max_heading_deg: float = 30.0
    view_margin_px: float = 10.0
    supersample: int = 16
    jobs: int = 2
    mission: DockingConfig = field(default_factory=DockingConfig)
    drive: DiffDriveConfig = field(default_factory=DiffDriveConfig)
    layout: DockLayout = field(default_factory=DockLayout.default)
    camera: CameraModel = field(default_factory=CameraModel.default)
    robot: RobotConfig = field(default_factory=RobotConfig.default)
    nuisances: Nuisances = field(default_factory=Nuisances)
    bundle: Path | None = None  # the regression's model bundle
    # What the robot believes when the world differs (a wrong world, commissioned or not): the layout and the robot
    # file its estimator and mission get; None: the world's own. And the wheels, fixed for the world (a robot).
    believed_layout: DockLayout | None = None
    believed_robot: RobotConfig | None = None
    wheel_scale: tuple[float, float] | None = None

    @property
    def robot_layout(self) -> DockLayout:
        """The layout the robot's estimator uses."""
        return self.believed_layout or self.layout

    @property
    def robot_file(self) -> RobotConfig:
        """The robot file the robot's estimator and mission use."""
        return self.believed_robot or self.robot

    @property
    def fault_kinds(self) -> tuple[str, ...]:
        """The faults that run, each from every start ("none": the nominal run)."""
        return self.faults or ("none",)

    def variant(self, method: str, planner: str, fault: str = "none") -> str:
        """A run's group in the summary: the method, with the planner and the fault when more than one ran."""
        label = method
        if len(self.planner_kinds) > 1:
            label += f"/{planner}"
        if len(self.fault_kinds) > 1 or fault != "none":
            label += f"/{fault}"
        return label

    @property
    def variants(self) -> list[tuple[str, str, str, str]]:
        """(label, method, planner, fault) of every variant, in the order the summary lists them."""
        return [
            (self.variant(m, p, f), m, p, f) for f in self.fault_kinds for p in self.planner_kinds for m in self.methods
        ]

    @property
    def planner_kinds(self) -> tuple[str, ...]:
        """The planners that run, each from every start."""
        return self.planners or (self.mission.planner.kind,)

    def simulator(self, seed: int = 0) -> Simulator:
        # supersample is the renderer's sampling where surfaces meet, not a nuisance (Nuisances.supersample).
        return Simulator(
            layout=self.layout,
            camera=self.camera,
            robot=self.robot,
            nuisances=self.nuisances.updated(supersample=self.supersample),
            seed=seed,
        )


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


# The room envelope (``--starts room``): base_link this far from the face centre, this far off the dock's axis,
# any heading (the dock possibly behind the robot).
ROOM_DISTANCE = (0.5, 5.0)
ROOM_BEARING_DEG = 60.0
STARTS = ("cases", "room")


def sample_room_start(rng: np.random.Generator, robot: RobotConfig, drive: DiffDriveConfig) -> Pose2D:
    """A random start in the room envelope (dock frame): distance and bearing uniform, heading uniform in ±180°.
    Starts from which the robot could not turn on the spot without its footprint touching the face are redrawn
    (close in and well off the axis)."""
    reach = math.hypot(max(robot.front_offset, drive.rear_offset), 0.5 * drive.footprint_width) + 0.05
    for _ in range(10_000):
        d = float(rng.uniform(*ROOM_DISTANCE))
        bearing = math.radians(float(rng.uniform(-ROOM_BEARING_DEG, ROOM_BEARING_DEG)))
        heading = float(rng.uniform(-math.pi, math.pi))
        x, y = -d * math.cos(bearing), d * math.sin(bearing)
        if -x > reach:
            return Pose2D(x, y, heading)
    raise InputError("no room start clears the dock face")  # pragma: no cover - the envelope is fixed


def room_tasks(config: DockSimConfig, planner: PlannerConfig) -> list[tuple[int, int, Pose2D]]:
    """(case, trial, start) of ``config.trials`` room starts; the case is the start region it lies in (by
    ``classify``), the trial numbers run across them."""
    rng = np.random.default_rng([config.seed, 0, 7])
    a = point_a(planner, config.robot.front_offset)
    out = []
    for trial in range(config.trials):
        start = sample_room_start(rng, config.robot, config.drive)
        out.append((classify(start, a), trial, start))
    return out


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
    estimators: dict[str, Estimator]
    robot: RobotConfig  # the robot file the mission believes (the world's own unless told otherwise)


# The environment of the config last run in this process, with the config itself: an id alone could be reused by
# a later config once the first is gone (several dock-sims in one process, one after the other).
_ENV: dict[int, tuple[DockSimConfig, _Environment]] = {}


def _environment(config: DockSimConfig) -> _Environment:
    """The simulator and estimators, built once per worker process."""
    key = id(config)
    if key not in _ENV or _ENV[key][0] is not config:
        _ENV.clear()
        sim = config.simulator()
        learnt = any(m in BUNDLE_METHODS for m in config.methods)
        bundle = load_bundle(config.bundle) if learnt and config.bundle is not None else None
        # One estimator per method, so that a frame costs only its own method; built as the robot builds its own.
        # The camera was checked against the bundle's once, by run_dock_sim: not again in every worker.
        estimators = {
            m: make_estimator(
                method=m,
                bundle=bundle if m in BUNDLE_METHODS else None,
                camera=sim.camera,
                layout=config.robot_layout,
                robot=config.robot_file,
                warn_camera=False,
            )
            for m in config.methods
        }
        blind = blind_gap(sim.camera, config.robot_layout, config.robot_file)
        _ENV[key] = (config, _Environment(sim, blind, estimators, config.robot_file))
    return _ENV[key][1]


@dataclass(frozen=True)
class _Task:
    """Which run to make; its TrialResult names every field alike."""

    case: int
    trial: int
    method: str
    start: Pose2D
    planner: str = "monodock"
    fault: str = "none"
    variant: str = ""

    def keywords(self) -> dict[str, Any]:
        """The task's fields as keywords for its TrialResult."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


def _run_trial(config: DockSimConfig, task: _Task) -> TrialResult:
    env = _environment(config)
    t0, c0 = time.perf_counter(), time.process_time()
    # The same draws for every method: wheel slip, camera phase and image noise start alike.
    rng = np.random.default_rng([config.seed, task.case, task.trial, 11])
    sim = env.sim
    # Frames in which no marker can be detected (the last centimetres at the face) are not rendered nor detected:
    # the estimator would find nothing in them (``SimulatedRobot.blank_undetectable``), so the mission sees the
    # same observations, at a fraction of the cost.
    robot = SimulatedRobot(sim, task.start, config.drive, rng, blank_undetectable=True, wheel_scale=config.wheel_scale)
    mission_config = dataclasses.replace(
        config.mission,
        planner=dataclasses.replace(config.mission.planner, kind=task.planner),
        measurement=MeasurementNoise.for_method(task.method),
        track=dataclasses.replace(config.mission.track, odometry=odometry_noise(config.drive)),
    )
    mission = DockingMission(mission_config, env.robot, env.blind)
    faults = FaultInjector(task.fault, robot)
    perceive_s = perceive_cpu_s = 0.0
    # As the docking node does: the running mission's dock track predicts the markers the detector missed.
    running = [mission]
    track = (lambda: running[0].track) if mission_config.approach.predicted_markers else None
    inner = _skip_undetectable(robot, make_perceive(env.estimators[task.method], task.method, track=track))
    frames: list[FilterFrame] = []
    pending: list[Observation] = []

    posed = predicted = 0

    def perceive(stamp: float, image: np.ndarray) -> Observation:
        nonlocal perceive_s, perceive_cpu_s, posed, predicted
        t, c = time.perf_counter(), time.process_time()
        observation = inner(stamp, image)
        perceive_s += time.perf_counter() - t
        perceive_cpu_s += time.process_time() - c
        posed += observation.pose is not None
        predicted += observation.predicted > 0
        if mission.state in (State.MOVING3, State.SETTLE):  # the filter was seeded at Calculate
            pending.append(observation)
        return observation

    def on_tick(m: DockingMission, _odom: Odometry) -> None:
        """After the mission took a frame in: the filter at the frame's exposure against the truth."""
        faults.tick(m)
        while pending:
            record = _filter_frame(m, robot, pending.pop())
            if record is not None:
                frames.append(record)

    result = run_mission(robot, perceive, mission, on_tick=on_tick)
    c = config.mission
    p = robot.pose
    lateral, gap, heading = p.y, robot.longitudinal_error(), p.theta
    success = result.docked and _inside_tolerances(robot, c)
    redock = ""
    if config.redock and result.docked:
        redock = _undock_and_redock(robot, mission_config, env, inner, running)
    samples = robot.truth[::10]
    path = tuple((s.pose.x, s.pose.y, s.pose.theta) for s in samples)
    m = mission.manoeuvre
    return TrialResult(
        **task.keywords(),
        classified_case=result.case,
        **verdict(result),
        success=success,
        time_s=result.duration,
        lateral_cm=lateral * 100,
        longitudinal_cm=gap * 100,
        heading_deg=math.degrees(heading),
        impact_speed=robot.impact_speed,
        frames=robot.frames_rendered + robot.frames_blank,
        wall_s=time.perf_counter() - t0,
        render_s=robot.render_seconds,
        perceive_s=perceive_s,
        path=(*path, (p.x, p.y, p.theta)),
        path_t=(*(s.t for s in samples), robot.t),
        log=tuple(result.log),
        filter_frames=tuple(frames),
        point_a=None if m is None else (m.point_a.x, m.point_a.y),
        fault_triggered=faults.triggered,
        collided=robot.collided,
        redock=redock,
        cpu_s=time.process_time() - c0,
        render_cpu_s=robot.render_cpu_seconds,
        perceive_cpu_s=perceive_cpu_s,
        posed_frames=posed,
        predicted_frames=predicted,
    )


def _skip_undetectable(robot: SimulatedRobot, perceive: Perceive) -> Perceive:
    """``perceive``, but a frame the simulator delivered blank because no marker can be detected in it gives the
    observation of a frame without markers at once (what the estimator returns when it detects none)."""

    def skipping(stamp: float, image: np.ndarray) -> Observation:
        if robot.undetectable(stamp):
            return Observation(stamp, None, 0)
        return perceive(stamp, image)

    return skipping


def _undock_and_redock(
    robot: SimulatedRobot, config: DockingConfig, env: _Environment, perceive: Perceive, running: list[DockingMission]
) -> str:
    """From docked: undock to the staging pose, then dock again; what happened, in words. ``running`` holds the
    mission ``perceive``'s prior comes from: each new mission is put in it."""
    running[0] = DockingMission(config, env.robot, env.blind, task="undock")
    undock = run_mission(robot, perceive, running[0])
    if not undock.succeeded:
        return f"undock failed: {undock.reason}"
    running[0] = DockingMission(config, env.robot, env.blind)
    again = run_mission(robot, perceive, running[0])
    if not again.docked:
        return f"redock failed: {again.reason}"
    return "redocked" if _inside_tolerances(robot, config) else "redock outside the tolerances"


def _inside_tolerances(robot: SimulatedRobot, c: DockingConfig) -> bool:
    """Whether the robot truly stands docked: lateral, gap (or overshoot) and heading within the tolerances."""
    p = robot.pose
    return (
        abs(p.y) <= c.retry.tolerance_lateral
        and abs(robot.longitudinal_error()) <= c.retry.tolerance_longitudinal
        and abs(p.theta) <= math.radians(c.retry.tolerance_heading_deg)
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
    placed = mission.track.dock_at(observation.stamp)
    true_pose = next((pose for stamp, pose in robot.exposures if stamp == observation.stamp), None)
    if placed is None or true_pose is None:
        return None
    filtered, cov = placed
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
    if any(m in NEEDS_BUNDLE for m in config.methods) and config.bundle is None:
        raise InputError("the regression method needs a model bundle")
    sim = config.simulator(config.seed)
    if any(m in BUNDLE_METHODS for m in config.methods) and config.bundle is not None:
        said = camera_disagreement(load_bundle(config.bundle).camera(), sim.camera, str(config.bundle), "simulated")
        if said is not None:
            logging.getLogger("monodock.input").warning(said)
    planner = config.mission.planner
    tasks: list[_Task] = []
    if config.starts == "room":
        for case, trial, start in room_tasks(config, planner):
            tasks.extend(_Task(case, trial, m, start, p, f, label) for label, m, p, f in config.variants)
    for case in config.cases if config.starts == "cases" else ():
        rng = np.random.default_rng([config.seed, case, 5])
        for trial in range(config.trials):
            start = sample_start(case, sim, planner, rng, config)
            tasks.extend(_Task(case, trial, m, start, p, f, label) for label, m, p, f in config.variants)
    results = map_with_state(_run_trial, config, tasks, jobs=config.jobs, chunksize=1)
    bar = tqdm(results, total=len(tasks), desc="docking runs", unit="run", disable=None if progress else True)
    return list(bar)


# --- the numbers: summary.json -------------------------------------------------------------------------


def summarize(results: Sequence[TrialResult], config: DockSimConfig) -> DockSimSummary:
    """The summary.json contract: per method its runs overall and per case, the filter's accuracy, the settings."""
    labels = [v[0] for v in config.variants]
    groups = {
        v: [r for r in results if (r.variant or config.variant(r.method, r.planner, r.fault)) == v] for v in labels
    }
    c = config.mission
    return DockSimSummary(
        method=labels[0],
        methods={v: MethodRuns.of(runs, config.cases) for v, runs in groups.items()},
        filter={v: filter_accuracy(runs, config.robot.camera_mount.x) for v, runs in groups.items()},
        settings=DockSimSettings(
            trials_per_case=config.trials,
            seed=config.seed,
            distance_m=config.distance,
            max_heading_deg=config.max_heading_deg,
            standoff_m=c.planner.standoff,
            planner=",".join(config.planner_kinds),
            tolerance_lateral_cm=c.retry.tolerance_lateral * 100,
            tolerance_longitudinal_cm=c.retry.tolerance_longitudinal * 100,
            tolerance_heading_deg=c.retry.tolerance_heading_deg,
            camera_rate_hz=config.drive.camera_rate,
            supersample=config.supersample,
        ),
        speed=RunSpeed.of(results),
    )
