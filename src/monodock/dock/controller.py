"""The docking mission: acquire → calculate → Moving₁ → Moving₂ → Moving₃ → docked, as a state machine.

The papers' procedure (conference paper §IV, Sensors 2025 §4.9): Calculate depth, angle and K and set Point A;
Moving₁ straight to Point A; Moving₂ rotate by the computed angle; Moving₃ straight to the dock, fine-tuned by
P-control. Moving₁ and Moving₂ run on odometry towards targets fixed at Calculate (the markers may leave the
view while the robot turns towards A). Moving₃ re-estimates from every frame: each frame, with its covariance,
refines the dock's pose in the odometry frame (``DockFilter``, an extended Kalman filter predicted by the wheel
odometry), and a P-controller steers the lateral and heading errors against it at the control rate, so frame
latency and the camera's rate do not enter the loop. The last centimetres, where the camera is too close to
see marker 2 whole, are driven on the filter and odometry alone (predict only), at creep speed.

Safety: accelerations and speeds are limited; the speed near the face is bounded by what can stop in the
remaining distance; markers lost for longer than ``lost_timeout`` outside that blind zone stop the robot;
the whole mission has a time limit. Every stop is a zero command, never a silent hang, and every failure
says why as a ``FailureReason`` (the kind of error code Nav2's docking server reports), with the numbers in
``MissionResult.reason``. ``State`` documents what the robot does in each state and what ends it.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.interface import Odometry, RobotInterface
from monodock.dock.planner import Manoeuvre, PlannerConfig, plan_for, point_a
from monodock.dock.pose_filter import DockFilter, FilterConfig, MeasurementNoise
from monodock.errors import ConfigError
from monodock.estimation.estimator import Estimator

__all__ = [
    "DockingConfig",
    "DockingMission",
    "FailureReason",
    "MissionResult",
    "Observation",
    "Perceive",
    "State",
    "blind_gap",
    "make_perceive",
    "run_mission",
]


class State(StrEnum):
    """The mission's states: what the robot does in each and what ends it.

    Every state that is not final also ends in ``FAILED`` (``FailureReason.TIMEOUT``) when the mission has run
    longer than ``DockingConfig.mission_timeout``. The values are what the mission's log and dock-sim's
    ``runs.csv`` print.
    """

    ACQUIRE = "acquire"
    """Find the dock: stand still while the first frames arrive (``first_frame_wait``), then turn on the spot at
    ``acquire_turn_rate``. Ends in ``CALCULATE`` when a frame gives the dock's pose; in ``FAILED`` when
    ``acquire`` is off (``NOT_IN_VIEW``) or after ``acquire_max_turn_deg`` of turning (``NOT_FOUND``)."""

    CENTER = "center"
    """Turn on the spot, on odometry, to face the dock, so that all three markers come into view. Ends in
    ``CALCULATE`` when the heading is within ``turn_tolerance_deg`` and the robot has stopped turning."""

    CALCULATE = "calculate"
    """Stand still (until the odometry reads still, at most ``settle_timeout``), then take the median of
    ``calculate_frames`` frames (or of those that came within ``calculate_timeout``). Ends in ``CENTER`` when the
    frames saw fewer than three markers and the dock is more than ``center_tolerance_deg`` off the heading (not
    twice in a row); in ``MOVING1_TURN`` with the plan (the case, Point A, the targets in odometry; the dock filter
    seeded); back in ``ACQUIRE`` when no frame came within ``calculate_timeout``."""

    MOVING1_BACK = "moving1-back"
    """monodock's planner only: back out straight along the start heading (the camera keeps the dock in view) by
    the plan's ``back_out``, on odometry. Ends in ``MOVING1_TURN`` on arrival."""

    MOVING1_TURN = "moving1-turn"
    """Moving₁'s first part: turn on the spot, on odometry, to the heading of the straight leg to Point A (no turn
    with the papers' planner). Ends in ``MOVING1_DRIVE`` when there and still."""

    MOVING1_DRIVE = "moving1-drive"
    """Moving₁: drive straight to Point A on odometry (backwards where the plan says so), steering on the
    bearing. Ends in ``MOVING2`` on arrival (within ``arrive_tolerance``)."""

    MOVING2 = "moving2"
    """Moving₂: turn on the spot, on odometry, to face the charger square from Point A (by Θab). Ends in
    ``MOVING3`` when there and still; the lost-markers clock starts then. From ``MOVING1_TURN`` to here, every
    frame that sees the dock refines the dock filter, and Point A and the turns follow it
    (``refine_while_moving``)."""

    MOVING3 = "moving3"
    """Moving₃: straight at the face; every frame refines the dock filter, a P-controller steers the lateral and
    heading errors, the speed falls towards the face, and the blind zone is driven on the filter alone at creep
    speed. Ends in ``SETTLE`` on contact or at the face by the estimate; in ``BACK_OFF`` at the checkpoint
    (``checkpoint_gap``) when off the axis or the heading reference with retries left; in ``RECOVER`` when no
    frame updated the filter for ``lost_timeout`` outside the blind zone with retries left, else in ``FAILED``
    (``MARKERS_LOST``)."""

    RECOVER = "recover"
    """Markers lost mid-approach: stop, back off straight (along the approach) by ``recover_distance``, on
    odometry. Ends in ``CALCULATE`` on arrival (which re-acquires when no frame comes)."""

    SETTLE = "settle"
    """Stand still at the face (until the odometry reads still, at most ``settle_timeout``), then judge. Ends in
    ``DOCKED`` when the charger reports charging, or when the robot's own estimate of its pose is inside the
    tolerances and the robot cannot tell whether it charges; in ``CHARGE_WAIT`` inside the tolerances when it
    can; outside them in ``BACK_OFF`` with retries left, else in ``FAILED`` (``OUTSIDE_TOLERANCES``)."""

    CHARGE_WAIT = "charge-wait"
    """Stand on the contacts until the charger reports charging. Ends in ``DOCKED`` when it does; after
    ``charge_timeout`` in ``RESEAT`` with re-seats left, else in ``FAILED`` (``NOT_CHARGING``)."""

    RESEAT = "reseat"
    """Back off ``reseat_distance`` straight, on odometry, and drive in again, each time ``reseat_push`` farther
    than the estimate's face (contacts that did not mate are most often not pressed home): ends in ``MOVING3``."""

    BACK_OFF = "back-off"
    """A retry: reverse straight to Point A (placed again from the filter's dock pose; at most
    ``max_reverse_distance`` towards it) on odometry. Ends in ``CALCULATE`` on arrival, with the dock filter
    reset."""

    UNDOCK = "undock"
    """Undocking (``DockingMission(..., task="undock")``): back out straight from the face to the staging pose,
    Point A (``planner.standoff`` of floor before the face), on odometry. Ends in ``UNDOCKED`` on arrival."""

    DOCKED = "docked"
    """Final: at the face, charging (or inside the tolerances by the robot's own estimate when it cannot tell);
    every command is zero."""

    UNDOCKED = "undocked"
    """Final: undocked, standing at the staging pose; every command is zero."""

    FAILED = "failed"
    """Final: the mission gave up (``DockingMission.failure`` says why); every command is zero."""

    @property
    def final(self) -> bool:
        """Whether the mission has ended in this state."""
        return self in (State.DOCKED, State.UNDOCKED, State.FAILED)


