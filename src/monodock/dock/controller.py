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

The parts: the states and failure reasons (``dock.states``), the control law as pure functions
(``dock.control_law``), what the mission knows of the dock (``dock.tracking.DockTrack``: frames placed by the
odometry, the filter), the gains (``dock.config.DockingConfig``), the far approach's geometry (``dock.far_approach``)
and each state's data (``dock.phases``). This module sequences them; ``dock.run.run_mission`` runs a mission on a
robot.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig
from monodock.dock.extensions import ArucoChargingDock, ControlLaw, Dock, PControlLaw
from monodock.dock.far_approach import beyond_manoeuvre, leg_end, off_axis
from monodock.dock.interface import Odometry
from monodock.dock.phases import (
    _P,
    _Acquiring,
    _Approaching,
    _Calculating,
    _Centring,
    _FarLeg,
    _Phase,
    _Reversing,
    _Undocking,
)
from monodock.dock.planner import Manoeuvre, plan_for, point_a
from monodock.dock.states import FailureReason, State
from monodock.dock.tracking import DockTrack, Observation
from monodock.errors import ConfigError

__all__ = ["DockingMission"]


@dataclass
class _Targets:
    """Moving₁ and Moving₂'s goals in the odometry frame, set at Calculate (refined while moving)."""

    a: Pose2D
    drive_heading: float
    final_heading: float
    reverse: bool


