"""Real time for the simulated robot: simulated time paced by the wall clock, every camera frame on time.

A ``SimulatedRobot`` normally runs as fast as it can and renders a frame only when its controller asks. A robot
on a ROS 2 graph (``monodock-sim-ros``) must instead behave like hardware: its clock is the wall clock and its
camera publishes every frame, ``camera_latency`` after the exposure, whoever listens. ``RealTimeRunner`` does
that: it steps the physics in simulated time, sleeps whenever simulated time runs ahead of the wall clock, renders
each frame as soon as it is exposed (the robot's pose is known then) and hands it over when it is due. A frame is
late when its rendering finished after its due time; the report says how often and by how much, which is how
``bench/realtime.py`` shows that 640x480 at 15 fps keeps up on one core.

Simulated time never runs ahead of the wall clock, and never catches up in a burst either: when a step finds the
simulation more than ``max_lag`` behind (the machine was busy, the process was starved), it goes on from there at
the wall clock's pace, as Gazebo does, and those seconds are lost to the simulation rather than run at once, where
every listener would miss them (a starved detector would see the robot jump, a docking node its markers vanish). The
real-time factor, simulated seconds per wall second, then drops below 1; ``on_real_time_factor`` hears it every
``window`` wall seconds, and the report gives the worst window, the stalls and the seconds lost.
"""

from __future__ import annotations

import math
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
        real_time_factor: simulated seconds per wall second over the run (``speed`` when it kept up).
        min_real_time_factor: the worst window's (NaN for a run shorter than one window).
        stalls: how often the simulation fell more than ``max_lag`` behind and went on from there.
        lost_s: wall seconds the stalls cost (simulated time did not run them).
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
    real_time_factor: float = 1.0
    min_real_time_factor: float = math.nan
    stalls: int = 0
    lost_s: float = 0.0

    def summary(self) -> str:
        return (
            f"{self.frames} frames in {self.simulated_s:.1f} s simulated / {self.wall_s:.1f} s wall (real-time factor "
            f"{self.real_time_factor:.2f}, worst {self.min_real_time_factor:.2f}; {self.stalls} stalls, "
            f"{self.lost_s:.2f} s lost); late: {self.late_frames} frames, mean {self.late_mean_ms:.2f} ms, "
            f"p95 {self.late_p95_ms:.2f} ms, max {self.late_max_ms:.2f} ms; rendering {self.render_mean_ms:.1f} ms "
            f"a frame, busy {self.busy:.0%}"
        )


class RealTimeRunner:
    """Runs a SimulatedRobot against the wall clock (``speed`` simulated seconds per wall second).

    Args:
        robot: the robot; its camera rate and latency are the config's.
        speed: 1.0 is real time; 2.0 runs twice as fast as the wall clock.
        max_lag: wall seconds the simulation may fall behind and still catch up; beyond, it goes on from there.
        window: wall seconds over which the real-time factor is measured.
        clock, sleep: the wall clock and how to wait on it (tests pass a fake pair).
    """

    def __init__(
        self,
        robot: SimulatedRobot,
        *,
        speed: float = 1.0,
        max_lag: float = 0.02,
        window: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not speed > 0:
            raise ConfigError(f"real-time speed must be positive, got {speed}")
        if not (max_lag >= 0 and window > 0):
            raise ConfigError(f"max_lag must be at least 0 and window above 0, got {max_lag} and {window}")
        self.robot = robot
        self.speed = speed
        self.max_lag, self.window = max_lag, window
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
        on_real_time_factor: Callable[[float], None] | None = None,
    ) -> RealTimeReport:
        """Run ``duration`` simulated seconds; frames go to ``on_frame`` when due, odometry every control period,
        the real-time factor to ``on_real_time_factor`` every ``window`` wall seconds.

        ``command`` is asked for a velocity every ``control_period`` simulated seconds (a teleop, a script, or
        the latest ``cmd_vel`` of a ROS node).
        """
        robot = self.robot
        dt = robot.config.physics_dt
        latency = robot.config.camera_latency
        start_wall = self._clock()
        start_sim = robot.t
        anchor_wall, anchor_sim = start_wall, start_sim  # simulated time anchor_sim is due at wall time anchor_wall
        window_wall, window_sim = start_wall, start_sim
        factors: list[float] = []
        stalls, lost = 0, 0.0
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
                due_wall = anchor_wall + (due - anchor_sim) / self.speed
                late.append(max(0.0, self._clock() - due_wall))
                robot.deliver(frame)
                if on_frame is not None:
                    on_frame(frame)
            busy_s += self._clock() - t0
            now = self._clock()
            wait = anchor_wall + (robot.t - anchor_sim) / self.speed - now
            if wait > 0:
                self._sleep(wait)
            elif wait < -self.max_lag:  # behind: go on from here at the wall clock's pace, no burst to catch up
                stalls, lost = stalls + 1, lost - wait
                anchor_wall, anchor_sim = now, robot.t
            now = self._clock()
            if now - window_wall >= self.window:
                factors.append((robot.t - window_sim) / (now - window_wall))
                window_wall, window_sim = now, robot.t
                if on_real_time_factor is not None:
                    on_real_time_factor(factors[-1])
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
            real_time_factor=(robot.t - start_sim) / wall if wall > 0 else self.speed,
            min_real_time_factor=min(factors) if factors else math.nan,
            stalls=stalls,
            lost_s=lost,
        )


def drive_arc(linear: float, angular: float) -> Command:
    """A constant-velocity command (a test drive, or a robot creeping towards the charger)."""

    def command(_t: float, _odom: Odometry) -> tuple[float, float]:
        return linear, angular

    return command