class FailureReason(StrEnum):
    """Why a mission failed, one member per way it can; the nearest error code of Nav2's docking server.

    Nav2's ``nav2_msgs/action/DockRobot`` reports a failure as an error code, raised in ``opennav_docking`` as an
    exception type. Ours map onto them like this:

    ======================  ==============================================================================
    member                  Nav2 ``DockRobot`` result code (``opennav_docking_core`` exception)
    ======================  ==============================================================================
    ``NOT_IN_VIEW``         ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, initial perception)
    ``NOT_FOUND``           ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, initial perception)
    ``MARKERS_LOST``        ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, during the approach)
    ``OUTSIDE_TOLERANCES``  ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, all retries used)
    ``OBSTACLE_BEHIND``     ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, cannot reverse)
    ``REVERSE_LIMIT``       ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, a reverse leg too long)
    ``NOT_CHARGING``        ``FAILED_TO_CHARGE`` = 906 (``FailedToCharge``, all re-seats used)
    ``TIMEOUT``             ``TIMEOUT`` = 907
    ``ODOMETRY_LOST``       ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, no odometry to steer by)
    ``CANCELLED``           ``NONE`` = 0 (Nav2 ends a cancelled action as CANCELED, not with an error code)
    ======================  ==============================================================================

    ``MissionResult.reason`` carries the human detail (the numbers) next to the member.
    """

    NOT_IN_VIEW = "not-in-view"
    """No markers in view at the start, and ``acquire`` is off (the robot does not turn to look)."""

    NOT_FOUND = "not-found"
    """No markers in view after turning ``acquire_max_turn_deg`` on the spot."""

    MARKERS_LOST = "markers-lost"
    """No frame updated the dock filter for ``lost_timeout`` during Moving₃, outside the blind zone."""

    OUTSIDE_TOLERANCES = "outside-tolerances"
    """At the face, the robot's own estimate of its final pose is outside the tolerances after ``max_retries``."""

    OBSTACLE_BEHIND = "obstacle-behind"
    """The rear range sensor saw something within ``rear_safety_distance`` for ``blocked_timeout`` while the robot
    had to reverse: it stopped short and gave up."""

    REVERSE_LIMIT = "reverse-limit"
    """A reverse leg would be, or became, longer than ``max_reverse_distance``."""

    NOT_CHARGING = "not-charging"
    """At the face inside the tolerances, the charger never reported charging, after ``max_reseats`` re-seats."""

    TIMEOUT = "timeout"
    """The mission ran longer than ``mission_timeout``."""

    ODOMETRY_LOST = "odometry-lost"
    """The robot's odometry stopped coming (``DockingMission.abort`` by whoever runs the mission, e.g. the ROS node)."""

    CANCELLED = "cancelled"
    """Cancelled from outside (``DockingMission.abort``): a second call, a cancel request, a shutdown."""

    @property
    def nav2_error_code(self) -> int:
        """The nearest ``DockRobot.Result`` error code of Nav2's docking server (see the table above)."""
        return _NAV2_ERROR_CODE[self]


# nav2_msgs/action/DockRobot.action's result codes.
_FAILED_TO_DETECT_DOCK, _FAILED_TO_CONTROL, _FAILED_TO_CHARGE, _TIMEOUT = 904, 905, 906, 907
_NAV2_ERROR_CODE = {
    FailureReason.NOT_IN_VIEW: _FAILED_TO_DETECT_DOCK,
    FailureReason.NOT_FOUND: _FAILED_TO_DETECT_DOCK,
    FailureReason.MARKERS_LOST: _FAILED_TO_DETECT_DOCK,
    FailureReason.OUTSIDE_TOLERANCES: _FAILED_TO_CONTROL,
    FailureReason.OBSTACLE_BEHIND: _FAILED_TO_CONTROL,
    FailureReason.REVERSE_LIMIT: _FAILED_TO_CONTROL,
    FailureReason.NOT_CHARGING: _FAILED_TO_CHARGE,
    FailureReason.TIMEOUT: _TIMEOUT,
    FailureReason.ODOMETRY_LOST: _FAILED_TO_CONTROL,
    FailureReason.CANCELLED: 0,
}


@dataclass(frozen=True)
class Observation:
    """One frame's estimate: the DockPose (None when the estimator had nothing), how many markers it used, and
    its 3x3 covariance (x m, y m, yaw rad; base_link) when the method gives one (else the mission's defaults).
    """

    stamp: float
    pose: DockPose | None
    markers: int = 0
    covariance: NDArray[np.float64] | None = field(default=None, repr=False, compare=False)


# What turns an image into an observation: the caller's estimator (regression, board PnP, ...).
Perceive = Callable[[float, "np.ndarray"], Observation]


def make_perceive(estimator: Estimator, method: str) -> Perceive:
    """Turn the estimator's method into the controller's per-frame observation."""

    def perceive(stamp: float, image: np.ndarray) -> Observation:
        e = estimator.estimate("", stamp, image).estimates[method]
        return Observation(stamp, e.pose, len(e.markers_seen), e.covariance)

    return perceive


