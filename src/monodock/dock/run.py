"""Running a docking mission on a robot: the loop (read, decide, command, wait one control period), and how the
mission ended (``MissionResult``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from monodock.core.pose2d import Pose2D
from monodock.dock.controller import DockingMission
from monodock.dock.interface import Odometry, RobotInterface
from monodock.dock.states import FailureReason, State
from monodock.dock.tracking import Perceive

__all__ = ["VERDICT_FIELDS", "MissionResult", "run_mission", "verdict"]

# How the mission ended by its own account: the mission, its MissionResult and a simulated trial's record
# (evaluation.dock_results.TrialResult) all carry these under the same names.
VERDICT_FIELDS = ("state", "failure", "reason", "retries", "reseats", "charging", "recoveries", "obstacle_waits")


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
    obstacle_waits: int = 0  # reverse legs stopped for something behind (until it cleared or the mission gave up)

    @property
    def docked(self) -> bool:
        return self.state is State.DOCKED

    @property
    def succeeded(self) -> bool:
        """Docked, or undocked for an undocking mission."""
        return self.state in (State.DOCKED, State.UNDOCKED)


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
            robot.now(),
            odom,
            observation,
            robot.contact(),
            charging=mission.dock.is_charging(robot),
            rear_range=robot.rear_range(),
        )
        robot.send_velocity(v, w)
        if on_tick is not None:
            on_tick(mission, odom)
        if not mission.finished:
            robot.sleep(mission.config.limits.control_period)
    robot.send_velocity(0.0, 0.0)
    return MissionResult(
        **verdict(mission),
        case=mission.case,
        duration=robot.now() - start,
        estimated_final=mission.estimated_final(),
        impact_speed=mission.impact_speed,
        log=list(mission.log),
    )


def verdict(source: DockingMission | MissionResult) -> dict[str, Any]:
    """The ``VERDICT_FIELDS`` of a mission or its result, as keywords for the record that carries them on."""
    return {name: getattr(source, name) for name in VERDICT_FIELDS}
