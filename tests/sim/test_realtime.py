"""The real-time runner paces simulated time to a wall clock and delivers every frame on time, or says it did not.

The wall clock here is a fake one that moves only when the runner sleeps and when a frame is rendered (by a
chosen rendering cost), so the figures are exact and the test does not depend on the machine's speed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose2d import Pose2D
from monodock.dock.interface import CameraFrame
from monodock.sim import Simulator
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from monodock.sim.realtime import RealTimeRunner, drive_arc


class FakeWall:
    def __init__(self) -> None:
        self.now = 100.0
        self.slept = 0.0

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.now += seconds
        self.slept += seconds


def _robot(render_cost: float, wall: FakeWall) -> SimulatedRobot:
    robot = SimulatedRobot(Simulator(seed=2), Pose2D(-1.6, 0.05, 0.02), DiffDriveConfig(), np.random.default_rng(4))
    render = robot.render

    def costly_render(stamp: float, pose: Pose2D) -> np.ndarray:
        wall.now += render_cost
        return render(stamp, pose)

    robot.render = costly_render  # type: ignore[method-assign]
    return robot


def test_frames_arrive_at_the_camera_rate_on_time_and_time_is_paced() -> None:
    wall = FakeWall()
    robot = _robot(0.010, wall)
    frames: list[tuple[float, float, CameraFrame]] = []  # (robot time, wall time, frame) at delivery

    report = RealTimeRunner(robot, clock=wall.clock, sleep=wall.sleep).run(
        2.0, command=drive_arc(0.1, 0.0), on_frame=lambda f: frames.append((robot.t, wall.now, f))
    )

    config = robot.config
    stamps = np.array([f.stamp for _, _, f in frames])
    # Every exposure of the 2 s, in order, one camera period apart, each handed over its latency after exposure.
    assert 28 <= len(frames) <= 31
    np.testing.assert_allclose(np.diff(stamps), 1.0 / config.camera_rate, atol=1e-9)
    for t, _, frame in frames:
        assert frame.stamp + config.camera_latency <= t + 1e-9 < frame.stamp + config.camera_latency + config.physics_dt
    # Rendering takes 10 ms of a 67 ms period: never late, and the wall clock followed simulated time.
    assert report.frames == len(frames)
    assert report.late_frames == 0
    assert report.late_max_ms == 0.0
    assert report.wall_s == pytest.approx(2.0, abs=config.physics_dt)
    assert report.render_mean_ms == pytest.approx(10.0)
    assert report.busy == pytest.approx(robot.frames_rendered * 0.010 / report.wall_s, rel=1e-6)
    # The controller's view: the newest frame that has arrived, never rendered twice.
    assert robot.latest_frame() is frames[-1][2]
    assert robot.frames_rendered == len(frames) + sum(s > frames[-1][2].stamp for s, _ in robot.exposures)
    # The robot drove: 0.1 m/s for 2 s, less the motors' lag and the command latency.
    assert 0.17 < robot.pose.x - (-1.6) < 0.2


def test_a_renderer_slower_than_the_camera_slows_the_simulation_and_says_so() -> None:
    wall = FakeWall()
    robot = _robot(0.120, wall)  # slower than one 67 ms camera period
    factors: list[float] = []

    report = RealTimeRunner(robot, clock=wall.clock, sleep=wall.sleep, window=0.5).run(
        2.0, on_real_time_factor=factors.append
    )

    # Each frame's 120 ms of rendering costs the simulation that much wall time: 15 frames a simulated second make
    # 2.8 wall seconds of it, a real-time factor of 1 / 2.8. Nothing is run in a burst to catch up, so no frame is
    # due before it is ready.
    expected = 1.0 / (1.0 + 15 * 0.120)
    assert report.real_time_factor == pytest.approx(expected, rel=0.08)
    assert report.wall_s == pytest.approx(2.0 / expected, rel=0.08)
    assert max(factors) < 0.5
    assert report.min_real_time_factor == min(factors)
    assert report.stalls >= report.frames - 1
    assert report.lost_s == pytest.approx(report.wall_s - 2.0, abs=0.05)
    assert report.late_frames == 0
    assert report.busy == pytest.approx(robot.frames_rendered * 0.120 / report.wall_s, rel=1e-6)


def test_a_stall_is_lost_to_the_simulation_never_run_in_a_burst() -> None:
    """A process starved for 1.5 s (the wall clock jumps under it): afterwards simulated time runs at the wall
    clock's pace again, the stall's seconds are not run at once, and every frame still comes one camera period of
    wall time after the one before."""
    wall = FakeWall()
    robot = _robot(0.005, wall)
    frames: list[tuple[float, float]] = []  # (simulated time, wall time) at each delivery
    stalled: list[float] = []

    def command(t: float, _odometry: object) -> None:
        if t >= 0.5 and not stalled:
            stalled.append(wall.now)
            wall.now += 1.5  # the process got no CPU for 1.5 s

    report = RealTimeRunner(robot, clock=wall.clock, sleep=wall.sleep).run(
        2.0, command=command, on_frame=lambda _frame: frames.append((robot.t, wall.now))
    )

    assert report.stalls == 1
    assert report.lost_s == pytest.approx(1.5, abs=0.03)
    assert report.simulated_s == pytest.approx(2.0)
    assert report.wall_s == pytest.approx(3.5, abs=0.05)
    assert report.real_time_factor == pytest.approx(2.0 / 3.5, rel=0.02)
    period = 1.0 / robot.config.camera_rate
    after = [(s, w) for s, w in frames if w > stalled[0] + 1.5]
    gaps = np.diff([w for _, w in after])
    assert len(after) > 15
    assert gaps.min() == pytest.approx(period, abs=0.025)  # no burst: frames keep the camera's pace
    simulated, walled = after[-1][0] - after[0][0], after[-1][1] - after[0][1]
    assert simulated == pytest.approx(walled, abs=0.03)  # real time again after the stall


def test_speed_scales_the_wall_clock() -> None:
    wall = FakeWall()
    robot = _robot(0.0, wall)

    report = RealTimeRunner(robot, speed=4.0, clock=wall.clock, sleep=wall.sleep).run(1.0)

    assert report.wall_s == pytest.approx(0.25, abs=robot.config.physics_dt)
    assert math.isclose(report.simulated_s, 1.0, abs_tol=1e-9)
    with pytest.raises(Exception, match="speed must be positive"):
        RealTimeRunner(robot, speed=0.0)