@dataclass(frozen=True)
class DockingConfig:
    """Every gain, speed, acceleration, tolerance, time-out and retry count of docking (SI units, angles in degrees).

    The docking config file (``monodock.dock.config``, ``--config``) and the docking node's ROS parameters set
    these by name; docs/docking.md lists every field with its unit, default and what it does.
    """

    planner: PlannerConfig = field(default_factory=PlannerConfig)
    control_period: float = 0.02
    # Speed and acceleration limits; the robot's own maxima cap these.
    cruise_speed: float = 0.20
    approach_speed: float = 0.12
    turn_rate: float = 0.6
    linear_accel: float = 0.4
    angular_accel: float = 1.5
    min_speed: float = 0.02  # below this a real base's wheels stall; a non-zero command is never smaller
    min_turn_rate: float = 0.08
    creep_distance: float = 0.03  # the last metres at min_speed
    stop_lead: float = 0.1  # seconds: stop this early for the command latency and the motors' lag
    # Moving₃'s P-control: heading reference -atan(k_lateral * lateral error), turn rate k_heading * heading error.
    k_lateral: float = 4.0
    k_heading: float = 2.5
    max_correction_deg: float = 20.0
    heading_only_gap: float = 0.12  # closer than this the lateral term fades out: arrive square
    # Turning and driving on odometry.
    k_turn: float = 3.0
    turn_tolerance_deg: float = 0.3
    k_bearing: float = 2.0
    arrive_tolerance: float = 0.005
    refine_while_moving: bool = True  # frames during Moving₁ and Moving₂ refine Point A and the turns
    # Acquire and calculate.
    acquire: bool = True
    acquire_turn_rate: float = 0.3
    first_frame_wait: float = 0.5
    reacquire_wait: float = 3.0  # after losing the markers: stand and look this long before turning to search
    acquire_max_turn_deg: float = 370.0
    calculate_frames: int = 9
    center_tolerance_deg: float = 5.0
    calculate_timeout: float = 3.0
    settle_speed: float = 0.005
    settle_timeout: float = 1.5
    # Retry, recovery and tolerances.
    checkpoint_gap: float = 0.25  # end of Moving₃'s early part: front edge this far from the face
    retry_lateral: float = 0.02
    retry_heading_deg: float = 4.0  # off the P-controller's heading reference
    max_retries: int = 2  # retries and recoveries together
    recover_distance: float = 0.30  # markers lost mid-approach: back off this far before looking again
    tolerance_lateral: float = 0.02
    tolerance_longitudinal: float = 0.02
    tolerance_heading_deg: float = 3.0
    # Charging.
    charge_timeout: float = 2.0  # at the face: the charger must report charging within this
    reseat_distance: float = 0.05  # not charging: back off this far and drive in again
    reseat_push: float = 0.005  # each re-seat drives this much farther in than the last (the contacts' springs)
    max_reseats: int = 2
    # Safety.
    max_reverse_speed: float = 0.10
    max_reverse_distance: float = 1.5  # no reverse leg is longer
    rear_safety_distance: float = 0.25  # stop reversing short of anything this close behind the back edge
    blocked_timeout: float = 5.0  # wait this long for the space behind to clear, then fail
    lost_timeout: float = 1.0
    mission_timeout: float = 120.0
    blind_margin: float = 0.04
    track: FilterConfig = field(default_factory=FilterConfig)  # the dock filter: odometry noise, gate, reset
    measurement: MeasurementNoise = field(default_factory=MeasurementNoise)  # frames without a covariance

    def __post_init__(self) -> None:
        positive = (
            "control_period",
            "cruise_speed",
            "approach_speed",
            "turn_rate",
            "linear_accel",
            "angular_accel",
            "max_reverse_speed",
            "max_reverse_distance",
            "recover_distance",
            "reseat_distance",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"docking config: {name} must be positive, got {getattr(self, name)}")
        not_negative = (
            "rear_safety_distance",
            "blocked_timeout",
            "charge_timeout",
            "reacquire_wait",
            "lost_timeout",
            "reseat_push",
        )
        for name in not_negative:
            if not getattr(self, name) >= 0:
                raise ConfigError(f"docking config: {name} must not be negative, got {getattr(self, name)}")
        if self.min_speed > self.approach_speed:
            raise ConfigError("docking config: min_speed must not exceed approach_speed")
        if self.min_speed > self.max_reverse_speed:
            raise ConfigError("docking config: min_speed must not exceed max_reverse_speed")
        if self.recover_distance > self.max_reverse_distance or self.reseat_distance > self.max_reverse_distance:
            raise ConfigError(
                "docking config: recover_distance and reseat_distance must not exceed max_reverse_distance"
            )


@dataclass
class MissionResult:
    """How a mission ended, as the robot itself sees it (the simulator's truth is not in here)."""

    state: State
    failure: FailureReason | None  # why it failed; None when docked
    reason: str  # the human detail, with the numbers (empty when docked)
    case: int | None
    retries: int
    duration: float
    estimated_final: Pose2D | None  # the robot's pose in the dock frame by its own estimate
    impact_speed: float | None = None
    log: list[tuple[float, str]] = field(default_factory=list)
    reseats: int = 0
    charging: bool | None = None  # whether the charger confirmed charging; None when the robot cannot tell
    recoveries: int = 0  # of ``retries``: those after the markers were lost

    @property
    def docked(self) -> bool:
        return self.state is State.DOCKED

    @property
    def succeeded(self) -> bool:
        """Docked, or undocked for an undocking mission."""
        return self.state in (State.DOCKED, State.UNDOCKED)


def blind_gap(camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> float:
    """The front edge's distance from the face below which marker 2 no longer fits in the image (robot square on)."""

    def fits(gap: float) -> bool:
        base_T_dock = DockPose(gap + robot.front_offset, 0.0, 0.0).matrix()
        optical_T_dock = transforms.invert(robot.base_T_optical()) @ base_T_dock
        p = transforms.apply(optical_T_dock, layout.corners_in_dock("center"))
        if np.any(p[:, 2] <= 0) or not np.all(camera.in_view_field(p)):
            return False
        px = camera.project(p)
        return bool(np.all((px >= 0) & (px <= np.array(camera.size) - 1)))

    lo, hi = 0.0, 3.0
    if fits(lo):
        return 0.0
    if not fits(hi):
        raise ConfigError("marker 2 never fits in the image in front of the dock; check the camera and layout")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def _positive_definite(cov: NDArray[np.float64]) -> bool:
    """Symmetric with positive eigenvalues: a covariance the filter can invert."""
    if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-12):
        return False
    return bool(np.all(np.linalg.eigvalsh(cov) > 0.0))


