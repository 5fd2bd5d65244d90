"""Real time for the simulated robot: simulated time paced by the wall clock, every camera frame on time.

A ``SimulatedRobot`` normally runs as fast as it can and renders a frame only when its controller asks. A robot
on a ROS 2 graph (``monodock-sim-ros``) must instead behave like hardware: its clock is the wall clock and its
camera publishes every frame, ``camera_latency`` after the exposure, whoever listens. ``RealTimeRunner`` does
that: it steps the physics in simulated time, sleeps whenever simulated time runs ahead of the wall clock, renders
each frame as soon as it is exposed (the robot's pose is known then) and hands it over when it is due. A frame is
late when its rendering finished after its due time; the report says how often and by how much, which is how
``bench/realtime.py`` shows that 640x480 at 15 fps keeps up on one core.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from monodock.dock.interface import CameraFrame, Odometry
from monodock.errors import ConfigError
from monodock.sim.diffdrive import SimulatedRobot

__all__ = ["Command", "RealTimeReport", "RealTimeRunner", "drive_arc"]

Command = Callable[[float, Odometry], tuple[float, float] | None]
"""``command(t, odometry)`` -> a (linear, angular) velocity to send, or None to leave the last one."""


@dataclass(frozen=True)
class RealTimeReport:
    """How a real-time run kept up with the wall clock.

    Attributes:
        frames: camera frames delivered.
        simulated_s: simulated seconds run.
        wall_s: wall seconds it took.
        late_mean_ms, late_p95_ms, late_max_ms: how long after its due time each frame was ready (0 when on
            time; a frame due while it was still rendering counts the difference).
        late_frames: frames ready after their due time.
        render_mean_ms: wall milliseconds to render a frame.
        busy: share of the wall time spent stepping and rendering (1.0: no time left to sleep).
    """

    frames: int
    simulated_s: float
    wall_s: float
    late_mean_ms: float
    late_p95_ms: float
    late_max_ms: float
    late_frames: int
    render_mean_ms: float
    busy: float

    def summary(self) -> str:
        return (
            f"{self.frames} frames in {self.simulated_s:.1f} s simulated / {self.wall_s:.1f} s wall; "
            f"late: {self.late_frames} frames, mean {self.late_mean_ms:.2f} ms, p95 {self.late_p95_ms:.2f} ms, "
            f"max {self.late_max_ms:.2f} ms; rendering {self.render_mean_ms:.1f} ms a frame, busy {self.busy:.0%}"
        )


class RealTimeRunner:
    """Runs a SimulatedRobot against the wall clock (``speed`` simulated seconds per wall second).

    Args:
        robot: the robot; its camera rate and latency are the config's.
        speed: 1.0 is real time; 2.0 runs twice as fast as the wall clock.
        clock, sleep: the wall clock and how to wait on it (tests pass a fake pair).
    """

    def __init__(
        self,
        robot: SimulatedRobot,
        *,
        speed: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not speed > 0:
            raise ConfigError(f"real-time speed must be positive, got {speed}")
        self.robot = robot
        self.speed = speed
        self._clock = clock
        self._sleep = sleep
        self._pending: deque[tuple[float, CameraFrame]] = deque()  # (due, frame), in order
        self._rendered_until = -np.inf  # the last exposure rendered

    def run(
        self,
        duration: float,
        *,
        command: Command | None = None,
        control_period: float = 0.02,
        on_frame: Callable[[CameraFrame], None] | None = None,
        on_odometry: Callable[[Odometry], None] | None = None,
    ) -> RealTimeReport:
        """Run ``duration`` simulated seconds; frames go to ``on_frame`` when due, odometry every control period.

        ``command`` is asked for a velocity every ``control_period`` simulated seconds (a teleop, a script, or
        the latest ``cmd_vel`` of a ROS node).
        """
        robot = self.robot
        dt = robot.config.physics_dt
        latency = robot.config.camera_latency
        start_wall = self._clock()
        start_sim = robot.t
        next_control = robot.t
        late: list[float] = []
        render_s = 0.0
        rendered = 0
        busy_s = 0.0
        while robot.t - start_sim < duration - 1e-12:
            t0 = self._clock()
            if robot.t >= next_control - 1e-12:
                next_control += control_period
                if command is not None:
                    wanted = command(robot.t, robot.odometry())
                    if wanted is not None:
                        robot.send_velocity(*wanted)
                if on_odometry is not None:
                    on_odometry(robot.odometry())
            robot.sleep(dt)
            # Render each new exposure now, while its pose is the robot's; hand it over once it is due. New
            # exposures are at the end of the deque: at most one per step at any camera rate below 1/dt.
            fresh = []
            for stamp, pose in reversed(robot.exposures):
                if stamp <= self._rendered_until:
                    break
                fresh.append((stamp, pose))
            for stamp, pose in reversed(fresh):
                r0 = self._clock()
                frame = CameraFrame(stamp, robot.render(stamp, pose))
                render_s += self._clock() - r0
                rendered += 1
                self._rendered_until = stamp
                self._pending.append((stamp + latency, frame))
            while self._pending and self._pending[0][0] <= robot.t + 1e-12:
                due, frame = self._pending.popleft()
                due_wall = start_wall + (due - start_sim) / self.speed
                late.append(max(0.0, self._clock() - due_wall))
                robot.deliver(frame)
                if on_frame is not None:
                    on_frame(frame)
            busy_s += self._clock() - t0
            wait = start_wall + (robot.t - start_sim) / self.speed - self._clock()
            if wait > 0:
                self._sleep(wait)
        wall = self._clock() - start_wall
        lateness = np.array(late) * 1e3 if late else np.zeros(1)
        return RealTimeReport(
            frames=len(late),
            simulated_s=robot.t - start_sim,
            wall_s=wall,
            late_mean_ms=float(lateness.mean()),
            late_p95_ms=float(np.percentile(lateness, 95)),
            late_max_ms=float(lateness.max()),
            late_frames=int(np.count_nonzero(lateness > 0)),
            render_mean_ms=1e3 * render_s / max(rendered, 1),
            busy=busy_s / wall if wall > 0 else 1.0,
        )


def drive_arc(linear: float, angular: float) -> Command:
    """A constant-velocity command (a test drive, or a robot creeping towards the charger)."""

    def command(_t: float, _odom: Odometry) -> tuple[float, float]:
        return linear, angular

    return command
