"""Continuous simulated drives written as rosbag2: a commissioning drive before the dock, a teaching back-off.

Commissioning a robot (``monodock calibrate mount``, ``monodock teach``) needs what a person records with a
joystick and ``ros2 bag record``, not a stop-and-go data collection:

- **commissioning**: about a minute of driving and turning in front of the dock, the markers in view most of
  the time: stations 0.6-1.7 m before the face across ±0.4 m, at each a wiggle of ±15° about the dock's bearing,
  between them a turn, a straight leg and a turn back. Rotations at several places excite the camera's position
  on the base, the changing headings its roll and pitch, the legs the layout's scale against the odometry.
- **teach**: the robot on the charger's contacts, charging (a person pushed it on, a few millimetres and a
  fraction of a degree off the axis), then backing off straight on its odometry for about a metre.

A simulated operator steers on the robot's true pose (as a person would by eye); the robot's own odometry, with
its wheel errors, and its camera frames (motion blur, exposure timing) are what is recorded, as on a real
robot: ``/camera/image_raw`` (mono8) with ``/camera/camera_info``, ``/odom`` nav_msgs/Odometry at the control
rate, ``/battery_state`` at 10 Hz, and the truth on ``/monodock/ground_truth`` (the DockPose at each image).
"""

from __future__ import annotations

import heapq
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.errors import ConfigError
from monodock.recording import messages as m
from monodock.recording.write import (
    BASE_FRAME,
    BATTERY_TOPIC,
    CAMERA_FRAME,
    CAMERA_INFO_TOPIC,
    IMAGE_TOPIC,
    ODOM_FRAME,
    ODOMETRY_TOPIC,
    RELIABLE,
    SENSOR,
    TRUTH_TOPIC,
    BagWriter,
)
from monodock.sim.diffdrive import SimulatedRobot

__all__ = ["DRIVES", "DriveSummary", "Leg", "commissioning_route", "record_drive", "teach_route", "teach_start"]

DRIVES = ("commissioning", "teach")
CONTROL_PERIOD = 0.02  # s: the operator's commands and the odometry messages, 50 Hz
BATTERY_PERIOD = 0.1
_IMAGE_LATENCY_S = 0.030  # the recorder's receive time after the stamp, as sim.recording


@dataclass(frozen=True)
class Leg:
    """One step of a drive: ``turn`` to a heading, ``go`` straight to a point (forwards or backwards), or
    ``wait``; headings and points in the dock frame, seconds for ``wait``."""

    kind: str
    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    seconds: float = 0.0
    reverse: bool = False


@dataclass(frozen=True)
class DriveSummary:
    """What a written drive holds."""

    path: Path
    images: int
    odometry: int
    duration_s: float
    bytes: int


def _bearing_to_dock(x: float, y: float, aim_y: float = 0.0) -> float:
    """The heading that faces a point of the dock's face from (x, y) in the dock frame."""
    return math.atan2(aim_y - y, -x)


def commissioning_route(rng: np.random.Generator, *, stations: int = 5) -> tuple[Pose2D, list[Leg]]:
    """The start and the legs of a commissioning drive (about a minute at 0.15 m/s)."""
    xs = rng.uniform(-1.7, -0.6, stations)
    ys = rng.uniform(-0.4, 0.4, stations)
    start = Pose2D(float(xs[0]), float(ys[0]), _bearing_to_dock(xs[0], ys[0]))
    legs: list[Leg] = []
    for k in range(stations):
        x, y = float(xs[k]), float(ys[k])
        if k > 0:
            legs.append(Leg("turn", heading=math.atan2(y - float(ys[k - 1]), x - float(xs[k - 1]))))
            legs.append(Leg("go", x, y))
        face = _bearing_to_dock(x, y, float(rng.uniform(-0.1, 0.1)))
        swing = math.radians(float(rng.uniform(10.0, 16.0)))
        legs += [
            Leg("turn", heading=face),
            Leg("wait", seconds=0.4),
            Leg("turn", heading=face + swing),
            Leg("turn", heading=face - swing),
            Leg("turn", heading=face),
            Leg("wait", seconds=0.4),
        ]
    # Last, straight at the dock and back: the layout's scale against the odometry, the markers growing in view.
    x, y = float(xs[-1]), float(ys[-1])
    face = _bearing_to_dock(x, y)
    d = max(0.0, min(0.5, -x - 0.55))
    legs += [Leg("go", x + d * math.cos(face), y + d * math.sin(face)), Leg("go", x, y, reverse=True)]
    return start, legs