class _OdomHistory:
    """Odometry poses of the last seconds, to place a frame by where the robot was at its exposure."""

    def __init__(self, horizon: float = 3.0) -> None:
        self.horizon = horizon
        self.t: list[float] = []
        self.poses: list[Pose2D] = []

    def add(self, t: float, pose: Pose2D) -> None:
        self.t.append(t)
        self.poses.append(pose)
        while self.t and self.t[0] < t - self.horizon:
            self.t.pop(0)
            self.poses.pop(0)

    def at(self, t: float) -> Pose2D | None:
        if not self.t or t < self.t[0]:
            return None
        i = bisect.bisect_right(self.t, t)
        if i >= len(self.t):
            return self.poses[-1]
        t0, t1 = self.t[i - 1], self.t[i]
        p0, p1 = self.poses[i - 1], self.poses[i]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return Pose2D(
            p0.x + w * (p1.x - p0.x),
            p0.y + w * (p1.y - p0.y),
            wrap_angle(p0.theta + w * wrap_angle(p1.theta - p0.theta)),
        )


@dataclass
class _Targets:
    """Moving₁ and Moving₂'s goals in the odometry frame, fixed at Calculate."""

    a: Pose2D
    drive_heading: float
    final_heading: float
    reverse: bool


@dataclass(frozen=True)
class _Tick:
    """What a state's handler gets each control tick: the time, the odometry and the robot's other sensors (None
    where it has none): the contact switch, the charger's charging signal and the rear range, metres."""

    now: float
    odom: Odometry
    contact: bool | None
    charging: bool | None = None
    rear_range: float | None = None


# The states that move towards Point A on the plan, in which frames refine it.
_MOVING_TO_A = (State.MOVING1_BACK, State.MOVING1_TURN, State.MOVING1_DRIVE, State.MOVING2)

# One state's work for one tick: the desired velocity command (m/s, rad/s), before the limits.
_Handler = Callable[[_Tick], tuple[float, float]]


