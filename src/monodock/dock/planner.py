"""The papers' eight docking cases, Point A, and the manoeuvre each planner makes of them.

Everything here lives in the ``dock`` frame (docs/architecture.md): x normal to the charger face and pointing into it,
y to the left, the face at x = 0. The robot approaches from x < 0 and is docked at (-front_offset, 0, 0).

The stand-off Point A is the base_link position on the approach axis (y = 0) that stands ``standoff`` metres of
floor in front of the face, measured from the robot's front edge, facing the charger: from there the last part is
a straight line. The papers choose one of eight cases (Sensors 2025, Fig. 15; conference paper, Fig. 13) without
spelling them out; we define them by three questions:

- side: is the robot left (y ≥ 0) or right (y < 0) of the approach axis, looking at the charger;
- heading: does its heading point towards the axis (it would cross it driving forward) or along or away from it;
- zone: does the manoeuvre drive forward to Point A ("before", cases 1–4) or backwards before Moving₂ ("past",
  cases 5–8). ``classify`` answers it for a start by where it lies (before or past the stand-off A: the start
  region); ``Manoeuvre.case`` by what the planner made of it (the case executed).

Three planners:

- ``plan_papers`` (``kind="papers"``), the papers as written: Point A where the heading line meets the axis,
  Moving₁ straight there (forward or in reverse) with no turn, Moving₂ the turn by Θab; where there is no usable
  crossing, Fig. 15's first turn (``plan``).
- ``plan`` (the papers' "turn-first" fallback): turn to face the stand-off A (or put one's back to it when past
  it), drive (or reverse) to it, turn square. It jumps at A's boundary.
- ``plan_monodock`` (``kind="monodock"``, the default): back out straight along the heading if the leg to the
  stand-off A would be too steep, turn to face A, drive forward, turn square; continuous in the start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.settings import setting
from monodock.errors import ConfigError

__all__ = [
    "CASES",
    "PLANNERS",
    "CaseSpec",
    "Manoeuvre",
    "PlannerConfig",
    "classify",
    "executed_case",
    "plan",
    "plan_for",
    "plan_monodock",
    "plan_papers",
    "point_a",
]


@dataclass(frozen=True)
class CaseSpec:
    """One of the eight cases: where the robot is and what it does about it."""

    number: int
    side: str  # "left" or "right" of the approach axis, looking at the charger
    heading: str  # "towards" or "away" (along or away from) the axis
    zone: str  # "before" (forward to Point A) or "past" (reversing before Moving₂; a start region past Point A)
    manoeuvre: str  # what the turn-first plan (``plan``) does, in words

    @property
    def title(self) -> str:
        how = "forward to Point A" if self.zone == "before" else "reversing (past Point A)"
        return f"Case {self.number}: {self.side} of the axis, heading {self.heading}, {how}"


def _spec(number: int, side: str, heading: str, zone: str) -> CaseSpec:
    other = "right" if side == "left" else "left"
    if zone == "before":
        first = (
            f"a short turn {other} (or back {side} if the heading already crosses the axis before A) to face A"
            if heading == "towards"
            else f"a long turn {other}, through square-on, to face A"
        )
        words = f"{first}; drive forward to A; turn {side} square to the face; straight approach"
    else:
        first = (
            f"a long turn {side}, through square-on, to put its back to A"
            if heading == "towards"
            else f"a short turn {side} (or {other} if already turned past it) to put its back to A"
        )
        words = f"{first}; reverse to A; turn {other} square to the face; straight approach"
    return CaseSpec(number, side, heading, zone, words)


CASES: dict[int, CaseSpec] = {
    1: _spec(1, "left", "towards", "before"),
    2: _spec(2, "right", "towards", "before"),
    3: _spec(3, "left", "away", "before"),
    4: _spec(4, "right", "away", "before"),
    5: _spec(5, "left", "towards", "past"),
    6: _spec(6, "right", "towards", "past"),
    7: _spec(7, "left", "away", "past"),
    8: _spec(8, "right", "away", "past"),
}


PLANNERS = ("monodock", "papers")


@dataclass(frozen=True)
class PlannerConfig:
    """Where Point A is.

    Attributes:
        kind: "monodock" (``plan_monodock``: Point A at the stand-off, reached continuously: back out straight if
            needed, turn to face A, drive forward) or "papers" (``plan_papers``: Point A on the heading line,
            Moving₁ straight with no turn).
        standoff: floor between the robot's front edge and the charger face at Point A, metres.
        arrive_tolerance: for ``plan`` (the papers' turn-first fallback): a start closer than this to A skips the
            drive to A (Moving₃'s P-control takes the rest), metres.
        papers_min_standoff, papers_max_standoff: the papers' planner puts Point A where the robot's heading line
            crosses the approach axis when that leaves this much floor (metres) before the face; otherwise it
            turns first, to the stand-off above.
        max_leg_angle_deg: monodock's leg to A meets the approach axis at no more than this angle, degrees; a
            start from which it would be steeper first backs out straight along its heading.
        min_leg: monodock's leg to A is at least this long along the axis, metres (so that its direction is
            defined, and changes smoothly, for starts at or next to A).
        max_back_out: monodock backs out at most this far, metres.
    """

    standoff: float = setting(1.0, unit="m", help="floor between front edge and face at the stand-off Point A")
    arrive_tolerance: float = setting(
        0.10, unit="m", help="turn-first plan: a start this close to A skips the drive to A"
    )
    papers_min_standoff: float = setting(
        0.5, unit="m", help="papers' planner: least floor before the face at a heading-line Point A"
    )
    papers_max_standoff: float = setting(
        2.0, unit="m", help="papers' planner: most floor before the face at a heading-line Point A"
    )
    kind: str = setting("monodock", help="`monodock` or `papers` ([the manoeuvre](#the-manoeuvre))")
    max_leg_angle_deg: float = setting(60.0, unit="°", help="monodock: steepest leg to A against the axis")
    min_leg: float = setting(0.30, unit="m", help="monodock: shortest leg to A along the axis")
    max_back_out: float = setting(1.0, unit="m", help="monodock: longest back-out before the turn to A")

    def __post_init__(self) -> None:
        if self.kind not in PLANNERS:
            raise ConfigError(f"planner: kind must be one of {', '.join(PLANNERS)}, got {self.kind!r}")
        if not self.standoff > 0:
            raise ConfigError(f"the stand-off of Point A must be positive, got {self.standoff}")
        if not 0 < self.max_leg_angle_deg < 90:
            raise ConfigError(f"planner: max_leg_angle_deg must be in (0, 90), got {self.max_leg_angle_deg}")
        if not (self.min_leg > 0 and self.max_back_out >= 0):
            raise ConfigError("planner: min_leg must be positive and max_back_out not negative")
        if not 0 < self.papers_min_standoff < self.papers_max_standoff:
            raise ConfigError(
                "the papers' planner needs 0 < papers_min_standoff < papers_max_standoff, got "
                f"{self.papers_min_standoff} and {self.papers_max_standoff}"
            )


def point_a(config: PlannerConfig, front_offset: float) -> Pose2D:
    """Point A: base_link on the approach axis, ``standoff`` of floor before the face, facing the charger."""
    return Pose2D(-(config.standoff + front_offset), 0.0, 0.0)


def classify(robot: Pose2D, a: Pose2D) -> int:
    """The case number (1–8) of a robot pose in the dock frame, with Point A at ``a``."""
    left = robot.y >= 0.0
    side = 1.0 if left else -1.0
    towards = math.sin(robot.theta) * side < 0.0
    past = robot.x > a.x
    for n, spec in CASES.items():
        if (spec.side == "left") == left and (spec.heading == "towards") == towards and (spec.zone == "past") == past:
            return n
    raise AssertionError("the eight cases cover every pose")  # pragma: no cover


@dataclass(frozen=True)
class Manoeuvre:
    """The planned Moving₁ and Moving₂ of one case, in the dock frame.

    Attributes:
        case: 1–8.
        start: the robot's pose when it was planned.
        point_a: Point A.
        drive_heading: the heading held while driving to A (the robot faces A, or turns its back to it).
        reverse: whether the drive to A is backwards.
        first_turn: Moving₁'s turn before the drive, radians, counter-clockwise positive.
        drive_distance: length of the drive to A, metres (0 when the start is already at A).
        second_turn: Moving₂'s turn at A to square up with the face, radians.
        back_out: monodock's reverse straight along the start heading before the first turn, metres (0: none).
        planner: which planner made it ("monodock", "papers", or "turn-first" for the papers' Fig. 15 fallback).
    """

    case: int
    start: Pose2D
    point_a: Pose2D
    drive_heading: float
    reverse: bool
    first_turn: float
    drive_distance: float
    second_turn: float
    back_out: float = 0.0
    planner: str = "turn-first"

    @property
    def reverses(self) -> float:
        """How far the manoeuvre drives backwards before Moving₃, metres."""
        return self.back_out + (self.drive_distance if self.reverse else 0.0)


def plan(robot: Pose2D, config: PlannerConfig, front_offset: float) -> Manoeuvre:
    """Classify the robot's pose (dock frame) and plan its turn, drive to Point A and turn square."""
    a = point_a(config, front_offset)
    case = classify(robot, a)
    dx, dy = a.x - robot.x, a.y - robot.y
    distance = math.hypot(dx, dy)
    reverse = CASES[case].zone == "past"
    if distance < config.arrive_tolerance:
        heading, distance = robot.theta, 0.0
    elif reverse:
        heading = math.atan2(-dy, -dx)  # back towards A: the robot faces away from it
    else:
        heading = math.atan2(dy, dx)
    first = wrap_angle(heading - robot.theta)
    second = wrap_angle(a.theta - heading)
    return Manoeuvre(case, robot, a, heading, reverse, first, distance, second)


def executed_case(robot: Pose2D, reverses: bool) -> int:
    """The case a manoeuvre executes: side and heading of the start, "past" when it reverses before Moving₂."""
    left = robot.y >= 0.0
    towards = math.sin(robot.theta) * (1.0 if left else -1.0) < 0.0
    for n, spec in CASES.items():
        same_side, same_heading = (spec.side == "left") == left, (spec.heading == "towards") == towards
        if same_side and same_heading and (spec.zone == "past") == reverses:
            return n
    raise AssertionError("the eight cases cover every manoeuvre")  # pragma: no cover


def _first_root(g0: float, slope: float, kink: float | None, slope_after: float) -> float | None:
    """The smallest r ≥ 0 where the piecewise linear g (g(0) = g0 < 0, a kink at ``kink``) reaches zero."""
    end = math.inf if kink is None else kink
    if slope > 0.0 and -g0 / slope <= end:
        return -g0 / slope
    if kink is None or slope_after <= 0.0:
        return None
    g_kink = g0 + slope * kink
    return kink + max(0.0, -g_kink) / slope_after


def plan_monodock(robot: Pose2D, config: PlannerConfig, front_offset: float) -> Manoeuvre:
    """monodock's manoeuvre: back out straight if needed, turn to face Point A, drive forward to it, turn square.

    Point A is fixed at the stand-off on the approach axis. The leg to A must meet the axis at no more than
    ``max_leg_angle_deg`` and run at least ``min_leg`` along it; a start from which it would not backs out,
    straight along its heading (the camera keeps the dock in view, the robot retraces floor it has seen), by the
    shortest distance that makes it so (at most ``max_back_out``). Every quantity of the plan is a continuous
    function of the start: there is no case boundary at which it jumps (for headings within
    ``max_leg_angle_deg`` of square-on, where backing out gains room; beyond that the back-out is capped).
    """
    a = point_a(config, front_offset)
    c, s = math.cos(robot.theta), math.sin(robot.theta)
    slack = 1.0 / math.tan(math.radians(config.max_leg_angle_deg))
    # g(r) >= 0: after backing out r, A lies far enough ahead along the axis for a leg no steeper than allowed.
    # g(r) = (a.x - x + r c) - slack * |y - r s| - min_leg, piecewise linear in r with a kink where y - r s = 0.
    g0 = a.x - robot.x - slack * abs(robot.y) - config.min_leg
    back = 0.0
    if g0 < 0.0:
        sign = math.copysign(1.0, robot.y) if robot.y != 0.0 else -math.copysign(1.0, s)
        kink = robot.y / s if s != 0.0 and robot.y / s > 0.0 else None
        root = _first_root(g0, c + sign * s * slack, kink, c - sign * s * slack)
        back = config.max_back_out if root is None else min(root, config.max_back_out)
    bx, by = robot.x - back * c, robot.y - back * s
    heading = math.atan2(a.y - by, a.x - bx)
    distance = math.hypot(a.x - bx, a.y - by)
    return Manoeuvre(
        executed_case(robot, back > 0.0),
        robot,
        a,
        heading,
        False,
        wrap_angle(heading - robot.theta),
        distance,
        wrap_angle(a.theta - heading),
        back,
        "monodock",
    )


def plan_papers(robot: Pose2D, config: PlannerConfig, front_offset: float) -> Manoeuvre:
    """The papers' manoeuvre as written: Moving₁ straight to Point A, Moving₂ the turn by Θab, no other turn.

    Point A is where the robot's heading line meets the approach axis (y = 0), so driving straight along the
    heading (forward if A is ahead, in reverse if behind) reaches it with no turn; Θab, the angle between the
    heading and the axis, is then turned at A. When the heading line meets the axis nowhere usable (parallel to
    it, or leaving less than ``papers_min_standoff`` or more than ``papers_max_standoff`` of floor before the
    face), the papers' Fig. 15 cases turn first: this is ``plan``'s manoeuvre to the stand-off Point A.
    """
    sin_t, cos_t = math.sin(robot.theta), math.cos(robot.theta)
    if abs(sin_t) > 1e-6:
        along = -robot.y / sin_t  # signed distance along the heading to the axis
        a = Pose2D(robot.x + along * cos_t, 0.0, 0.0)
        floor = -(a.x + front_offset)
        if config.papers_min_standoff <= floor <= config.papers_max_standoff:
            reverse = along < 0.0
            return Manoeuvre(
                executed_case(robot, reverse),
                robot,
                a,
                robot.theta,
                reverse,
                0.0,
                abs(along),
                wrap_angle(-robot.theta),
                planner="papers",
            )
    return plan(robot, config, front_offset)


def plan_for(robot: Pose2D, config: PlannerConfig, front_offset: float) -> Manoeuvre:
    """The configured planner's manoeuvre (``config.kind``)."""
    return (plan_papers if config.kind == "papers" else plan_monodock)(robot, config, front_offset)
