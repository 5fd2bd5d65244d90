"""What can go wrong around the simulated robot: obstacles behind it, and the geometry its safety truth needs.

``Obstacle`` is a vertical cylinder in the dock frame (a table leg, a person's legs) that may come and go.
``cone_range`` is what a rear range sensor (ultrasonic or a LiDAR's rear sector, ``sensor_msgs/Range``) reports
of it; ``footprint_clearance`` is the simulator's truth of how close the robot came to it. The robot's own fault
hooks (dropped and late frames, odometry jumps, wheel slip) are methods of ``SimulatedRobot``; their windows
are the small records here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.errors import ConfigError

__all__ = ["DelayWindow", "Obstacle", "SlipWindow", "cone_range", "footprint_clearance"]


@dataclass(frozen=True)
class Obstacle:
    """A vertical cylinder standing on the floor, in the dock frame (metres, seconds).

    Attributes:
        x, y: its axis in the dock frame.
        radius: its radius.
        appear, vanish: it is there for robot time in [appear, vanish) (someone stepping behind the robot).
    """

    x: float
    y: float
    radius: float
    appear: float = 0.0
    vanish: float = math.inf

    def __post_init__(self) -> None:
        if not self.radius > 0:
            raise ConfigError(f"obstacle radius must be positive, got {self.radius}")
        if not self.vanish > self.appear:
            raise ConfigError(f"obstacle must vanish after it appears, got [{self.appear}, {self.vanish})")

    def present(self, t: float) -> bool:
        return self.appear <= t < self.vanish


@dataclass(frozen=True)
class DelayWindow:
    """Frames exposed in [t0, t1) arrive ``extra`` seconds later than the camera's latency."""

    t0: float
    t1: float
    extra: float


@dataclass(frozen=True)
class SlipWindow:
    """During [t0, t1) the wheel's (0 left, 1 right) ground speed is ``factor`` times what it would be."""

    wheel: int
    factor: float
    t0: float
    t1: float


def _ray_hit(ox: float, oy: float, ux: float, uy: float, ob: Obstacle) -> float:
    """Distance along the unit ray (o, u) to the circle's surface; inf if it misses, 0 from inside."""
    fx, fy = ox - ob.x, oy - ob.y
    c = fx * fx + fy * fy - ob.radius * ob.radius
    if c <= 0.0:
        return 0.0
    b = fx * ux + fy * uy
    disc = b * b - c
    if disc < 0.0 or b >= 0.0:  # misses, or the circle is behind the ray's origin
        return math.inf
    return -b - math.sqrt(disc)


def cone_range(origin: Pose2D, fov: float, obstacles: list[Obstacle], t: float) -> float:
    """The distance (m) from ``origin`` to the nearest obstacle surface inside its cone; inf if none.

    The cone is centred on ``origin.theta`` and ``fov`` radians wide. Exact, not sampled by rays: the disc's
    nearest point is either the one towards its centre, when that direction is inside the cone, or else where
    one of the cone's two edges first enters the disc (the distance grows monotonically along the circle away
    from the nearest point).
    """
    best = math.inf
    half = 0.5 * fov
    for ob in obstacles:
        if not ob.present(t):
            continue
        dx, dy = ob.x - origin.x, ob.y - origin.y
        centre = math.hypot(dx, dy)
        if centre <= ob.radius:
            return 0.0
        if abs(wrap_angle(math.atan2(dy, dx) - origin.theta)) <= half:
            best = min(best, centre - ob.radius)
            continue
        for edge in (origin.theta - half, origin.theta + half):
            best = min(best, _ray_hit(origin.x, origin.y, math.cos(edge), math.sin(edge), ob))
    return best


def footprint_clearance(
    pose: Pose2D, front: float, rear: float, width: float, obstacles: list[Obstacle], t: float
) -> float:
    """The smallest distance (m) between the robot's rectangle and any present obstacle; negative when they
    overlap (minus the depth of the overlap), inf without obstacles.

    The rectangle spans ``front`` ahead of base_link, ``rear`` behind it and ``width`` across.
    """
    best = math.inf
    half = 0.5 * width
    for ob in obstacles:
        if not ob.present(t):
            continue
        lx, ly, _ = Pose2D(ob.x, ob.y, 0.0).relative_to(pose)
        dx = max(-rear - lx, 0.0, lx - front)
        dy = max(abs(ly) - half, 0.0)
        if dx > 0.0 or dy > 0.0:
            d = math.hypot(dx, dy) - ob.radius
        else:  # the axis is inside the footprint
            d = -min(lx + rear, front - lx, half - abs(ly)) - ob.radius
        best = min(best, d)
    return best