class DockingMission:
    """The state machine; ``step`` turns odometry and the latest observation into a velocity command.

    Each state has one handler (``_on_<state>``), looked up in a table keyed by ``State``; a handler returns the
    desired command and moves to the next state with ``_enter`` or ``_fail``.
    """

    def __init__(self, config: DockingConfig, robot: RobotConfig, blind: float, *, task: str = "dock") -> None:
        if task not in ("dock", "undock"):
            raise ConfigError(f"a docking mission's task is dock or undock, got {task!r}")
        self.task = task
        self.config = config
        self.robot = robot
        self.blind = blind + config.blind_margin
        self.max_speed = min(config.cruise_speed, robot.max_linear_speed)
        self.max_turn = min(config.turn_rate, robot.max_angular_speed)
        self.track = DockFilter(config.track)
        self.history = _OdomHistory()
        self.state = State.ACQUIRE
        self.failure: FailureReason | None = None
        self.reason = ""
        self.case: int | None = None
        self.manoeuvre: Manoeuvre | None = None
        self.heading_before_center: float | None = None  # odometry heading when a centring turn began
        self.retries = 0
        self.recoveries = 0
        self.reseats = 0
        self.charging: bool | None = None
        self.log: list[tuple[float, str]] = []
        self.command = (0.0, 0.0)
        self.start_time: float | None = None
        self.state_since = 0.0
        self.last_seen = -math.inf
        self.calc_samples: list[tuple[Pose2D, DockPose, NDArray[np.float64]]] = []
        self.calc_markers: list[int] = []
        self.centered = False
        self.center_heading = 0.0
        self.turned = 0.0
        self.checked = False
        self.impact_speed: float | None = None
        self._last_odom: Pose2D | None = None
        self._last_stamp = 0.0
        self._targets = _Targets(Pose2D(0.0, 0.0, 0.0), 0.0, 0.0, False)
        self._back_target: Pose2D | None = None  # where a straight reverse (back-out, recover, re-seat, undock) ends
        self._reverse_from: Pose2D | None = None  # odometry pose where the current reverse leg began
        self._blocked_since: float | None = None  # when the rear range first stopped the current reverse
        self._handlers: dict[State, _Handler] = {
            State.ACQUIRE: self._on_acquire,
            State.CENTER: self._on_center,
            State.CALCULATE: self._on_calculate,
            State.MOVING1_BACK: self._on_moving1_back,
            State.MOVING1_TURN: self._on_moving1_turn,
            State.MOVING1_DRIVE: self._on_moving1_drive,
            State.MOVING2: self._on_moving2,
            State.MOVING3: self._on_moving3,
            State.RECOVER: self._on_recover,
            State.SETTLE: self._on_settle,
            State.CHARGE_WAIT: self._on_charge_wait,
            State.RESEAT: self._on_reseat,
            State.BACK_OFF: self._on_back_off,
            State.UNDOCK: self._on_undock,
            State.DOCKED: self._on_final,
            State.UNDOCKED: self._on_final,
            State.FAILED: self._on_final,
        }

    # --- bookkeeping ------------------------------------------------------------------------

    @property
    def finished(self) -> bool:
        return self.state.final

    @property
    def wants_frames(self) -> bool:
        """Whether this state uses camera frames (the simulator renders only frames that are used)."""
        if self.state in (State.ACQUIRE, State.CALCULATE, State.MOVING3, State.SETTLE):
            return True
        return self.config.refine_while_moving and self.state in _MOVING_TO_A

    def _enter(self, now: float, state: State, note: str = "") -> None:
        if state is State.CALCULATE:
            self.calc_samples, self.calc_markers = [], []
            self.centered = self.state is State.CENTER
        self.state, self.state_since = state, now
        self.log.append((now, state.value + (f": {note}" if note else "")))

    def _fail(self, now: float, failure: FailureReason, reason: str) -> tuple[float, float]:
        """End the mission in ``FAILED``: why (the enum) and the detail (the log's text), and a zero command."""
        self.failure, self.reason = failure, reason
        self._enter(now, State.FAILED, reason)
        self.command = (0.0, 0.0)
        return self.command

    def abort(self, now: float, failure: FailureReason, reason: str) -> None:
        """End the mission from outside (cancelled, or a sensor it cannot go on without); the next command is zero."""
        if not self.finished:
            self._fail(now, failure, reason)

    # --- the loop ---------------------------------------------------------------------------

    def step(
        self,
        now: float,
        odom: Odometry,
        observation: Observation | None,
        contact: bool | None = None,
        *,
        charging: bool | None = None,
        rear_range: float | None = None,
    ) -> tuple[float, float]:
        """One control tick: the velocity command (m/s, rad/s) for the next period.

        ``contact``, ``charging`` and ``rear_range`` are the robot's optional sensors (None: it has none): the
        contact switch, the charger's charging signal, the distance to the nearest thing behind it (metres).
        """
        if self.start_time is None:
            self.start_time = now
            self._enter(now, State.UNDOCK if self.task == "undock" else State.ACQUIRE)
        pose = odom.pose
        if self._last_odom is not None:
            # Predict: the dock stays put, its uncertainty in the odometry frame grows with the wheels' drift.
            self.track.predict(self._last_odom, pose, odom.stamp - self._last_stamp)
        self._last_odom, self._last_stamp = pose, odom.stamp
        self.history.add(odom.stamp, pose)
        if observation is not None and observation.pose is not None:
            at = self.history.at(observation.stamp)
            if at is not None:
                cov = self.measurement_covariance(observation)
                if self.state is State.CALCULATE:
                    self.calc_samples.append((at, observation.pose, cov))  # the median comes at the plan
                    self.calc_markers.append(observation.markers)
                    self.last_seen = observation.stamp
                elif self.track.update(at, observation.pose, cov):
                    self.last_seen = observation.stamp
        if self.finished:
            return (0.0, 0.0)
        if now - self.start_time > self.config.mission_timeout:
            return self._fail(
                now, FailureReason.TIMEOUT, f"mission took longer than {self.config.mission_timeout:.0f} s"
            )
        tick = _Tick(now, odom, contact, charging, rear_range)
        v, w = self._handlers[self.state](tick)
        if not self.finished:
            v, w = self._guard_reverse(tick, v, w)
        if self.finished:
            return (0.0, 0.0)
        self.command = self._limit(v, w)
        return self.command

    def _guard_reverse(self, tick: _Tick, v: float, w: float) -> tuple[float, float]:
        """Reversing made safe: every reverse leg bounded in length; stop short of anything the rear range sees."""
        c = self.config
        if not (v < 0.0 or tick.odom.linear < -c.settle_speed):
            self._reverse_from, self._blocked_since = None, None
            return v, w
        if self._reverse_from is None:
            self._reverse_from = tick.odom.pose
        reversed_by = self._reverse_from.distance(tick.odom.pose)
        # Every leg is planned within max_reverse_distance; the guard allows a tenth more for steering on odometry
        # and for a stop that follows one reverse leg straight with another (a recovery after a back-off).
        if reversed_by > 1.1 * c.max_reverse_distance + c.recover_distance:
            self._fail(
                tick.now,
                FailureReason.REVERSE_LIMIT,
                f"reversed {reversed_by:.2f} m in one leg (max_reverse_distance {c.max_reverse_distance:g} m)",
            )
            return 0.0, 0.0
        if tick.rear_range is not None:
            speed = abs(tick.odom.linear)
            stopping = c.rear_safety_distance + speed * c.stop_lead + speed * speed / (2.0 * c.linear_accel)
            if tick.rear_range < stopping:
                if self._blocked_since is None:
                    self._blocked_since = tick.now
                    self.log.append((tick.now, f"{self.state.value}: obstacle {tick.rear_range:.2f} m behind; waiting"))
                elif tick.now - self._blocked_since > c.blocked_timeout:
                    self._fail(
                        tick.now,
                        FailureReason.OBSTACLE_BEHIND,
                        f"obstacle {tick.rear_range:.2f} m behind for {c.blocked_timeout:g} s while reversing",
                    )
                return 0.0, 0.0
        self._blocked_since = None
        return v, w

    def measurement_covariance(self, observation: Observation) -> NDArray[np.float64]:
        """The frame's own covariance when it has a usable one, else the method's defaults at its pose."""
        assert observation.pose is not None
        cov = observation.covariance
        if cov is not None:
            cov = np.asarray(cov, dtype=np.float64)
            if cov.shape == (3, 3) and np.all(np.isfinite(cov)) and _positive_definite(cov):
                return cov
        return self.config.measurement.covariance(observation.pose, observation.markers)

    def _limit(self, v: float, w: float) -> tuple[float, float]:
        """Speed and acceleration limits, and the minimum speed a real base still moves at."""
        c, dt = self.config, self.config.control_period
        v = float(np.clip(v, -min(self.max_speed, c.max_reverse_speed), self.max_speed))
        w = float(np.clip(w, -self.max_turn, self.max_turn))
        pv, pw = self.command
        want_v, want_w = v, w
        v = float(np.clip(v, pv - c.linear_accel * dt, pv + c.linear_accel * dt))
        w = float(np.clip(w, pw - c.angular_accel * dt, pw + c.angular_accel * dt))
        # Below the minimum a base does not move: round up when asked to move, down to zero when asked to stop.
        if abs(v) < c.min_speed:
            v = math.copysign(c.min_speed, want_v) if want_v != 0.0 else 0.0
        if v == 0.0 and abs(w) < c.min_turn_rate:
            w = math.copysign(c.min_turn_rate, want_w) if want_w != 0.0 else 0.0
        return v, w

    def _stopped(self, odom: Odometry) -> bool:
        return abs(odom.linear) < self.config.settle_speed and abs(odom.angular) < 5 * self.config.settle_speed

    # --- the states: one handler each, in the order a mission meets them ----------------------------

    def _on_acquire(self, tick: _Tick) -> tuple[float, float]:
        """``ACQUIRE``: stand while the first frames arrive, then turn on the spot until a frame gives the dock."""
        c = self.config
        assert self.start_time is not None
        if self.track.mean is not None:
            self._enter(tick.now, State.CALCULATE, "markers in view")
            self.track.reset()
            return (0.0, 0.0)
        wait = c.first_frame_wait if self.recoveries == 0 else c.reacquire_wait
        if tick.now - self.state_since < wait:
            return (0.0, 0.0)  # the first frames are still on their way, or whatever hid the dock may move
        if not c.acquire:
            return self._fail(tick.now, FailureReason.NOT_IN_VIEW, "no markers in view (acquire is off)")
        if self.turned >= math.radians(c.acquire_max_turn_deg):
            return self._fail(tick.now, FailureReason.NOT_FOUND, "no markers in view after a full turn")
        self.turned += abs(tick.odom.angular) * c.control_period
        return (0.0, c.acquire_turn_rate)

    def _on_calculate(self, tick: _Tick) -> tuple[float, float]:
        """``CALCULATE``: stand still, take the median of a few frames, and plan (or centre the dock first)."""
        c = self.config
        now, odom = tick.now, tick.odom
        # Stand still, then take the median of a few frames: motion blur, latency and a wild frame stay
        # out of the plan. (A base whose odometry never reads still is taken as still after settle_timeout.)
        if not self._stopped(odom) and now - self.state_since < c.settle_timeout:
            self.calc_samples.clear()
            return (0.0, 0.0)
        n = len(self.calc_samples)
        if n >= c.calculate_frames or (now - self.state_since > c.calculate_timeout and n > 0):
            x = float(np.median([e.x for _, e, _ in self.calc_samples]))
            y = float(np.median([e.y for _, e, _ in self.calc_samples]))
            bearing = math.atan2(y, x)
            # Fewer than three markers: the heading of a lone, small marker can flip sign (the planar pose
            # ambiguity); turn to face the dock so that all three are in view, then calculate again.
            if (
                not self.centered
                and float(np.median(self.calc_markers)) < 3
                and abs(bearing) > math.radians(c.center_tolerance_deg)
            ):
                self.center_heading = wrap_angle(odom.pose.theta + bearing)
                self.heading_before_center = odom.pose.theta
                self._enter(now, State.CENTER, f"fewer than three markers; turning {math.degrees(bearing):+.1f} deg")
                return (0.0, 0.0)
            self.track.seed(self.calc_samples)
            return self._plan(now, odom.pose)
        if now - self.state_since > c.calculate_timeout:
            self.turned = 0.0
            self._enter(now, State.ACQUIRE, "markers lost while calculating")
        return (0.0, 0.0)

    def _on_center(self, tick: _Tick) -> tuple[float, float]:
        """``CENTER``: turn to face the dock, then calculate again."""
        done, w = self._turn_to(self.center_heading, tick.odom)
        if done:
            self._enter(tick.now, State.CALCULATE, "dock centred")
        return (0.0, w)

    def _on_moving1_back(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING1_BACK``: back out straight along the heading the robot calculated from."""
        assert self._back_target is not None
        v, w, arrived = self._drive_to(self._back_target, tick.odom.pose, reverse=True)
        if arrived:
            self._enter(tick.now, State.MOVING1_TURN)
            return (0.0, 0.0)
        return (v, w)

    def _on_moving1_turn(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING1_TURN``: turn to the heading of the straight leg to Point A."""
        self._refine(tick.odom.pose, aim=True)
        done, w = self._turn_to(self._targets.drive_heading, tick.odom)
        if done:
            self._enter(tick.now, State.MOVING1_DRIVE)
        return (0.0, w)

    def _on_moving1_drive(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING1_DRIVE``: drive straight to Point A, backwards when the plan says so."""
        self._refine(tick.odom.pose)
        v, w, arrived = self._drive_to(self._targets.a, tick.odom.pose, self._targets.reverse)
        if arrived:
            self._enter(tick.now, State.MOVING2)
            return (0.0, 0.0)
        return (v, w)

    def _on_moving2(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING2``: turn to face the charger square, then start the approach."""
        self._refine(tick.odom.pose)
        done, w = self._turn_to(self._targets.final_heading, tick.odom)
        if done:
            self.checked = False
            self.last_seen = max(self.last_seen, tick.now)  # the lost-markers clock starts when Moving₃ does
            self._enter(tick.now, State.MOVING3)
        return (0.0, w)

    def _on_moving3(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING3``: straight at the face under P-control on the lateral and heading errors."""
        c = self.config
        now, odom = tick.now, tick.odom
        robot = self.track.robot_in_dock(odom.pose)
        gap = -robot.x - self.robot.front_offset
        lateral, heading = robot.y, robot.theta
        if gap > self.blind and now - self.last_seen > c.lost_timeout:
            why = f"markers lost for {now - self.last_seen:.1f} s during the approach"
            if self.retries >= c.max_retries:
                return self._fail(now, FailureReason.MARKERS_LOST, why)
            self.retries += 1
            self.recoveries += 1
            self._back_target = odom.pose.compose(Pose2D(-c.recover_distance, 0.0, 0.0))
            self._enter(now, State.RECOVER, f"retry {self.retries}: {why}; backing off {c.recover_distance:g} m")
            return (0.0, 0.0)
        # A re-seat drives on past where the estimate puts the face (the face is solid, the springs give).
        push = c.reseat_push * self.reseats
        if tick.contact or gap <= abs(odom.linear) * c.stop_lead - push:
            if self.impact_speed is None:
                self.impact_speed = abs(odom.linear)
            self._enter(now, State.SETTLE, "contact" if tick.contact else "at the face by the estimate")
            return (0.0, 0.0)
        # Heading reference that closes the lateral error, faded out near the face so the robot arrives square.
        fade = min(1.0, max(0.0, (gap - 0.5 * c.heading_only_gap) / (0.5 * c.heading_only_gap)))
        ref = -math.atan(c.k_lateral * lateral) * fade
        ref = float(np.clip(ref, -math.radians(c.max_correction_deg), math.radians(c.max_correction_deg)))
        if not self.checked and gap <= c.checkpoint_gap:
            # The end of the early part: too far off the axis, or not following the reference, to finish well.
            self.checked = True
            off = abs(lateral) > c.retry_lateral or abs(wrap_angle(heading - ref)) > math.radians(c.retry_heading_deg)
            if off and self.retries < c.max_retries:
                return self._retry(now, f"lateral {lateral * 100:+.1f} cm, heading {math.degrees(heading):+.1f} deg")
        w = c.k_heading * wrap_angle(ref - heading)
        v = min(c.approach_speed, math.sqrt(2 * c.linear_accel * 0.5 * max(gap - c.creep_distance, 0.0)) + c.min_speed)
        if gap <= c.creep_distance:
            v = c.min_speed
        return v, w

    def _on_recover(self, tick: _Tick) -> tuple[float, float]:
        """``RECOVER``: back off straight, then look again (Calculate, which re-acquires if nothing comes)."""
        assert self._back_target is not None
        v, w, arrived = self._drive_to(self._back_target, tick.odom.pose, reverse=True)
        if arrived:
            self.track.reset()
            self._enter(tick.now, State.CALCULATE, "backed off; looking again")
            return (0.0, 0.0)
        return (v, w)

    def _on_settle(self, tick: _Tick) -> tuple[float, float]:
        """``SETTLE``: stand still at the face, then judge the final pose."""
        if not self._stopped(tick.odom) and tick.now - self.state_since < self.config.settle_timeout:
            return (0.0, 0.0)
        return self._judge(tick.now, tick.odom.pose, tick.charging)

    def _on_charge_wait(self, tick: _Tick) -> tuple[float, float]:
        """``CHARGE_WAIT``: stand on the contacts until the charger reports charging; re-seat if it does not."""
        c = self.config
        if tick.charging:
            self.charging = True
            self._enter(tick.now, State.DOCKED, "charging")
            return (0.0, 0.0)
        if tick.now - self.state_since < c.charge_timeout:
            return (0.0, 0.0)
        self.charging = False
        if self.reseats >= c.max_reseats:
            return self._fail(
                tick.now,
                FailureReason.NOT_CHARGING,
                f"no charging {c.charge_timeout:g} s after touching the contacts, after {self.reseats} re-seats",
            )
        self.reseats += 1
        self._back_target = tick.odom.pose.compose(Pose2D(-c.reseat_distance, 0.0, 0.0))
        self._enter(tick.now, State.RESEAT, f"re-seat {self.reseats}: not charging")
        return (0.0, 0.0)

    def _on_reseat(self, tick: _Tick) -> tuple[float, float]:
        """``RESEAT``: back off a few centimetres, then drive in again under Moving₃'s control."""
        assert self._back_target is not None
        v, w, arrived = self._drive_to(self._back_target, tick.odom.pose, reverse=True)
        if arrived:
            self.checked = True  # no checkpoint this close
            self.last_seen = max(self.last_seen, tick.now)
            self._enter(tick.now, State.MOVING3, "driving in again")
            return (0.0, 0.0)
        return (v, w)

    def _on_undock(self, tick: _Tick) -> tuple[float, float]:
        """``UNDOCK``: back out straight from the face to the staging pose, Point A."""
        if self._back_target is None:
            distance = self.config.planner.standoff
            if distance > self.config.max_reverse_distance:
                return self._fail(
                    tick.now,
                    FailureReason.REVERSE_LIMIT,
                    f"the staging pose is {distance:g} m back, more than max_reverse_distance "
                    f"{self.config.max_reverse_distance:g} m",
                )
            self._back_target = tick.odom.pose.compose(Pose2D(-distance, 0.0, 0.0))
        v, w, arrived = self._drive_to(self._back_target, tick.odom.pose, reverse=True)
        if arrived:
            self._enter(tick.now, State.UNDOCKED, "at the staging pose")
            return (0.0, 0.0)
        return (v, w)

    def _on_back_off(self, tick: _Tick) -> tuple[float, float]:
        """``BACK_OFF``: reverse straight to Point A, then calculate afresh."""
        v, w, arrived = self._drive_to(self._targets.a, tick.odom.pose, reverse=True)
        if arrived:
            self._enter(tick.now, State.CALCULATE, "back at Point A")
            self.track.reset()
            return (0.0, 0.0)
        return (v, w)

    def _on_final(self, _tick: _Tick) -> tuple[float, float]:
        """``DOCKED`` and ``FAILED``: stand still (``step`` stops before it asks, this keeps the table whole)."""
        return (0.0, 0.0)

    # --- what the handlers share ----------------------------------------------------------------

    def _plan(self, now: float, pose: Pose2D) -> tuple[float, float]:
        """Calculate: the robot's pose in the dock frame, its case, Point A and the targets in odometry."""
        assert self.track.mean is not None
        robot = self.track.robot_in_dock(pose)
        if self.config.planner.kind == "papers" and self.centered and self.heading_before_center is not None:
            # The papers' Point A lies on the heading the robot had when it calculated; a centring turn (ours,
            # for a lone marker's ambiguity) is undone by Moving₁'s turn back to that heading.
            robot = Pose2D(robot.x, robot.y, wrap_angle(robot.theta + self.heading_before_center - pose.theta))
        m = plan_for(robot, self.config.planner, self.robot.front_offset)
        longest = max(m.back_out, m.drive_distance if m.reverse else 0.0)
        if longest > self.config.max_reverse_distance:
            return self._fail(
                now,
                FailureReason.REVERSE_LIMIT,
                f"case {m.case} would reverse {longest:.2f} m in one leg "
                f"(max_reverse_distance {self.config.max_reverse_distance:g} m)",
            )
        dock = self.track.mean
        self.manoeuvre = m
        if self.case is None:
            self.case = m.case
        self._targets = _Targets(
            a=dock.compose(m.point_a),
            drive_heading=wrap_angle(dock.theta + m.drive_heading),
            final_heading=wrap_angle(dock.theta + m.point_a.theta),
            reverse=m.reverse,
        )
        note = (
            f"case {m.case}; robot at ({robot.x:+.3f}, {robot.y:+.3f}) m, {math.degrees(robot.theta):+.1f} deg in the "
            f"dock frame; {m.planner} plan: "
            + (f"back out {m.back_out:.3f} m, " if m.back_out > 0 else "")
            + f"turn {math.degrees(m.first_turn):+.1f} deg, {'reverse' if m.reverse else 'drive'} "
            f"{m.drive_distance:.3f} m to A, turn {math.degrees(m.second_turn):+.1f} deg"
        )
        if m.back_out > 0.0:
            self._back_target = pose.compose(Pose2D(-m.back_out, 0.0, 0.0))
            self._enter(now, State.MOVING1_BACK, note)
        else:
            self._enter(now, State.MOVING1_TURN, note)
        return (0.0, 0.0)

    def _refine(self, pose: Pose2D, *, aim: bool = False) -> None:
        """Moving₁ and Moving₂ follow the dock filter, which frames that see the dock keep refining: Point A and the
        last turn move with it; with ``aim`` (before the leg), monodock's and the turn-first plan's leg heading is
        aimed at the refined A again (the papers' leg keeps its heading: Moving₁ has no turn)."""
        m, dock = self.manoeuvre, self.track.mean
        if not self.config.refine_while_moving or m is None or dock is None:
            return
        a = dock.compose(m.point_a)
        self._targets.a = a
        self._targets.final_heading = wrap_angle(dock.theta + m.point_a.theta)
        if aim and m.planner != "papers" and pose.distance(a) > self.config.arrive_tolerance:
            heading = math.atan2(a.y - pose.y, a.x - pose.x)
            self._targets.drive_heading = wrap_angle(heading + (math.pi if m.reverse else 0.0))

    def _turn_to(self, heading: float, odom: Odometry) -> tuple[bool, float]:
        """Turn in place towards ``heading`` (odometry frame): (there and still, turn rate)."""
        c = self.config
        err = wrap_angle(heading - odom.pose.theta)
        if abs(err) < math.radians(c.turn_tolerance_deg):
            return abs(odom.angular) < 0.05, 0.0
        # Decelerate so as to stop on the target: w <= sqrt(2 a |err|).
        w = min(c.k_turn * abs(err), math.sqrt(2 * c.angular_accel * abs(err)), self.max_turn)
        return False, math.copysign(max(w, c.min_turn_rate), err)

    def _drive_to(self, target: Pose2D, pose: Pose2D, reverse: bool) -> tuple[float, float, bool]:
        """Drive straight at ``target`` (forwards or backwards), steering on the bearing; True on arrival."""
        c = self.config
        dx, dy = target.x - pose.x, target.y - pose.y
        heading = pose.theta + (math.pi if reverse else 0.0)
        along = dx * math.cos(heading) + dy * math.sin(heading)
        if along <= c.arrive_tolerance:
            return 0.0, 0.0, True
        bearing = wrap_angle(math.atan2(dy, dx) - heading)
        speed = min(self.max_speed, math.sqrt(2 * c.linear_accel * along), 2.0 * along + c.min_speed)
        # Steer only while there is room; the last centimetres hold the heading.
        w = c.k_bearing * bearing if along > 0.05 else 0.0
        return (-speed if reverse else speed), w, False

    def _retry(self, now: float, why: str) -> tuple[float, float]:
        """Start a retry: ``BACK_OFF`` to Point A, placed again from the filter's current dock pose."""
        assert self.track.mean is not None
        assert self._last_odom is not None
        self.retries += 1
        a = self.track.mean.compose(point_a(self.config.planner, self.robot.front_offset))
        here, limit = self._last_odom, self.config.max_reverse_distance
        if here.distance(a) > limit:  # no farther than a reverse leg may go: Calculate works from anywhere
            w = limit / here.distance(a)
            a = Pose2D(here.x + w * (a.x - here.x), here.y + w * (a.y - here.y), a.theta)
        self._targets.a = a
        self._enter(now, State.BACK_OFF, f"retry {self.retries}: {why}")
        return (0.0, 0.0)

    def _judge(self, now: float, pose: Pose2D, charging: bool | None = None) -> tuple[float, float]:
        """At the face: docked when charging, or when the robot's own estimate of its pose is inside the
        tolerances (then, if it can tell, it waits for the charger to confirm)."""
        c = self.config
        robot = self.track.robot_in_dock(pose)
        gap = -robot.x - self.robot.front_offset
        ok = (
            abs(robot.y) <= c.tolerance_lateral
            and abs(gap) <= c.tolerance_longitudinal
            and abs(robot.theta) <= math.radians(c.tolerance_heading_deg)
        )
        summary = (
            f"lateral {robot.y * 100:+.1f} cm, gap {gap * 100:+.1f} cm, heading {math.degrees(robot.theta):+.1f} deg"
        )
        if charging:
            self.charging = True
            self._enter(now, State.DOCKED, "charging; " + summary)
        elif ok and charging is None:
            self._enter(now, State.DOCKED, summary)
        elif ok:
            self._enter(now, State.CHARGE_WAIT, summary)
        elif self.retries < c.max_retries:
            self._retry(now, "final pose outside the tolerances: " + summary)
        else:
            self._fail(now, FailureReason.OUTSIDE_TOLERANCES, "final pose outside the tolerances: " + summary)
        return (0.0, 0.0)

    def estimated_final(self) -> Pose2D | None:
        if self.track.mean is None or self._last_odom is None:
            return None
        return self.track.robot_in_dock(self._last_odom)


def run_mission(
    robot: RobotInterface,
    perceive: Perceive,
    mission: DockingMission,
    *,
    on_tick: Callable[[DockingMission, Odometry], None] | None = None,
) -> MissionResult:
    """Drive the mission to its end on ``robot``: read, decide, command, wait one control period."""
    last_stamp = -math.inf
    start = robot.now()
    while not mission.finished:
        odom = robot.odometry()
        observation = None
        if mission.wants_frames:
            frame = robot.latest_frame()
            if frame is not None and frame.stamp > last_stamp:
                last_stamp = frame.stamp
                observation = perceive(frame.stamp, frame.image)
        v, w = mission.step(
            robot.now(), odom, observation, robot.contact(), charging=robot.charging(), rear_range=robot.rear_range()
        )
        robot.send_velocity(v, w)
        if on_tick is not None:
            on_tick(mission, odom)
        if not mission.finished:
            robot.sleep(mission.config.control_period)
    robot.send_velocity(0.0, 0.0)
    return MissionResult(
        state=mission.state,
        failure=mission.failure,
        reason=mission.reason,
        case=mission.case,
        retries=mission.retries,
        duration=robot.now() - start,
        estimated_final=mission.estimated_final(),
        impact_speed=mission.impact_speed,
        log=list(mission.log),
        reseats=mission.reseats,
        charging=mission.charging,
        recoveries=mission.recoveries,
    )
