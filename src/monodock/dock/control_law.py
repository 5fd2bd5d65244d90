"""The docking control law, as pure functions: turning in place and driving straight on odometry, Moving₃'s
P-control on the lateral and heading errors, the speed and acceleration limits, and the reverse stopping distance.

No state: each function maps the errors, the odometry and the gains of ``DockingConfig`` to a command (m/s,
rad/s), so the law is tested alone (tests/dock/test_control_law.py), as Nav2's ``opennav_docking`` tests its
``controller.cpp``. The mission decides which law applies when.
"""

from __future__ import annotations

import math

import numpy as np

from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.dock.config import DockingConfig
from monodock.dock.interface import Odometry

__all__ = [
    "approach_command",
    "drive_straight",
    "heading_reference",
    "is_still",
    "limit_command",
    "reverse_stopping_distance",
    "turn_in_place",
]


def limit_command(
    v: float, w: float, previous: tuple[float, float], c: DockingConfig, max_speed: float, max_turn: float
) -> tuple[float, float]:
    """Speed and acceleration limits from the ``previous`` command, and the minimum speed a real base still moves at.

    Args:
        v: Desired forward speed, m/s (negative: reverse).
        w: Desired turn rate, rad/s.
        previous: The command sent one control period ago.
        c: The gains and limits.
        max_speed: The forward speed limit (the config's and the robot's, whichever is lower).
        max_turn: The turn rate limit, likewise.

    Returns:
        The command to send.
    """
    dt = c.limits.control_period
    v = float(np.clip(v, -min(max_speed, c.reverse.max_reverse_speed), max_speed))
    w = float(np.clip(w, -max_turn, max_turn))
    pv, pw = previous
    want_v, want_w = v, w
    v = float(np.clip(v, pv - c.limits.linear_accel * dt, pv + c.limits.linear_accel * dt))
    w = float(np.clip(w, pw - c.limits.angular_accel * dt, pw + c.limits.angular_accel * dt))
    # Below the minimum a base does not move: round up when asked to move, down to zero when asked to stop.
    if abs(v) < c.limits.min_speed:
        v = math.copysign(c.limits.min_speed, want_v) if want_v != 0.0 else 0.0
    if v == 0.0 and abs(w) < c.limits.min_turn_rate:
        w = math.copysign(c.limits.min_turn_rate, want_w) if want_w != 0.0 else 0.0
    return v, w


def is_still(odom: Odometry, c: DockingConfig) -> bool:
    """Whether the odometry reads the robot as standing still."""
    return abs(odom.linear) < c.settle.settle_speed and abs(odom.angular) < 5 * c.settle.settle_speed


def turn_in_place(heading: float, odom: Odometry, c: DockingConfig, max_turn: float) -> tuple[bool, float]:
    """Turn on the spot towards ``heading`` (odometry frame), decelerating to stop on it.

    Returns:
        (there and no longer turning, the turn rate in rad/s).
    """
    err = wrap_angle(heading - odom.pose.theta)
    if abs(err) < math.radians(c.approach.turn_tolerance_deg):
        return abs(odom.angular) < 0.05, 0.0
    # Decelerate so as to stop on the target: w <= sqrt(2 a |err|).
    w = min(c.approach.k_turn * abs(err), math.sqrt(2 * c.limits.angular_accel * abs(err)), max_turn)
    return False, math.copysign(max(w, c.limits.min_turn_rate), err)


def drive_straight(
    target: Pose2D, pose: Pose2D, reverse: bool, c: DockingConfig, max_speed: float
) -> tuple[float, float, bool]:
    """Drive straight at ``target`` (forwards or backwards), steering on the bearing.

    Returns:
        (speed m/s, turn rate rad/s, arrived: the target is no more than ``arrive_tolerance`` ahead).
    """
    dx, dy = target.x - pose.x, target.y - pose.y
    heading = pose.theta + (math.pi if reverse else 0.0)
    along = dx * math.cos(heading) + dy * math.sin(heading)
    if along <= c.approach.arrive_tolerance:
        return 0.0, 0.0, True
    bearing = wrap_angle(math.atan2(dy, dx) - heading)
    speed = min(max_speed, math.sqrt(2 * c.limits.linear_accel * along), 2.0 * along + c.limits.min_speed)
    # Steer only while there is room; the last centimetres hold the heading.
    w = c.approach.k_bearing * bearing if along > 0.05 else 0.0
    return (-speed if reverse else speed), w, False


def heading_reference(lateral: float, gap: float, c: DockingConfig) -> float:
    """Moving₃'s heading reference (rad, dock frame) that closes the lateral error (m), faded out near the face
    (``gap``, m, front edge to face) so that the robot arrives square; bounded by ``max_correction_deg``."""
    fade = min(1.0, max(0.0, (gap - 0.5 * c.approach.heading_only_gap) / (0.5 * c.approach.heading_only_gap)))
    ref = -math.atan(c.approach.k_lateral * lateral) * fade
    return float(
        np.clip(ref, -math.radians(c.approach.max_correction_deg), math.radians(c.approach.max_correction_deg))
    )


def approach_command(heading: float, reference: float, gap: float, c: DockingConfig) -> tuple[float, float]:
    """Moving₃'s command: the turn rate steers the heading (rad, dock frame) onto the reference; the speed falls
    towards the face so as to stop in the remaining gap, and is the creep speed for the last ``creep_distance``."""
    w = c.approach.k_heading * wrap_angle(reference - heading)
    v = min(
        c.limits.approach_speed,
        math.sqrt(2 * c.limits.linear_accel * 0.5 * max(gap - c.limits.creep_distance, 0.0)) + c.limits.min_speed,
    )
    if gap <= c.limits.creep_distance:
        v = c.limits.min_speed
    return v, w


def reverse_stopping_distance(speed: float, c: DockingConfig) -> float:
    """How much room behind (m) a robot reversing at ``speed`` needs to stop short of ``rear_safety_distance``:
    the command latency and the braking at ``linear_accel``."""
    return c.reverse.rear_safety_distance + speed * c.limits.stop_lead + speed * speed / (2.0 * c.limits.linear_accel)