def teach_start(robot_front_offset: float, rng: np.random.Generator) -> Pose2D:
    """Where a person left the robot on the contacts: a millimetre off the face, a few off the axis, square to
    within half a degree (in the dock frame)."""
    return Pose2D(-robot_front_offset - 0.001, float(rng.uniform(-0.003, 0.003)), math.radians(rng.uniform(-0.5, 0.5)))


def teach_route(distance: float = 1.0) -> list[Leg]:
    """Sit on the contacts (charging), then back off ``distance`` metres straight on the odometry, then stand."""
    return [Leg("wait", seconds=1.5), Leg("back", seconds=distance), Leg("wait", seconds=0.5)]


def _unseen(robot: SimulatedRobot, after: float) -> bool:
    return bool(robot.exposure_log) and robot.exposure_log[-1].stamp > after


class _Operator:
    """A person with a joystick: drives the legs on the robot's true pose (or, backing off, on its odometry)."""

    def __init__(self, robot: SimulatedRobot, legs: list[Leg]) -> None:
        self.robot, self.legs = robot, list(legs)
        self.leg_start: float | None = None
        self.back_from: Pose2D | None = None

    def command(self) -> tuple[float, float] | None:
        """The next command, or None when every leg is done."""
        while self.legs:
            leg = self.legs[0]
            done, v, w = self._leg(leg)
            if not done:
                return v, w
            self.legs.pop(0)
            self.leg_start, self.back_from = None, None
        return None

    def _leg(self, leg: Leg) -> tuple[bool, float, float]:
        r = self.robot
        if self.leg_start is None:
            self.leg_start = r.now()
        pose = r.pose
        if leg.kind == "wait":
            return r.now() - self.leg_start >= leg.seconds, 0.0, 0.0
        if leg.kind == "turn":
            err = wrap_angle(leg.heading - pose.theta)
            return abs(err) < math.radians(0.5), 0.0, float(np.clip(2.5 * err, -0.5, 0.5))
        if leg.kind == "back":  # straight back on the odometry, heading held: what a robot's own controller does
            odom = r.odom
            if self.back_from is None:
                self.back_from = odom
            moved = self.back_from.distance(odom)
            heading = wrap_angle(self.back_from.theta - odom.theta)
            return moved >= leg.seconds, -0.1, 2.0 * heading
        dx, dy = leg.x - pose.x, leg.y - pose.y
        dist = math.hypot(dx, dy)
        if dist < 0.01:
            return True, 0.0, 0.0
        aim = math.atan2(dy, dx) + (math.pi if leg.reverse else 0.0)
        err = wrap_angle(aim - pose.theta)
        v = min(0.15, 1.5 * dist) * (-1.0 if leg.reverse else 1.0) * max(0.0, math.cos(err))
        return False, v, float(np.clip(2.0 * err, -0.5, 0.5))


def _ticks(robot: SimulatedRobot, legs: list[Leg], max_seconds: float) -> Iterator[None]:
    operator = _Operator(robot, legs)
    while robot.now() < max_seconds:
        command = operator.command()
        if command is None:
            return
        robot.send_velocity(*command)
        robot.sleep(CONTROL_PERIOD)
        yield
    raise ConfigError(f"simulated drive: the route took longer than {max_seconds:.0f} s")


