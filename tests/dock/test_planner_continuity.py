"""monodock's planner has no boundary at which the plan jumps: starts a centimetre apart get plans a centimetre apart.

The sweep covers the starts dock-sim draws from (1–2.5 m from the face, up to 1 m off the axis) with headings up
to 40° either way (wider than dock-sim's 30°: the dock must be in the camera's view to plan at all). Neighbouring
starts 1 cm or 0.5° apart must give plans whose distances (back-out, leg, Point A) differ by at most 3 cm and
whose turns differ by at most 5°. The old turn-first plan fails this at the Point A boundary (the issue's
example: a 59° right turn and 0.80 m forward against a 119° left turn and 0.80 m in reverse).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose2d import Pose2D
from monodock.dock.planner import Manoeuvre, PlannerConfig, plan, plan_monodock

FRONT = 0.34
STEPS = ((0.01, 0.0, 0.0), (0.0, 0.01, 0.0), (0.0, 0.0, math.radians(0.5)))


def _parts(m: Manoeuvre) -> tuple[np.ndarray, np.ndarray]:
    lengths = np.array([m.back_out, -m.drive_distance if m.reverse else m.drive_distance, m.point_a.x, m.point_a.y])
    turns = np.degrees([m.first_turn, m.second_turn])
    return lengths, turns


def _largest_jump(planner, xs, ys, headings) -> tuple[float, float, tuple[float, float, float]]:  # type: ignore[no-untyped-def]
    worst_len = worst_turn = 0.0
    where = (0.0, 0.0, 0.0)
    for x in xs:
        for y in ys:
            for th in headings:
                a = _parts(planner(Pose2D(x, y, th), PlannerConfig(), FRONT))
                for dx, dy, dth in STEPS:
                    b = _parts(planner(Pose2D(x + dx, y + dy, th + dth), PlannerConfig(), FRONT))
                    d_len = float(np.max(np.abs(a[0] - b[0])))
                    d_turn = float(np.max(np.abs(a[1] - b[1])))
                    if d_turn > worst_turn or d_len > worst_len:
                        where = (x, y, math.degrees(th))
                    worst_len, worst_turn = max(worst_len, d_len), max(worst_turn, d_turn)
    return worst_len, worst_turn, where


def test_neighbouring_starts_get_neighbouring_plans() -> None:
    xs = np.arange(-2.5, -0.9, 0.02)
    ys = np.arange(-1.0, 1.0, 0.05)
    headings = np.radians(np.arange(-40.0, 40.1, 5.0))
    worst_len, worst_turn, where = _largest_jump(plan_monodock, xs, ys, headings)
    assert worst_len <= 0.03, f"a 1 cm / 0.5° step moved a distance by {worst_len * 100:.1f} cm at {where}"
    assert worst_turn <= 5.0, f"a 1 cm / 0.5° step changed a turn by {worst_turn:.1f}° at {where}"


def test_the_turn_first_plan_jumps_where_the_issue_found_it() -> None:
    """The sweep is sharp enough to catch the jump it exists for."""
    worst_len, worst_turn, _ = _largest_jump(plan, np.arange(-1.40, -1.28, 0.01), [0.8], [math.radians(-30)])
    assert worst_turn > 90.0
    assert worst_len > 1.0


@pytest.mark.parametrize("start", [(-1.35, 0.8, -30.0), (-1.33, 0.8, -30.0)])
def test_the_issues_two_starts_plan_alike_and_reach_point_a(start: tuple[float, float, float]) -> None:
    robot = Pose2D(start[0], start[1], math.radians(start[2]))
    m = plan_monodock(robot, PlannerConfig(), FRONT)
    other = plan_monodock(Pose2D(-1.34, 0.8, math.radians(-30.0)), PlannerConfig(), FRONT)
    assert abs(m.back_out - other.back_out) < 0.05
    assert abs(m.first_turn - other.first_turn) < math.radians(2)
    # Follow the plan: back out along the heading, turn, drive forward, turn; the robot is at A facing the dock.
    x = robot.x - m.back_out * math.cos(robot.theta)
    y = robot.y - m.back_out * math.sin(robot.theta)
    heading = robot.theta + m.first_turn
    x, y = x + m.drive_distance * math.cos(heading), y + m.drive_distance * math.sin(heading)
    assert not m.reverse
    assert math.hypot(x - m.point_a.x, y - m.point_a.y) < 1e-9
    assert abs(math.remainder(heading + m.second_turn, 2 * math.pi)) < 1e-9
    # The leg meets the axis no steeper than allowed.
    assert abs(math.degrees(heading)) <= PlannerConfig().max_leg_angle_deg + 1e-9
