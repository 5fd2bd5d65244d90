"""The far approach and the search (issue 28 item 3): from beyond the manoeuvre's range, or far off the dock's axis,
the mission makes for the staging point on the axis in legs, then hands over to Calculate; the ways it fails.

The missions run the simulated base with the true dock pose as the "camera" (``TruthfulRobot``): the state
machine's steering and hand-over against where the robot really is. The camera-in-the-loop far starts are in
tests/evaluation/test_dock_sim_room.py (slow).
"""

from __future__ import annotations

import math

import pytest

from monodock.core import settings
from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.projection import blind_gap
from monodock.dock import DockingConfig, DockingMission, State, run_mission
from monodock.dock.far_approach import beyond_manoeuvre, leg_end, off_axis, staging_point
from monodock.dock.pose_filter import MeasurementNoise
from monodock.dock.states import FailureReason
from monodock.errors import ConfigError
from shared import TruthfulRobot, truthful_robot


def _mission(robot: TruthfulRobot, **config: object) -> DockingMission:
    sim = robot.sim
    cfg = settings.replace(DockingConfig(measurement=MeasurementNoise.for_method("board")), **config)
    return DockingMission(cfg, sim.robot, blind_gap(sim.camera, sim.layout, sim.robot))


def _states(log: list[tuple[float, str]]) -> list[str]:
    return [entry.split(":")[0] for _, entry in log]


# --- the geometry ------------------------------------------------------------------------------------------


def test_the_papers_envelope_stays_with_the_manoeuvre_and_the_room_beyond_it_does_not() -> None:
    c = DockingConfig()
    # dock-sim's per-case starts: 1.0-2.5 m before the face, up to 1 m off the axis: never the far approach.
    for x in (-1.0, -1.7, -2.5):
        for y in (-1.0, 0.0, 0.6, 1.0):
            assert not beyond_manoeuvre(Pose2D(x, y, 0.3), c), (x, y)
    assert beyond_manoeuvre(Pose2D(-4.5, 0.0, 0.0), c)  # too far
    assert beyond_manoeuvre(Pose2D(-0.8, 1.2, 0.0), c)  # 56 degrees off the axis
    assert off_axis(Pose2D(-1.0, -1.0, 2.0)) == pytest.approx(math.radians(45))
    assert not settings.replace(DockingConfig(), far_approach=False).far.far_approach


def test_staging_point_is_on_the_dock_axis_and_legs_are_bounded() -> None:
    c = settings.replace(DockingConfig(), staging_distance=1.5)
    dock = Pose2D(3.0, 1.0, math.radians(30))  # the dock in odometry
    stage = staging_point(dock, c)
    in_dock = dock.inverse().compose(stage)
    assert in_dock.x == pytest.approx(-1.5)
    assert in_dock.y == pytest.approx(0.0, abs=1e-12)
    here = Pose2D(0.0, 0.0, 0.0)
    end = leg_end(here, stage, 0.5)
    assert here.distance(end) == pytest.approx(0.5)
    # on the straight line to the stage
    assert math.atan2(end.y, end.x) == pytest.approx(math.atan2(stage.y, stage.x))
    assert leg_end(here, stage, 10.0) == stage
    assert leg_end(here, stage, -1.0).distance(here) == pytest.approx(0.0)


def test_far_approach_keys_are_checked() -> None:
    with pytest.raises(ConfigError, match="staging_distance"):
        settings.replace(DockingConfig(), staging_distance=3.0, far_distance=2.8)
    with pytest.raises(ConfigError, match="far_leg"):
        settings.replace(DockingConfig(), far_leg=0.0)
    with pytest.raises(ConfigError, match="far_bearing_deg"):
        settings.replace(DockingConfig(), far_bearing_deg=120.0)
    with pytest.raises(ConfigError, match="far_max_legs"):
        settings.replace(DockingConfig(), far_max_legs=0)


# --- the mission, against the simulator's truth ------------------------------------------------------------


