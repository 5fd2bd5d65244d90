"""The control law alone, against a unicycle integrated here: each law, closed through the command limits, must
bring the robot where the law promises (turned onto a heading, at a point, square on the face's axis), within the
config's tolerances, and the limits must hold on every step. Nav2's opennav_docking tests its controller.cpp so."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.dock import control_law as law
from monodock.dock.config import DockingConfig
from monodock.dock.interface import Odometry

C = DockingConfig()
MAX_SPEED, MAX_TURN = C.limits.cruise_speed, C.limits.turn_rate


class Unicycle:
    """A base that does what it is told one control period later (the command's latency) and integrates exactly."""

    def __init__(self, pose: Pose2D) -> None:
        self.pose, self.v, self.w, self.t = pose, 0.0, 0.0, 0.0
        self.sent = (0.0, 0.0)

    def odometry(self) -> Odometry:
        return Odometry(self.t, self.pose, self.v, self.w)

    def command(self, v: float, w: float) -> tuple[float, float]:
        """Limit the desired command as the mission does, check the limits held, and move one period."""
        before = self.sent
        v, w = law.limit_command(v, w, before, C, MAX_SPEED, MAX_TURN)
        dt = C.limits.control_period
        assert -C.reverse.max_reverse_speed - 1e-12 <= v <= MAX_SPEED + 1e-12
        assert abs(w) <= MAX_TURN + 1e-12
        # The acceleration limits hold, except for the step up to the minimum speed a base moves at and the step
        # down to zero from below it (a base does not move that slowly).
        dv, dw = C.limits.linear_accel * dt, C.limits.angular_accel * dt
        crawl_v, crawl_w = (
            abs(before[0]) <= C.limits.min_speed + dv + 1e-12,
            abs(before[1]) <= C.limits.min_turn_rate + dw + 1e-12,
        )
        assert abs(v - before[0]) <= dv + 1e-12 or abs(v) == C.limits.min_speed or (v == 0.0 and crawl_v)
        assert abs(w - before[1]) <= dw + 1e-12 or abs(w) == C.limits.min_turn_rate or (w == 0.0 and crawl_w)
        self.sent = (v, w)
        self.v, self.w = v, w
        th = self.pose.theta
        if abs(w) < 1e-12:
            dx, dy = v * dt * math.cos(th), v * dt * math.sin(th)
        else:
            dx = v / w * (math.sin(th + w * dt) - math.sin(th))
            dy = -v / w * (math.cos(th + w * dt) - math.cos(th))
        self.pose = Pose2D(self.pose.x + dx, self.pose.y + dy, wrap_angle(th + w * dt))
        self.t += dt
        return v, w


@pytest.mark.parametrize("turn_deg", [-170.0, -45.0, -2.0, 0.5, 10.0, 90.0, 179.0])
def test_turn_in_place_stops_on_the_heading(turn_deg: float) -> None:
    """From standing, the turn ends (there and still) within the turn tolerance, never beyond it by more than the
    tolerance (no overshoot past the heading), with the robot not moving forwards."""
    robot = Unicycle(Pose2D(0.3, -0.2, 0.4))
    target = wrap_angle(0.4 + math.radians(turn_deg))
    for _ in range(2000):
        done, w = law.turn_in_place(target, robot.odometry(), C, MAX_TURN)
        if done:
            break
        robot.command(0.0, w)
        assert robot.v == 0.0
    else:
        pytest.fail("the turn never ended")
    assert abs(wrap_angle(robot.pose.theta - target)) < math.radians(C.approach.turn_tolerance_deg)
    assert (robot.pose.x, robot.pose.y) == (0.3, -0.2)


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("target", [(1.0, 0.0), (0.8, 0.12), (0.5, -0.05), (0.02, 0.0)])
def test_drive_straight_arrives(target: tuple[float, float], reverse: bool) -> None:
    """Facing the target (or facing away, reversing), the robot arrives within the arrive tolerance plus what one
    control period at the minimum speed carries it, and steers onto a point slightly off its heading."""
    x, y = target
    sign = -1.0 if reverse else 1.0
    goal = Pose2D(sign * x, sign * y, 0.0)
    robot = Unicycle(Pose2D(0.0, 0.0, 0.0))
    for _ in range(5000):
        v, w, arrived = law.drive_straight(goal, robot.pose, reverse, C, MAX_SPEED)
        if arrived:
            break
        assert (v < 0) == reverse
        robot.command(v, w)
    else:
        pytest.fail("never arrived")
    miss = math.hypot(robot.pose.x - goal.x, robot.pose.y - goal.y)
    assert miss < C.approach.arrive_tolerance + C.limits.min_speed * C.limits.control_period + 0.01 * math.hypot(x, y)


def test_drive_straight_says_arrived_when_the_target_is_behind() -> None:
    """A target behind the way of travel (overshot, or a zero-length leg) counts as arrived: never a U-turn."""
    v, w, arrived = law.drive_straight(Pose2D(-0.2, 0.0, 0.0), Pose2D(0.0, 0.0, 0.0), False, C, MAX_SPEED)
    assert arrived
    assert (v, w) == (0.0, 0.0)


def test_heading_reference_closes_the_lateral_error_and_fades_near_the_face() -> None:
    """The reference turns towards the axis (against the lateral error), is bounded, and is zero once the gap is
    below half of heading_only_gap (the robot arrives square)."""
    far = 1.0
    assert law.heading_reference(0.05, far, C) < 0.0 < law.heading_reference(-0.05, far, C)
    assert law.heading_reference(0.0, far, C) == 0.0
    bound = math.radians(C.approach.max_correction_deg)
    assert abs(law.heading_reference(5.0, far, C)) == pytest.approx(bound)
    assert law.heading_reference(0.05, 0.5 * C.approach.heading_only_gap, C) == 0.0
    assert abs(law.heading_reference(0.05, 0.75 * C.approach.heading_only_gap, C)) < abs(
        law.heading_reference(0.05, far, C)
    )


@pytest.mark.parametrize(("lateral", "heading_deg"), [(0.0, 0.0), (0.04, 0.0), (-0.03, 4.0), (0.015, -6.0)])
def test_moving3_brings_the_robot_square_onto_the_axis(lateral: float, heading_deg: float) -> None:
    """Moving₃'s law, closed on the true pose (a perfect estimate) from 1 m out: the front edge meets the face
    within the papers' 2 cm / 3° of the axis, at no more than the creep speed."""
    front = 0.2  # base_link to the front edge
    # The robot in the dock frame, as the mission measures it: the face at x = 0, the robot at x < 0 facing +x.
    robot = Unicycle(Pose2D(-(1.0 + front), lateral, math.radians(heading_deg)))
    for _ in range(10000):
        gap = -robot.pose.x - front
        if gap <= 0.0:
            break
        ref = law.heading_reference(robot.pose.y, gap, C)
        v, w = law.approach_command(robot.pose.theta, ref, gap, C)
        assert v > 0.0
        robot.command(v, w)
    else:
        pytest.fail("never reached the face")
    assert abs(robot.pose.y) < 0.02
    assert abs(math.degrees(robot.pose.theta)) < 3.0
    assert robot.v <= C.limits.min_speed + 1e-12


@pytest.mark.parametrize("speed", [0.02, 0.05, 0.1])
def test_reverse_stopping_distance_is_enough_to_stop_short(speed: float) -> None:
    """Reversing at ``speed``, a stop commanded when the room behind falls below the stopping distance, executed one
    period late (the latency) under the acceleration limit, ends at least rear_safety_distance short."""
    room = law.reverse_stopping_distance(speed, C) - 1e-9
    robot = Unicycle(Pose2D(0.0, 0.0, 0.0))
    robot.sent = (-speed, 0.0)
    robot.v = -speed
    travelled = 0.0
    latency = int(math.ceil(C.limits.stop_lead / C.limits.control_period))
    for _ in range(latency):  # the command in flight still reverses
        before = robot.pose.x
        robot.command(-speed, 0.0)
        travelled += before - robot.pose.x
    for _ in range(1000):
        before = robot.pose.x
        robot.command(0.0, 0.0)
        travelled += before - robot.pose.x
        if robot.v == 0.0:
            break
    assert room - travelled >= C.reverse.rear_safety_distance - 1e-3


def test_limit_command_never_steps_beyond_the_accelerations() -> None:
    """Random desired commands: every limited one is within the speed limits, within one period's acceleration of
    the last, rounded up to the minimum speed when asked to move, and zero when asked to stop from a crawl."""
    rng = np.random.default_rng(3)
    robot = Unicycle(Pose2D(0.0, 0.0, 0.0))
    for _ in range(3000):
        v, w = rng.uniform(-0.5, 0.5), rng.uniform(-2.0, 2.0)
        sent_v, _ = robot.command(v, w)  # Unicycle.command asserts the limits
        if v != 0.0:
            assert abs(sent_v) >= C.limits.min_speed
    assert law.limit_command(0.0, 0.0, (0.01, 0.0), C, MAX_SPEED, MAX_TURN) == (0.0, 0.0)


def test_is_still_reads_the_settle_speed() -> None:
    still = Odometry(0.0, Pose2D(0.0, 0.0, 0.0), 0.5 * C.settle.settle_speed, 2 * C.settle.settle_speed)
    moving = Odometry(0.0, Pose2D(0.0, 0.0, 0.0), 2 * C.settle.settle_speed, 0.0)
    turning = Odometry(0.0, Pose2D(0.0, 0.0, 0.0), 0.0, 6 * C.settle.settle_speed)
    assert law.is_still(still, C)
    assert not law.is_still(moving, C)
    assert not law.is_still(turning, C)