@dataclass
class _ReverseLeg:
    """The reverse guard's watch over the current reverse leg: where it began, and since when the rear range has
    stopped it (None while clear)."""

    start: Pose2D
    blocked_since: float | None = None


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
    desired command and moves to the next state with ``_enter`` (with the next state's data, ``phase``) or
    ``_fail``. The control law is ``law`` (``dock.control_law``'s by default), the dock's model ``dock`` (monodock's
    ArUco charger by default: ``dock.extensions``); what the mission knows of the dock's pose is ``track``.
    """

    def __init__(
        self,
        config: DockingConfig,
        robot: RobotConfig,
        blind: float,
        *,
        task: str = "dock",
        dock: Dock | None = None,
        law: ControlLaw | None = None,
    ) -> None:
        if task not in ("dock", "undock"):
            raise ConfigError(f"a docking mission's task is dock or undock, got {task!r}")
        self.task = task
        self.config = config
        self.robot = robot
        self.dock: Dock = ArucoChargingDock(config, robot.front_offset) if dock is None else dock  # docks onto
        self.law: ControlLaw = PControlLaw(config) if law is None else law  # drives by
        self.blind = blind + config.watch.blind_margin
        self.max_speed = min(config.limits.cruise_speed, robot.max_linear_speed)
        self.max_turn = min(config.limits.turn_rate, robot.max_angular_speed)
        self.track = DockTrack(
            config.track, config.measurement, config.charging_offset.dock_T_target(robot.front_offset)
        )
        self.state = State.ACQUIRE
        self.phase: _Phase = _Acquiring()
        self.failure: FailureReason | None = None
        self.reason = ""
        self.case: int | None = None
        self.manoeuvre: Manoeuvre | None = None
        self.retries = 0
        self.recoveries = 0
        self.reseats = 0
        self.obstacle_waits = 0
        self.far_legs = 0  # legs of the far approach so far
        self.seen_dock = False  # whether any frame has given the dock's pose (a later search that fails: DOCK_LOST)
        self.charging: bool | None = None
        self.log: list[tuple[float, str]] = []
        self.command = (0.0, 0.0)
        self.start_time: float | None = None
        self.state_since = 0.0
        self.last_seen = -math.inf
        self.impact_speed: float | None = None
        self._targets = _Targets(Pose2D(0.0, 0.0, 0.0), 0.0, 0.0, False)
        self._reverse: _ReverseLeg | None = None
        self._handlers: dict[State, _Handler] = {
            State.ACQUIRE: self._on_acquire,
            State.CENTER: self._on_center,
            State.CALCULATE: self._on_calculate,
            State.FAR_APPROACH: self._on_far_approach,
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
        if self.state in (State.ACQUIRE, State.CALCULATE, State.FAR_APPROACH, State.MOVING3, State.SETTLE):
            return True
        return self.config.approach.refine_while_moving and self.state in _MOVING_TO_A

    def _enter(self, now: float, state: State, note: str = "", phase: _Phase = None) -> None:
        """Move to ``state`` with its data (``ACQUIRE``, ``CALCULATE`` and ``UNDOCK`` start from empty data)."""
        if phase is None and state is State.ACQUIRE:
            phase = _Acquiring()
        elif phase is None and state is State.CALCULATE:
            phase = _Calculating()
        elif phase is None and state is State.UNDOCK:
            phase = _Undocking()
        self.state, self.state_since, self.phase = state, now, phase
        self.log.append((now, state.value + (f": {note}" if note else "")))

    def _data(self, kind: type[_P]) -> _P:
        """The current state's data, which must be of ``kind`` (a handler's own state)."""
        assert isinstance(self.phase, kind), f"{self.state.value} holds {type(self.phase).__name__}"
        return self.phase

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
        self.track.move(odom)
        placed = None if observation is None else self.track.place(observation)
        if observation is not None and placed is not None:
            at, seen, cov = placed
            self.seen_dock = True
            if isinstance(self.phase, _Calculating):
                self.phase.samples.append((at, seen, cov))  # the median comes at the plan
                self.phase.markers.append(observation.markers)
                self.last_seen = observation.stamp
            elif self.track.update(at, seen, cov):
                self.last_seen = observation.stamp
        if self.finished:
            return (0.0, 0.0)
        if now - self.start_time > self.config.watch.mission_timeout:
            return self._fail(
                now, FailureReason.TIMEOUT, f"mission took longer than {self.config.watch.mission_timeout:.0f} s"
            )
        tick = _Tick(now, odom, contact, charging, rear_range)
        v, w = self._handlers[self.state](tick)
        if not self.finished:
            v, w = self._guard_reverse(tick, v, w)
        if self.finished:
            return (0.0, 0.0)
        self.command = self.law.limit_command(v, w, self.command, self.max_speed, self.max_turn)
        return self.command

    def _guard_reverse(self, tick: _Tick, v: float, w: float) -> tuple[float, float]:
        """Reversing made safe: every reverse leg bounded in length; stop short of anything the rear range sees."""
        c = self.config
        if not (v < 0.0 or tick.odom.linear < -c.settle.settle_speed):
            self._reverse = None
            return v, w
        if self._reverse is None:
            self._reverse = _ReverseLeg(tick.odom.pose)
        leg = self._reverse
        reversed_by = leg.start.distance(tick.odom.pose)
        # Every leg is planned within max_reverse_distance; the guard allows a tenth more for steering on odometry
        # and for a stop that follows one reverse leg straight with another (a recovery after a back-off).
        if reversed_by > 1.1 * c.reverse.max_reverse_distance + c.retry.recover_distance:
            self._fail(
                tick.now,
                FailureReason.REVERSE_LIMIT,
                f"reversed {reversed_by:.2f} m in one leg (max_reverse_distance {c.reverse.max_reverse_distance:g} m)",
            )
            return 0.0, 0.0
        if tick.rear_range is not None and tick.rear_range < self.law.reverse_stopping_distance(abs(tick.odom.linear)):
            if leg.blocked_since is None:
                leg.blocked_since = tick.now
                self.obstacle_waits += 1
                self.log.append((tick.now, f"{self.state.value}: obstacle {tick.rear_range:.2f} m behind; waiting"))
            elif tick.now - leg.blocked_since > c.reverse.blocked_timeout:
                self._fail(
                    tick.now,
                    FailureReason.OBSTACLE_BEHIND,
                    f"obstacle {tick.rear_range:.2f} m behind for {c.reverse.blocked_timeout:g} s while reversing",
                )
            return 0.0, 0.0
        leg.blocked_since = None
        return v, w

    # --- the states: one handler each, in the order a mission meets them ----------------------------

    def _on_acquire(self, tick: _Tick) -> tuple[float, float]:
        """``ACQUIRE``: stand while the first frames arrive, then turn on the spot until a frame gives the dock."""
        c, looking = self.config, self._data(_Acquiring)
        if self.dock.refined_pose(self.track) is not None:
            self._enter(tick.now, State.CALCULATE, "markers in view")
            self.track.reset()
            return (0.0, 0.0)
        wait = c.search.first_frame_wait if self.recoveries == 0 else c.search.reacquire_wait
        if tick.now - self.state_since < wait:
            return (0.0, 0.0)  # the first frames are still on their way, or whatever hid the dock may move
        if not c.search.acquire:
            return self._fail(tick.now, FailureReason.NOT_IN_VIEW, "no markers in view (acquire is off)")
        if looking.turned >= math.radians(c.search.acquire_max_turn_deg):
            if self.seen_dock:
                return self._fail(tick.now, FailureReason.DOCK_LOST, "dock lost; not in view again after a full turn")
            return self._fail(tick.now, FailureReason.NOT_FOUND, "no markers in view after a full turn")
        looking.turned += abs(tick.odom.angular) * c.limits.control_period
        return (0.0, c.search.acquire_turn_rate)

    def _on_calculate(self, tick: _Tick) -> tuple[float, float]:
        """``CALCULATE``: stand still, take the median of a few frames, and plan (or centre the dock first)."""
        c, calc = self.config, self._data(_Calculating)
        now, odom = tick.now, tick.odom
        # Stand still, then take the median of a few frames: motion blur, latency and a wild frame stay
        # out of the plan. (A base whose odometry never reads still is taken as still after settle_timeout.)
        if not self.law.is_still(odom) and now - self.state_since < c.settle.settle_timeout:
            calc.samples.clear()
            return (0.0, 0.0)
        n = len(calc.samples)
        if n >= c.search.calculate_frames or (now - self.state_since > c.settle.calculate_timeout and n > 0):
            x = float(np.median([e.x for _, e, _ in calc.samples]))
            y = float(np.median([e.y for _, e, _ in calc.samples]))
            bearing = math.atan2(y, x)
            if c.far.far_approach:
                self.track.seed(calc.samples)
                robot = self.track.robot_in_dock(odom.pose)
                if beyond_manoeuvre(robot, c):
                    return self._start_far_leg(now, robot)
            # Fewer than three markers: the heading of a lone, small marker can flip sign (the planar pose
            # ambiguity); turn to face the dock so that all three are in view, then calculate again.
            if (
                calc.heading_before_center is None
                and float(np.median(calc.markers)) < 3
                and abs(bearing) > math.radians(c.search.center_tolerance_deg)
            ):
                turn = _Centring(wrap_angle(odom.pose.theta + bearing), odom.pose.theta)
                note = f"fewer than three markers; turning {math.degrees(bearing):+.1f} deg"
                self._enter(now, State.CENTER, note, turn)
                return (0.0, 0.0)
            self.track.seed(calc.samples)
            return self._plan(now, odom.pose, calc.heading_before_center)
        if now - self.state_since > c.settle.calculate_timeout:
            self._enter(now, State.ACQUIRE, "markers lost while calculating")
        return (0.0, 0.0)

    def _on_center(self, tick: _Tick) -> tuple[float, float]:
        """``CENTER``: turn to face the dock, then calculate again."""
        turn = self._data(_Centring)
        done, w = self.law.turn_in_place(turn.heading, tick.odom, self.max_turn)
        if done:
            self._enter(
                tick.now, State.CALCULATE, "dock centred", _Calculating(heading_before_center=turn.heading_before)
            )
        return (0.0, w)

    def _start_far_leg(self, now: float, robot: Pose2D) -> tuple[float, float]:
        """From Calculate: another leg of the far approach, or ``APPROACH_STALLED`` when the legs are used up."""
        c = self.config
        where = (
            f"{math.hypot(robot.x, robot.y):.2f} m from the face, {math.degrees(off_axis(robot)):.0f} deg off its axis"
        )
        if self.far_legs >= c.far.far_max_legs:
            return self._fail(now, FailureReason.APPROACH_STALLED, f"still {where} after {self.far_legs} far legs")
        self.far_legs += 1
        self._enter(now, State.FAR_APPROACH, f"leg {self.far_legs}: {where}", _FarLeg())
        return (0.0, 0.0)

    def _on_far_approach(self, tick: _Tick) -> tuple[float, float]:
        """``FAR_APPROACH``: one leg towards the staging point on the dock's axis, then face the dock again."""
        leg, c, pose = self._data(_FarLeg), self.config, tick.odom.pose
        dock = self.dock.refined_pose(self.track)
        assert dock is not None
        stage = self.dock.staging_pose(dock)
        if leg.step == "turn":
            if pose.distance(stage) < 0.05:
                leg.step = "face"
            else:
                done, w = self.law.turn_in_place(
                    math.atan2(stage.y - pose.y, stage.x - pose.x), tick.odom, self.max_turn
                )
                if not done:
                    return (0.0, w)
                leg.step, leg.origin = "drive", pose
        if leg.step == "drive":
            assert leg.origin is not None
            target = leg_end(pose, stage, c.far.far_leg - leg.origin.distance(pose))
            v, w, arrived = self.law.drive_straight(target, pose, False, self.max_speed)
            if not arrived:
                return (v, w)
            leg.step = "face"
        done, w = self.law.turn_in_place(math.atan2(dock.y - pose.y, dock.x - pose.x), tick.odom, self.max_turn)
        if done:
            self._enter(tick.now, State.CALCULATE, "facing the dock")
        return (0.0, w)

    def _on_moving1_back(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING1_BACK``: back out straight along the heading the robot calculated from."""
        command = self._reverse_leg(tick)
        if command is None:
            self._enter(tick.now, State.MOVING1_TURN)
            return (0.0, 0.0)
        return command

    def _on_moving1_turn(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING1_TURN``: turn to the heading of the straight leg to Point A."""
        self._refine(tick.odom.pose, aim=True)
        done, w = self.law.turn_in_place(self._targets.drive_heading, tick.odom, self.max_turn)
        if done:
            self._enter(tick.now, State.MOVING1_DRIVE)
        return (0.0, w)

    def _on_moving1_drive(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING1_DRIVE``: drive straight to Point A, backwards when the plan says so."""
        self._refine(tick.odom.pose)
        t = self._targets
        v, w, arrived = self.law.drive_straight(t.a, tick.odom.pose, t.reverse, self.max_speed)
        if arrived:
            self._enter(tick.now, State.MOVING2)
            return (0.0, 0.0)
        return (v, w)

    def _on_moving2(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING2``: turn to face the charger square, then start the approach."""
        self._refine(tick.odom.pose)
        done, w = self.law.turn_in_place(self._targets.final_heading, tick.odom, self.max_turn)
        if done:
            self.last_seen = max(self.last_seen, tick.now)  # the lost-markers clock starts when Moving₃ does
            self._enter(tick.now, State.MOVING3, phase=_Approaching(checked=False))
        return (0.0, w)

    def _on_moving3(self, tick: _Tick) -> tuple[float, float]:
        """``MOVING3``: straight at the face under P-control on the lateral and heading errors."""
        c, approach = self.config, self._data(_Approaching)
        now, odom = tick.now, tick.odom
        robot = self.track.robot_in_dock(odom.pose)
        gap = -robot.x - self.robot.front_offset
        lateral, heading = robot.y, robot.theta
        if gap > self.blind and now - self.last_seen > c.watch.lost_timeout:
            why = f"markers lost for {now - self.last_seen:.1f} s during the approach"
            if self.retries >= c.retry.max_retries:
                return self._fail(now, FailureReason.MARKERS_LOST, why)
            self.retries += 1
            self.recoveries += 1
            back = _Reversing(odom.pose.compose(Pose2D(-c.retry.recover_distance, 0.0, 0.0)))
            self._enter(
                now, State.RECOVER, f"retry {self.retries}: {why}; backing off {c.retry.recover_distance:g} m", back
            )
            return (0.0, 0.0)
        # A re-seat drives on past where the estimate puts the face (the face is solid, the springs give).
        push = c.charging.reseat_push * self.reseats
        if tick.contact or gap <= abs(odom.linear) * c.limits.stop_lead - push:
            if self.impact_speed is None:
                self.impact_speed = abs(odom.linear)
            self._enter(now, State.SETTLE, "contact" if tick.contact else "at the face by the estimate")
            return (0.0, 0.0)
        ref = self.law.heading_reference(lateral, gap)
        if not approach.checked and gap <= c.retry.checkpoint_gap:
            # The end of the early part: too far off the axis, or not following the reference, to finish well.
            approach.checked = True
            off = abs(lateral) > c.retry.retry_lateral or abs(wrap_angle(heading - ref)) > math.radians(
                c.retry.retry_heading_deg
            )
            if off and self.retries < c.retry.max_retries:
                return self._retry(now, f"lateral {lateral * 100:+.1f} cm, heading {math.degrees(heading):+.1f} deg")
        return self.law.approach_command(heading, ref, gap)

    def _on_recover(self, tick: _Tick) -> tuple[float, float]:
        """``RECOVER``: back off straight, then look again (Calculate, which re-acquires if nothing comes)."""
        command = self._reverse_leg(tick)
        if command is None:
            self.track.reset()
            self._enter(tick.now, State.CALCULATE, "backed off; looking again")
            return (0.0, 0.0)
        return command

    def _on_settle(self, tick: _Tick) -> tuple[float, float]:
        """``SETTLE``: stand still at the face, then judge the final pose."""
        if not self.law.is_still(tick.odom) and tick.now - self.state_since < self.config.settle.settle_timeout:
            return (0.0, 0.0)
        return self._judge(tick.now, tick.odom.pose, tick.charging)

    def _on_charge_wait(self, tick: _Tick) -> tuple[float, float]:
        """``CHARGE_WAIT``: stand on the contacts until the charger reports charging; re-seat if it does not."""
        c = self.config
        if tick.charging:
            self.charging = True
            self._enter(tick.now, State.DOCKED, "charging")
            return (0.0, 0.0)
        if tick.now - self.state_since < c.charging.charge_timeout:
            return (0.0, 0.0)
        self.charging = False
        if self.reseats >= c.charging.max_reseats:
            return self._fail(
                tick.now,
                FailureReason.NOT_CHARGING,
                f"no charging {c.charging.charge_timeout:g} s after touching the contacts, "
                f"after {self.reseats} re-seats",
            )
        self.reseats += 1
        back = _Reversing(tick.odom.pose.compose(Pose2D(-c.charging.reseat_distance, 0.0, 0.0)))
        self._enter(tick.now, State.RESEAT, f"re-seat {self.reseats}: not charging", back)
        return (0.0, 0.0)

    def _on_reseat(self, tick: _Tick) -> tuple[float, float]:
        """``RESEAT``: back off a few centimetres, then drive in again under Moving₃'s control."""
        command = self._reverse_leg(tick)
        if command is None:
            self.last_seen = max(self.last_seen, tick.now)
            self._enter(tick.now, State.MOVING3, "driving in again", _Approaching(checked=True))  # none this close
            return (0.0, 0.0)
        return command

    def _on_undock(self, tick: _Tick) -> tuple[float, float]:
        """``UNDOCK``: back out straight from the face to the staging pose, Point A."""
        leg = self._data(_Undocking)
        if leg.target is None:
            distance = self.config.planner.standoff
            if distance > self.config.reverse.max_reverse_distance:
                return self._fail(
                    tick.now,
                    FailureReason.REVERSE_LIMIT,
                    f"the staging pose is {distance:g} m back, more than max_reverse_distance "
                    f"{self.config.reverse.max_reverse_distance:g} m",
                )
            leg.target = tick.odom.pose.compose(Pose2D(-distance, 0.0, 0.0))
        v, w, arrived = self.law.drive_straight(leg.target, tick.odom.pose, True, self.max_speed)
        if arrived:
            self._enter(tick.now, State.UNDOCKED, "at the staging pose")
            return (0.0, 0.0)
        return (v, w)

    def _on_back_off(self, tick: _Tick) -> tuple[float, float]:
        """``BACK_OFF``: reverse straight to Point A, then calculate afresh."""
        command = self._reverse_leg(tick)
        if command is None:
            self._enter(tick.now, State.CALCULATE, "back at Point A")
            self.track.reset()
            return (0.0, 0.0)
        return command

    def _on_final(self, _tick: _Tick) -> tuple[float, float]:
        """``DOCKED`` and ``FAILED``: stand still (``step`` stops before it asks, this keeps the table whole)."""
        return (0.0, 0.0)

    # --- what the handlers share ----------------------------------------------------------------

    def _plan(self, now: float, pose: Pose2D, heading_before_center: float | None) -> tuple[float, float]:
        """Calculate: the robot's pose in the dock frame, its case, Point A and the targets in odometry."""
        assert self.track.mean is not None
        robot = self.track.robot_in_dock(pose)
        if self.config.planner.kind == "papers" and heading_before_center is not None:
            # The papers' Point A lies on the heading the robot had when it calculated; a centring turn (ours,
            # for a lone marker's ambiguity) is undone by Moving₁'s turn back to that heading.
            robot = Pose2D(robot.x, robot.y, wrap_angle(robot.theta + heading_before_center - pose.theta))
        m = plan_for(robot, self.config.planner, self.robot.front_offset)
        longest = max(m.back_out, m.drive_distance if m.reverse else 0.0)
        if longest > self.config.reverse.max_reverse_distance:
            return self._fail(
                now,
                FailureReason.REVERSE_LIMIT,
                f"case {m.case} would reverse {longest:.2f} m in one leg "
                f"(max_reverse_distance {self.config.reverse.max_reverse_distance:g} m)",
            )
        dock = self.dock.refined_pose(self.track)
        assert dock is not None
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
            self._enter(now, State.MOVING1_BACK, note, _Reversing(pose.compose(Pose2D(-m.back_out, 0.0, 0.0))))
        else:
            self._enter(now, State.MOVING1_TURN, note)
        return (0.0, 0.0)

    def _reverse_leg(self, tick: _Tick) -> tuple[float, float] | None:
        """A straight reverse leg to the state's ``_Reversing`` target: the command, or None on arrival."""
        target = self._data(_Reversing).target
        v, w, arrived = self.law.drive_straight(target, tick.odom.pose, True, self.max_speed)
        return None if arrived else (v, w)

    def _refine(self, pose: Pose2D, *, aim: bool = False) -> None:
        """Moving₁ and Moving₂ follow the dock filter, which frames that see the dock keep refining: Point A and the
        last turn move with it; with ``aim`` (before the leg), monodock's and the turn-first plan's leg heading is
        aimed at the refined A again (the papers' leg keeps its heading: Moving₁ has no turn)."""
        m, dock = self.manoeuvre, self.dock.refined_pose(self.track)
        if not self.config.approach.refine_while_moving or m is None or dock is None:
            return
        a = dock.compose(m.point_a)
        self._targets.a = a
        self._targets.final_heading = wrap_angle(dock.theta + m.point_a.theta)
        if aim and m.planner != "papers" and pose.distance(a) > self.config.approach.arrive_tolerance:
            heading = math.atan2(a.y - pose.y, a.x - pose.x)
            self._targets.drive_heading = wrap_angle(heading + (math.pi if m.reverse else 0.0))

    def _retry(self, now: float, why: str) -> tuple[float, float]:
        """Start a retry: ``BACK_OFF`` to Point A, placed again from the filter's current dock pose."""
        dock, here = self.dock.refined_pose(self.track), self.track.last_pose
        assert dock is not None
        assert here is not None
        self.retries += 1
        a = dock.compose(point_a(self.config.planner, self.robot.front_offset))
        limit = self.config.reverse.max_reverse_distance
        if here.distance(a) > limit:  # no farther than a reverse leg may go: Calculate works from anywhere
            w = limit / here.distance(a)
            a = Pose2D(here.x + w * (a.x - here.x), here.y + w * (a.y - here.y), a.theta)
        self._enter(now, State.BACK_OFF, f"retry {self.retries}: {why}", _Reversing(a))
        return (0.0, 0.0)

    def _judge(self, now: float, pose: Pose2D, charging: bool | None = None) -> tuple[float, float]:
        """At the face: docked when charging, or when the robot's own estimate of its pose is inside the
        tolerances (then, if it can tell, it waits for the charger to confirm)."""
        c = self.config
        robot = self.track.robot_in_dock(pose)
        gap = -robot.x - self.robot.front_offset
        ok = self.dock.is_docked(robot)
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
        elif self.retries < c.retry.max_retries:
            self._retry(now, "final pose outside the tolerances: " + summary)
        else:
            self._fail(now, FailureReason.OUTSIDE_TOLERANCES, "final pose outside the tolerances: " + summary)
        return (0.0, 0.0)

    def estimated_final(self) -> Pose2D | None:
        if self.track.mean is None or self.track.last_pose is None:
            return None
        return self.track.robot_in_dock(self.track.last_pose)