def test_far_start_off_the_axis_makes_for_the_staging_point_then_docks() -> None:
    """4.5 m out and 45 degrees off the axis, facing the dock: legs to the staging point, the dock back in view
    after each, then the manoeuvre; docked square at the face by the truth."""
    b = math.radians(45)
    start = Pose2D(-4.5 * math.cos(b), 4.5 * math.sin(b), -b)
    robot = truthful_robot(start)
    result = run_mission(robot, robot.perceive_truth, _mission(robot))
    states = _states(result.log)
    assert State.FAR_APPROACH.value in states
    assert result.state is State.DOCKED, result.log
    # The hand-over: the first plan comes from within the manoeuvre's range, by the truth at that moment.
    handover = next(t for t, e in result.log if e.startswith(("moving1-back", "moving1-turn")))
    at = min(robot.truth, key=lambda s: abs(s.t - handover)).pose
    assert not beyond_manoeuvre(at, DockingConfig())
    assert robot.front_gap() < 0.02
    assert abs(robot.pose.y) < 0.01
    assert abs(math.degrees(robot.pose.theta)) < 1.5


def test_dock_behind_the_robot_is_searched_for_then_approached() -> None:
    """4 m out, 30 degrees off the axis, the dock straight behind: it turns on the spot until the dock is in view,
    then approaches from afar and docks (truth)."""
    b = math.radians(30)
    start = Pose2D(-4.0 * math.cos(b), -4.0 * math.sin(b), wrap_angle(math.pi - b))
    robot = truthful_robot(start)
    assert not robot.perceive_truth(0.0, robot.render(0.0, start)).pose  # nothing in view at the start
    result = run_mission(robot, robot.perceive_truth, _mission(robot, acquire_turn_rate=0.6))
    states = _states(result.log)
    assert states[:3] == [State.ACQUIRE.value, State.CALCULATE.value, State.FAR_APPROACH.value]
    assert result.state is State.DOCKED, result.log
    assert robot.front_gap() < 0.02
    assert abs(robot.pose.y) < 0.01


def test_dock_lost_on_the_far_approach_and_not_found_again_fails_with_904() -> None:
    """Seen at the start, then never again: the search turns once and gives up with DOCK_LOST (Nav2 904), still."""
    robot = truthful_robot(Pose2D(-4.5, 0.3, 0.0))
    robot.hide_markers = lambda stamp, _pose: stamp > 3.0
    result = run_mission(robot, robot.perceive_truth, _mission(robot, acquire_turn_rate=0.8))
    assert result.state is State.FAILED, result.log
    assert result.failure is FailureReason.DOCK_LOST
    assert result.failure.nav2_error_code == 904
    assert State.FAR_APPROACH.value in _states(result.log)
    robot.sleep(0.5)
    assert abs(robot.odometry().angular) < 1e-3
    assert abs(robot.odometry().linear) < 1e-3


def test_far_approach_out_of_legs_fails_with_905() -> None:
    """One short leg allowed from 4.5 m: still beyond the manoeuvre after it, APPROACH_STALLED (Nav2 905)."""
    robot = truthful_robot(Pose2D(-4.5, 0.0, 0.0))
    result = run_mission(robot, robot.perceive_truth, _mission(robot, far_leg=0.3, far_max_legs=1))
    assert result.failure is FailureReason.APPROACH_STALLED, result.log
    assert result.failure.nav2_error_code == 905
    # it drove its one leg (by the truth), no more
    assert robot.pose.x - (-4.5) == pytest.approx(0.3, abs=0.03)


def test_far_approach_off_plans_from_afar_as_before() -> None:
    """With the far approach off, the manoeuvre plans straight from 4.5 m, as the papers' mission did."""
    robot = truthful_robot(Pose2D(-4.5, 0.3, 0.0))
    mission = _mission(robot, far_approach=False, mission_timeout=15.0)
    result = run_mission(robot, robot.perceive_truth, mission)
    assert State.FAR_APPROACH.value not in _states(result.log)
    assert any(e.startswith(("moving1-turn", "moving1-back")) for _, e in result.log)