def record_drive(
    out: str | os.PathLike[str],
    robot: SimulatedRobot,
    legs: list[Leg],
    *,
    frame_every: int = 1,
    start_s: float = 1_700_000_000.0,
    storage: str = "mcap",
    force: bool = False,
    progress: bool = True,
    max_seconds: float = 600.0,
) -> DriveSummary:
    """Drive the legs and write what the robot recorded as a rosbag2 folder (atomically, as sim.recording).

    Args:
        out: the recording's folder.
        robot: the simulated robot, at its start.
        legs: the route (``commissioning_route``, ``teach_route``).
        frame_every: record every n-th camera frame (the others are never rendered).
        start_s: the stamp of the drive's start (a wall-clock time, as a real recording has).
        storage: "mcap" or "sqlite3".
        force: replace an existing ``out``.
        progress: a progress bar in seconds of drive.
        max_seconds: refuse a route that takes longer.
    """
    if frame_every < 1:
        raise ConfigError(f"simulated drive: frame_every must be at least 1, got {frame_every}")
    cam = robot.sim.camera
    images = odoms = 0
    last_frame = -math.inf
    next_battery = 0.0
    exposures = 0
    bar = tqdm(desc="drive", unit="s", disable=None if progress else True, leave=False)
    try:
        with BagWriter(out, storage=storage, force=force) as bag:
            image_conn = bag.connect(IMAGE_TOPIC, m.IMAGE, SENSOR)
            info_conn = bag.connect(CAMERA_INFO_TOPIC, m.CAMERA_INFO, SENSOR)
            odom_conn = bag.connect(ODOMETRY_TOPIC, m.ODOMETRY, RELIABLE)
            battery_conn = bag.connect(BATTERY_TOPIC, m.BATTERY_STATE, RELIABLE)
            truth_conn = bag.connect(TRUTH_TOPIC, m.POSE_STAMPED, RELIABLE)
            pending: list[tuple[float, int, Any, Any]] = []  # (receive, order, connection, message)

            def later(receive: float, conn: Any, msg: Any) -> None:
                heapq.heappush(pending, (receive, len(pending) + images + odoms, conn, msg))

            for _ in _ticks(robot, legs, max_seconds):
                t = robot.now()
                odom = robot.odometry()
                o = odom.pose
                msg = m.odometry_msg(start_s + t, o.x, o.y, o.theta, odom.linear, odom.angular, frame_id=ODOM_FRAME)
                later(start_s + t, odom_conn, msg)
                odoms += 1
                if t >= next_battery:
                    later(start_s + t, battery_conn, m.battery_msg(start_s + t, bool(robot.charging())))
                    next_battery = t + BATTERY_PERIOD
                # Each exposure that has arrived by now; every frame_every-th rendered (motion blur included).
                while exposures < len(robot.exposure_log) or _unseen(robot, last_frame):
                    e = next((e for e in robot.exposure_log if e.stamp > last_frame), None)
                    if e is None or e.arrival > t:
                        break
                    last_frame = e.stamp
                    exposures += 1
                    if (exposures - 1) % frame_every:
                        continue
                    stamp = start_s + e.stamp
                    _, image_msg = m.encode_image(robot.render(e.stamp, e.mid), "mono8", stamp, CAMERA_FRAME)
                    receive = max(stamp + _IMAGE_LATENCY_S, start_s + t)
                    later(receive, image_conn, image_msg)
                    later(receive, info_conn, m.camera_info_msg(cam, stamp, CAMERA_FRAME))
                    later(receive, truth_conn, m.pose_msg(robot.dock_pose(e.mid), stamp, BASE_FRAME))
                    images += 1
                # In receive order, as a recorder writes them.
                while pending and pending[0][0] <= start_s + t:
                    receive, _, conn, msg = heapq.heappop(pending)
                    bag.write(conn, msg, receive)
                bar.update(CONTROL_PERIOD)
            while pending:
                receive, _, conn, msg = heapq.heappop(pending)
                bag.write(conn, msg, receive)
    finally:
        bar.close()
    return DriveSummary(bag.path, images, odoms, robot.now(), bag.size_bytes())
