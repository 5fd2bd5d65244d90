"""The papers' planner as written: Point A on the heading line, no turn before Moving₁, Θab at A."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose2d import Pose2D
from monodock.dock.planner import PlannerConfig, plan, plan_papers

FRONT = 0.2  # base_link to the robot's front edge, metres


def _arrive(start: Pose2D, distance: float, reverse: bool) -> tuple[float, float]:
    sign = -1.0 if reverse else 1.0
    return start.x + sign * distance * math.cos(start.theta), start.y + sign * distance * math.sin(start.theta)


@pytest.mark.parametrize(
    "start",
    [
        Pose2D(-2.2, 0.5, math.radians(-20)),  # left of the axis, heading across it ahead: forward to A
        Pose2D(-1.4, -0.3, math.radians(25)),  # right of the axis, crossing ahead
        Pose2D(-1.2, 0.3, math.radians(25)),  # heading away from the axis: A is behind, reverse to it
    ],
)
def test_point_a_is_on_the_heading_line_and_moving1_has_no_turn(start: Pose2D) -> None:
    config = PlannerConfig()
    m = plan_papers(start, config, FRONT)
    assert m.first_turn == 0.0
    assert m.point_a.y == 0.0
    assert m.point_a.theta == 0.0
    # Driving straight along the heading for the planned distance lands exactly on A.
    np.testing.assert_allclose(_arrive(start, m.drive_distance, m.reverse), (m.point_a.x, m.point_a.y), atol=1e-12)
    # Moving₂ turns by Θab: from the heading to square-on.
    assert m.second_turn == pytest.approx(-start.theta)
    floor = -(m.point_a.x + FRONT)
    assert config.papers_min_standoff <= floor <= config.papers_max_standoff
    assert m.reverse == (start.y * math.sin(start.theta) > 0)  # heading away from the axis: A is behind


@pytest.mark.parametrize(
    "start",
    [
        Pose2D(-1.8, 0.4, 0.0),  # parallel to the axis: no crossing
        Pose2D(-0.7, 0.3, math.radians(-60)),  # crosses 0.33 m of floor before the face: too near
        Pose2D(-1.6, 0.02, math.radians(-1)),  # crosses far beyond the charger
    ],
)
def test_without_a_usable_crossing_it_turns_first_as_fig15(start: Pose2D) -> None:
    config = PlannerConfig()
    m = plan_papers(start, config, FRONT)
    assert m == plan(start, config, FRONT)
    assert m.point_a.x == pytest.approx(-(config.standoff + FRONT))
