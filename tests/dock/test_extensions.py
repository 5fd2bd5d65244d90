"""The mission's extension points (``dock.extensions``): another ``Dock`` plugged into ``DockingMission`` changes
what the mission does, judged by the simulator's truth (the control law's test runs in dock-sim:
tests/evaluation/test_dock_sim_extensions.py).
"""

from __future__ import annotations

import math

from monodock.core.pose2d import Pose2D
from monodock.core.projection import blind_gap
from monodock.dock.config import DockingConfig
from monodock.dock.controller import DockingMission
from monodock.dock.extensions import ArucoChargingDock, Dock
from monodock.dock.interface import RobotInterface
from monodock.dock.pose_filter import MeasurementNoise
from monodock.dock.run import MissionResult, run_mission
from monodock.dock.states import State
from monodock.dock.tracking import DockTrack
from shared import TruthfulRobot, truthful_robot

START = Pose2D(-1.7, -0.2, math.radians(8))
CHARGE_DELAY = 1.5  # s: the simulated charger reports current this long after the contacts mate (< charge_timeout)


class _ChargesAtOnce:
    """A dock that reports charging whenever asked (a charger with no current sense, say); monodock's otherwise."""

    def __init__(self, inner: ArucoChargingDock) -> None:
        self.inner = inner
        self.asked = 0

    def staging_pose(self, dock: Pose2D) -> Pose2D:
        return self.inner.staging_pose(dock)

    def refined_pose(self, track: DockTrack) -> Pose2D | None:
        return self.inner.refined_pose(track)

    def is_docked(self, pose: Pose2D) -> bool:
        return self.inner.is_docked(pose)

    def is_charging(self, robot: RobotInterface) -> bool | None:  # noqa: ARG002 - it asks no sensor
        self.asked += 1
        return True


def _dock(robot: TruthfulRobot, dock: Dock | None) -> MissionResult:
    sim = robot.sim
    config = DockingConfig(measurement=MeasurementNoise.for_method("board"))
    mission = DockingMission(config, sim.robot, blind_gap(sim.camera, sim.layout, sim.robot), dock=dock)
    return run_mission(robot, robot.perceive_truth, mission)


def _states(result: MissionResult) -> list[str]:
    return [entry.split(":")[0] for _, entry in result.log]


def test_a_dock_that_charges_at_once_ends_docked_without_the_charge_wait() -> None:
    """With monodock's dock the robot stands on the contacts until the simulated charger's current comes (1.5 s);
    with a dock that says "charging" at once it ends docked as it reaches the face, inside the tolerances by the
    truth, before the charger's current has come."""
    default = truthful_robot(START, charge_delay=CHARGE_DELAY)
    waited = _dock(default, None)
    assert waited.state is State.DOCKED, waited.log
    assert "charge-wait" in _states(waited)
    assert default.charging() is True

    robot = truthful_robot(START, charge_delay=CHARGE_DELAY)
    sim = robot.sim
    dock = _ChargesAtOnce(ArucoChargingDock(DockingConfig(), sim.robot.front_offset))
    result = _dock(robot, dock)
    assert result.state is State.DOCKED, result.log
    assert result.charging is True
    assert dock.asked > 0
    assert "charge-wait" not in _states(result)
    assert result.duration < waited.duration
    assert robot.charging() is False  # the simulated charger has not yet sensed current: the dock's word ended it
    p = robot.pose  # the truth: on the face, straight
    assert abs(p.y) <= 0.02
    assert abs(robot.longitudinal_error()) <= 0.02
    assert abs(math.degrees(p.theta)) <= 3.0
