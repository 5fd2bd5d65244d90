"""The simulated base's sensors and faults against the simulator's ground truth.

Every expectation is computed here from geometry (the analytic distance to a cylinder, a densely sampled circle,
the true pose), never by calling the code under test a second way.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose2d import Pose2D
from monodock.sim import Nuisances, Simulator
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from monodock.sim.faults import Obstacle

SIM = Simulator(nuisances=Nuisances.clean(), seed=1)
FRONT = SIM.robot.front_offset
REAR = DiffDriveConfig().rear_offset


def _robot(start: Pose2D, seed: int = 0, obstacles: tuple[Obstacle, ...] = (), **drive: object) -> SimulatedRobot:
    config = DiffDriveConfig(**drive)  # type: ignore[arg-type]
    return SimulatedRobot(SIM, start, config, np.random.default_rng(seed), obstacles=list(obstacles))


# --- rear range -------------------------------------------------------------------------------------------


def test_rear_range_reads_a_cylinder_straight_behind() -> None:
    robot = _robot(Pose2D(-1.0, 0.2, 0.0))
    back = -1.0 - REAR
    robot.obstacles.append(Obstacle(back - 0.8 - 0.1, 0.2, 0.1))
    reads = np.array([robot.rear_range() for _ in range(400)], dtype=float)
    assert abs(reads.mean() - 0.8) < 0.002
    assert 0.004 < reads.std() < 0.006  # the configured noise
    assert np.all(np.abs(reads - 0.8) < 0.03)


def test_rear_range_follows_a_turned_robot_and_a_partly_seen_cylinder() -> None:
    theta = 0.7
    robot = _robot(Pose2D(0.3, -0.4, theta), rear_range_noise_sd=0.0)
    ox, oy = 0.3 - REAR * math.cos(theta), -0.4 - REAR * math.sin(theta)  # the back edge's centre
    back = theta + math.pi
    # 25 degrees off the axis, big enough to reach into the 15-degree half cone: only part of it is seen.
    centre_dir, dist, r = back + math.radians(25.0), 1.0, 0.25
    cx, cy = ox + dist * math.cos(centre_dir), oy + dist * math.sin(centre_dir)
    robot.obstacles.append(Obstacle(cx, cy, r))
    phi = np.linspace(0.0, 2.0 * math.pi, 200_000)
    px, py = cx + r * np.cos(phi), cy + r * np.sin(phi)
    bearing = np.angle(np.exp(1j * (np.arctan2(py - oy, px - ox) - back)))
    inside = np.abs(bearing) <= math.radians(15.0)
    expected = float(np.hypot(px - ox, py - oy)[inside].min())
    assert expected > dist - r + 0.01  # the part it sees is not the part nearest to it
    assert robot.rear_range() == pytest.approx(expected, abs=1e-4)


def test_rear_range_is_inf_outside_the_cone_or_range_and_none_without_a_sensor() -> None:
    start = Pose2D(-1.0, 0.0, 0.0)
    back = -1.0 - REAR
    robot = _robot(start)
    assert robot.rear_range() == math.inf  # nothing there
    a = math.radians(30.0)
    robot.obstacles.append(Obstacle(back - 0.8 * math.cos(a), 0.8 * math.sin(a), 0.05))  # 30 deg off the axis
    robot.obstacles.append(Obstacle(back - 2.1 - 0.05, 0.0, 0.05))  # straight behind, 2.1 m: beyond range
    assert robot.rear_range() == math.inf
    assert _robot(start, rear_range_max=2.5).rear_range() == math.inf  # no obstacles in that one
    robot.obstacles.append(Obstacle(back - 1.0, 0.0, 0.1, appear=0.5, vanish=1.0))  # someone walks by
    assert robot.rear_range() == math.inf
    robot.sleep(0.6)
    assert robot.rear_range() == pytest.approx(0.9 - (robot.pose.x - start.x), abs=0.03)
    robot.sleep(0.5)
    assert robot.rear_range() == math.inf
    assert _robot(start, rear_sensor=False).rear_range() is None


# --- clearance and collision --------------------------------------------------------------------------------


def test_reversing_into_a_cylinder_is_a_collision() -> None:
    cx, r = -1.0 - REAR - 0.3 - 0.1, 0.1
    beside = Obstacle(-1.0, 0.2 + 0.15 + 0.05, 0.05)  # 15 cm off the robot's left side, never touched
    robot = _robot(Pose2D(-1.0, 0.0, 0.0), obstacles=(Obstacle(cx, 0.0, r), beside))
    assert robot.min_clearance == pytest.approx(0.15)
    robot.send_velocity(-0.2, 0.0)
    robot.sleep(1.0)
    p = robot.pose
    gap = math.hypot(*np.subtract(p.point(-REAR, 0.0), (cx, 0.0))) - r  # back edge's centre to the surface
    assert 0.05 < gap < 0.2
    assert robot.min_clearance == pytest.approx(min(gap, 0.15), abs=0.01)
    assert not robot.collided
    robot.sleep(1.5)
    assert robot.collided
    assert robot.min_clearance < 0.0
    assert robot.pose.x - REAR < cx + r  # it really is inside the cylinder by the truth


# --- charging -----------------------------------------------------------------------------------------------


def _press(lateral: float, heading_deg: float = 0.0, **drive: object) -> tuple[SimulatedRobot, list[bool | None]]:
    """Start 1 mm from the face, creep forward; what ``charging()`` said every 50 ms for 1 s."""
    theta = math.radians(heading_deg)
    half = 0.5 * DiffDriveConfig().footprint_width
    # Place the nearest front corner 1 mm off the face.
    x = -0.001 - FRONT * math.cos(theta) - half * abs(math.sin(theta))
    robot = _robot(Pose2D(x, lateral, theta), contact_sensor=True, **drive)
    assert robot.front_gap() == pytest.approx(0.001)
    robot.send_velocity(0.02, 0.0)
    said = []
    for _ in range(20):
        robot.sleep(0.05)
        said.append(robot.charging())
    return robot, said


def test_charging_on_the_pads_after_the_delay() -> None:
    robot, said = _press(0.01)
    assert robot.contact()
    assert robot.front_gap() < 1e-4
    assert abs(robot.pose.y) < 0.015
    assert abs(robot.pose.theta) < math.radians(4.0)
    assert not any(said[:5])  # 0.25 s: the charger's current sense has not reported yet
    assert all(said[6:])  # from 0.35 s on
    robot.send_velocity(-0.1, 0.0)
    robot.sleep(0.2)
    assert robot.front_gap() > 0.002
    assert robot.charging() is False


def test_no_charging_off_the_pads() -> None:
    robot, said = _press(0.03)
    assert robot.contact()  # it touches the face ...
    assert not any(said)  # ... but the springs miss the pads
    robot, said = _press(0.0, heading_deg=6.0)
    assert robot.contact()
    assert not any(said)


def test_charging_is_none_without_the_signal() -> None:
    _, said = _press(0.0, charging_signal=False)
    assert said == [None] * 20
