"""dock-sim's fault table: each fault a small class that says when its moment has come (judged from the simulator's
truth and the mission's state) and what it does to the simulated robot then. ``FAULT_TYPES`` is the lookup table
by the names ``--faults`` takes; ``FaultInjector`` springs one fault, once, during a run."""

from __future__ import annotations

import math
from typing import ClassVar

from monodock.core.pose2d import Pose2D
from monodock.dock.controller import DockingMission
from monodock.dock.states import State
from monodock.sim.diffdrive import SimulatedRobot
from monodock.sim.faults import Obstacle

__all__ = ["FAULTS", "FAULT_TYPES", "Fault", "FaultInjector"]


class Fault:
    """A fault of the table: ``due`` says whether its moment has come this tick; ``spring`` does it (once).

    The nominal run (``none``) is this base class: its moment never comes.
    """

    name: ClassVar[str] = "none"
    description: ClassVar[str] = "nothing goes wrong"

    def due(self, mission: DockingMission, robot: SimulatedRobot) -> bool:  # noqa: ARG002 - the interface
        """Whether the fault springs now (checked every control tick until it has)."""
        return False

    def spring(self, robot: SimulatedRobot, t: float) -> None:
        """Do it to the robot at time ``t``."""


class _OnApproach(Fault):
    """A fault of the camera's frames during Moving₃, when the front edge comes within ``gap`` of the face."""

    gap: ClassVar[float]

    def due(self, mission: DockingMission, robot: SimulatedRobot) -> bool:
        return mission.state is State.MOVING3 and robot.front_gap() < self.gap


class Occlusion(_OnApproach):
    name, gap = "occlusion", 0.7
    description = "a passer-by hides the markers for 2.5 s when the front edge is 0.7 m from the face"

    def spring(self, robot: SimulatedRobot, t: float) -> None:
        robot.hide_markers = lambda stamp, _pose: t <= stamp < t + 2.5


class FrameDrops(_OnApproach):
    name, gap = "frame-drops", 0.8
    description = "no frame arrives for 1.5 s when the front edge is 0.8 m from the face"

    def spring(self, robot: SimulatedRobot, t: float) -> None:
        robot.drop_frames(t, t + 1.5)


class LatencySpike(_OnApproach):
    name, gap = "latency-spike", 0.8
    description = "frames exposed over 1 s arrive 0.4 s late, from 0.8 m before the face"

    def spring(self, robot: SimulatedRobot, t: float) -> None:
        robot.delay_frames(t, t + 1.0, 0.4)


class _IntoTheDrive(Fault):
    """A fault of the wheels 0.5 s into Moving₁'s drive to Point A."""

    def __init__(self) -> None:
        self.drive_started: float | None = None

    def due(self, mission: DockingMission, robot: SimulatedRobot) -> bool:
        if mission.state is not State.MOVING1_DRIVE:
            return False
        t = robot.now()
        if self.drive_started is None:
            self.drive_started = t
        return t - self.drive_started >= 0.5


class OdometryJump(_IntoTheDrive):
    name = "odometry-jump"
    description = "the odometry jumps 5 cm sideways and 3° 0.5 s into the drive to Point A"

    def spring(self, robot: SimulatedRobot, t: float) -> None:  # noqa: ARG002 - a jump takes no time
        robot.jump_odometry(0.0, 0.05, math.radians(3.0))


class WheelSlip(_IntoTheDrive):
    name = "wheel-slip"
    description = "the left wheel slips to 60 % of its speed for 1 s, 0.5 s into the drive to Point A"

    def spring(self, robot: SimulatedRobot, t: float) -> None:
        robot.slip_wheel("left", 0.6, t, t + 1.0)


class PersonBehind(Fault):
    name = "person-behind"
    description = "someone steps 0.5 m behind the robot as soon as it starts to reverse, for 4 s"

    def due(self, mission: DockingMission, robot: SimulatedRobot) -> bool:  # noqa: ARG002 - whatever the gap
        if mission.state in (State.MOVING1_BACK, State.BACK_OFF, State.RECOVER, State.RESEAT):
            return True
        m = mission.manoeuvre
        return mission.state is State.MOVING1_DRIVE and m is not None and m.reverse

    def spring(self, robot: SimulatedRobot, t: float) -> None:
        behind = robot.pose.compose(Pose2D(-(robot.config.rear_offset + 0.5 + 0.2), 0.0, 0.0))
        robot.obstacles.append(Obstacle(behind.x, behind.y, 0.2, appear=t, vanish=t + 4.0))


# The fault table, by the names ``DockSimConfig.faults`` and ``--faults`` take, in the order the report lists them.
FAULT_TYPES: dict[str, type[Fault]] = {
    f.name: f for f in (Fault, Occlusion, FrameDrops, LatencySpike, OdometryJump, WheelSlip, PersonBehind)
}
# Each fault's one line for the report's table.
FAULTS = {name: f.description for name, f in FAULT_TYPES.items()}


class FaultInjector:
    """Springs the run's fault on the simulated robot at its moment, once."""

    def __init__(self, fault: str, robot: SimulatedRobot) -> None:
        self.fault, self.robot = FAULT_TYPES[fault](), robot
        self.triggered = False

    def tick(self, mission: DockingMission) -> None:
        """After each control tick: spring the fault if its moment has come."""
        if not self.triggered and self.fault.due(mission, self.robot):
            self.triggered = True
            self.fault.spring(self.robot, self.robot.now())
