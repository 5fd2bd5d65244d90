"""A simulated differential-drive robot at the charger, implementing the docking controller's robot interface.

What a cheap base does that an ideal one does not, each from the seeded generator:
- commands arrive after a latency and the motors follow them with a first-order lag;
- each wheel's ground speed differs from what its encoder reports, by a fixed per-run factor (tyre wear,
  slip, wheel-radius error) and per-step noise, so odometry drifts, in heading most of all;
- the camera exposes at its own rate and phase, and a frame arrives a latency after its exposure;
- the charger face is solid: the robot cannot drive through it, and its wheels slip when it pushes.

The pose truth lives in the dock frame. The controller sees only odometry (the integral of the encoders,
in a frame that starts at the robot's start pose) and camera images rendered from the true pose. Frames are
rendered when the controller first asks for them, so states that do not look cost nothing.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.layout import ROLES
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.dock.interface import CameraFrame, Odometry
from monodock.errors import ConfigError
from monodock.sim.faults import Obstacle, cone_range, footprint_clearance
from monodock.sim.simulator import Simulator

__all__ = ["DiffDriveConfig", "Obstacle", "SimulatedRobot", "TruthSample"]


@dataclass(frozen=True)
class DiffDriveConfig:
    """The base's physics and the nuisances of its wheels, camera and links (SI units).

    Attributes:
        track_width: distance between the wheels.
        footprint_width: the robot's width, for contact and plots.
        rear_offset: base_link to the robot's back edge.
        command_latency: from ``send_velocity`` to the motor controller.
        motor_time_constant: first-order lag of each wheel's speed.
        wheel_scale_sd: per-run relative error of each wheel's ground speed against its encoder.
        wheel_noise_sd: per-step relative noise on each wheel's ground speed.
        camera_rate: frames per second; the phase of the first frame is random.
        camera_latency: from exposure to the frame's arrival.
        physics_dt: integration step.
        contact_sensor: whether the charger contacts report touch (``contact()``); otherwise None and the
            robot must stop on its own estimate.
        rear_sensor: whether the robot has a rear range sensor (``rear_range()``); otherwise None.
        rear_range_max: the sensor's maximum range, metres; farther reads ``math.inf``.
        rear_fov_deg: its full cone angle, degrees (``sensor_msgs/Range.field_of_view``).
        rear_range_noise_sd: standard deviation of its reading, metres.
        charging_signal: whether the robot reads the charger's current (``charging()``); otherwise None.
        contact_gap: the front edge charges from this far off the face, metres (the spring contacts' travel).
        contact_lateral_tolerance: the largest |lateral offset| of base_link at which the springs still land
            on the robot's pads, metres.
        contact_heading_tolerance_deg: the largest |heading| at which both pads touch, degrees.
        charge_delay: how long the contacts must hold before the charger reports current, seconds.
    """

    track_width: float = 0.40
    footprint_width: float = 0.40
    rear_offset: float = 0.20
    command_latency: float = 0.04
    motor_time_constant: float = 0.05
    wheel_scale_sd: float = 0.005
    wheel_noise_sd: float = 0.05
    camera_rate: float = 15.0
    camera_latency: float = 0.05
    physics_dt: float = 0.005
    contact_sensor: bool = False
    rear_sensor: bool = True
    rear_range_max: float = 2.0
    rear_fov_deg: float = 30.0
    rear_range_noise_sd: float = 0.005
    charging_signal: bool = True
    contact_gap: float = 0.002
    contact_lateral_tolerance: float = 0.015
    contact_heading_tolerance_deg: float = 4.0
    charge_delay: float = 0.3

    def __post_init__(self) -> None:
        for name in ("track_width", "camera_rate", "physics_dt", "rear_range_max"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"diff drive: {name} must be positive, got {getattr(self, name)}")
        for name in (
            "rear_range_noise_sd",
            "contact_gap",
            "contact_lateral_tolerance",
            "contact_heading_tolerance_deg",
            "charge_delay",
        ):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"diff drive: {name} must not be negative, got {getattr(self, name)}")
        if not 0 < self.rear_fov_deg < 180:
            raise ConfigError(f"diff drive: rear_fov_deg must be in (0, 180), got {self.rear_fov_deg}")


@dataclass(frozen=True)
class TruthSample:
    """The simulator's record of one moment: true pose in the dock frame and the odometry the robot saw."""

    t: float
    pose: Pose2D
    odom: Pose2D


@dataclass
class SimulatedRobot:
    """The robot, its camera and the charger, stepping in simulated time.

    Args:
        sim: the simulator that renders the camera (layout, camera, mounts, nuisances).
        start: the robot's true pose in the dock frame.
        config: the base's physics.
        rng: every random draw.
        hide_markers: ``hide_markers(t, pose)`` True hides the dock's markers from the frame exposed at time
            t with the robot at ``pose`` (someone standing in front of the charger).
        obstacles: cylinders around the robot (``monodock.sim.faults.Obstacle``); append to it at any time.
            They do not stop the robot: the rear sensor sees them and ``min_clearance`` / ``collided`` record
            how close it came (the charger face is not one of them).

    Charging: the charger reports current once its spring contacts have pressed the robot's pads for
    ``charge_delay`` (0.3 s, the charger's current sense) without a break. They press when the front edge is
    within ``contact_gap`` (2 mm, the springs' travel) of the face, base_link within
    ``contact_lateral_tolerance`` of the dock's axis and the heading within ``contact_heading_tolerance_deg``.
    The lateral tolerance is 15 mm, half the width of a 3 cm pad: a real robot 2 cm off the axis touches the
    face but its springs land beside the pads, so it does not charge although ``contact()`` says touch. The
    heading tolerance, 4 degrees, is where the second pad lifts off the springs' travel.

    Safety truth: ``min_clearance`` is the smallest distance (m) over the run so far between the robot's
    footprint (``front_offset`` ahead, ``rear_offset`` behind, ``footprint_width`` across) and any present
    obstacle, checked every physics step; ``collided`` is whether it ever reached 0.
    """

    sim: Simulator
    start: Pose2D
    config: DiffDriveConfig = field(default_factory=DiffDriveConfig)
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    hide_markers: Callable[[float, Pose2D], bool] | None = None
    obstacles: list[Obstacle] = field(default_factory=list)

    def __post_init__(self) -> None:
        c = self.config
        self.t = 0.0
        self.pose = self.start
        self.odom = Pose2D(0.0, 0.0, 0.0)
        self.wheel_scale = 1.0 + self.rng.normal(0.0, c.wheel_scale_sd, size=2)
        self.wheel_speed = np.zeros(2)  # encoder speeds (left, right), m/s at the rim
        self.odom_velocity = (0.0, 0.0)
        self.commands: deque[tuple[float, float, float]] = deque()  # (time it takes effect, v, w)
        self.target = (0.0, 0.0)
        self.next_exposure = float(self.rng.uniform(0.0, 1.0 / c.camera_rate))
        self.exposures: deque[tuple[float, Pose2D]] = deque(maxlen=64)
        self._frame: CameraFrame | None = None
        self.touching = False
        self.impact_speed: float | None = None
        self.pushed = 0.0  # how far the wheels drove on while the front edge pressed the face, metres
        self.truth: list[TruthSample] = [TruthSample(0.0, self.pose, self.odom)]
        self.frames_rendered = 0
        self.render_seconds = 0.0  # wall time spent rendering, for the speed figures
        self.min_clearance = math.inf
        self.collided = False
        self._pressed_since: float | None = None  # when the contacts last closed
        self.is_charging = False
        self._check_clearance()

    # --- the robot interface ------------------------------------------------------------------

    def now(self) -> float:
        return self.t

    def send_velocity(self, linear: float, angular: float) -> None:
        if not (math.isfinite(linear) and math.isfinite(angular)):
            raise ValueError(f"velocity command must be finite, got ({linear}, {angular})")
        self.commands.append((self.t + self.config.command_latency, float(linear), float(angular)))

    def odometry(self) -> Odometry:
        return Odometry(self.t, self.odom, *self.odom_velocity)

    def contact(self) -> bool | None:
        return self.touching if self.config.contact_sensor else None

    def charging(self) -> bool | None:
        return self.is_charging if self.config.charging_signal else None

    def rear_range(self) -> float | None:
        """The rear sensor's reading from the back edge's centre, metres; inf when nothing is within range."""
        c = self.config
        if not c.rear_sensor:
            return None
        x, y = self.pose.point(-c.rear_offset, 0.0)
        origin = Pose2D(x, y, wrap_angle(self.pose.theta + math.pi))
        d = cone_range(origin, math.radians(c.rear_fov_deg), self.obstacles, self.t)
        if d > c.rear_range_max:
            return math.inf
        if c.rear_range_noise_sd > 0:
            d += float(self.rng.normal(0.0, c.rear_range_noise_sd))
        return max(d, 0.0)

    def latest_frame(self) -> CameraFrame | None:
        """The newest frame whose exposure has arrived; rendered on first request."""
        arrived = [e for e in self.exposures if e[0] + self.config.camera_latency <= self.t]
        if not arrived:
            return self._frame
        stamp, pose = arrived[-1]
        if self._frame is None or self._frame.stamp != stamp:
            self._frame = CameraFrame(stamp, self.render(stamp, pose))
        return self._frame

    def deliver(self, frame: CameraFrame) -> None:
        """Hand over a frame rendered ahead (the real-time runner renders each exposure when it happens)."""
        self._frame = frame

    def sleep(self, seconds: float) -> None:
        steps = max(1, round(seconds / self.config.physics_dt))
        for _ in range(steps):
            self._step(self.config.physics_dt)
        self.truth.append(TruthSample(self.t, self.pose, self.odom))

    # --- what the simulator knows ---------------------------------------------------------------

    def dock_pose(self, pose: Pose2D | None = None) -> DockPose:
        """The true DockPose (dock in base_link) of a robot pose in the dock frame."""
        p = pose or self.pose
        return DockPose.from_robot_in_dock(p.x, p.y, p.theta)

    def render(self, stamp: float, pose: Pose2D) -> NDArray[np.uint8]:
        """The camera image of a robot at ``pose`` (dock frame), exposed at ``stamp``."""
        dock_pose = self.dock_pose(pose)
        t0 = time.perf_counter()
        image = self.sim.render(dock_pose, rng=self.rng)
        self.render_seconds += time.perf_counter() - t0
        self.frames_rendered += 1
        if self.hide_markers is not None and self.hide_markers(stamp, pose):
            corners = self.sim.true_corners(dock_pose)
            for role in ROLES:
                quad = corners[role]
                if np.all(np.isfinite(quad)):
                    centre = quad.mean(axis=0)
                    grown = centre + 1.3 * (quad - centre)  # cover the white margin too: nothing to detect
                    cv2.fillConvexPoly(image, np.round(grown).astype(np.int32), 128)
        return image

    def longitudinal_error(self) -> float:
        """Signed stopping error: the gap to the face when short of it, minus how far it drove on into it."""
        return self.front_gap() - self.pushed

    def front_gap(self, pose: Pose2D | None = None) -> float:
        """Distance from the robot's front edge (its nearest front corner) to the face, metres."""
        p = pose or self.pose
        half = 0.5 * self.config.footprint_width
        xs = [p.point(self.sim.robot.front_offset, s * half)[0] for s in (-1.0, 1.0)]
        return -max(xs)

    # --- physics ------------------------------------------------------------------------------

    def _step(self, dt: float) -> None:
        c = self.config
        while self.commands and self.commands[0][0] <= self.t:
            _, v, w = self.commands.popleft()
            self.target = (v, w)
        v, w = self.target
        half = 0.5 * c.track_width
        wanted = np.array([v - w * half, v + w * half])
        self.wheel_speed += (wanted - self.wheel_speed) * (1.0 - math.exp(-dt / c.motor_time_constant))
        ground = self.wheel_speed * self.wheel_scale * (1.0 + self.rng.normal(0.0, c.wheel_noise_sd, size=2))
        self.odom = self._integrate(self.odom, self.wheel_speed, dt)
        self.odom_velocity = (
            float(self.wheel_speed.mean()),
            float((self.wheel_speed[1] - self.wheel_speed[0]) / c.track_width),
        )
        before = self.pose
        self.pose = self._integrate(self.pose, ground, dt)
        # The face is solid: a robot that would pass it is pushed back out, its wheels slipping.
        gap = self.front_gap()
        charger_half = 0.5 * self.sim.charger.width + 0.5 * c.footprint_width
        touching = gap <= 1e-4 and abs(self.pose.y) < charger_half
        if touching and not self.touching and self.impact_speed is None:
            self.impact_speed = before.distance(self.pose) / dt
        if touching and gap < 0.0:
            self.pose = Pose2D(self.pose.x + gap, self.pose.y, self.pose.theta)
            self.pushed += -gap
        self.touching = touching
        self.t += dt
        self._check_contacts()
        self._check_clearance()
        if self.t >= self.next_exposure:
            self.exposures.append((self.next_exposure, self.pose))
            self.next_exposure += 1.0 / c.camera_rate

    def _check_contacts(self) -> None:
        c = self.config
        pressed = (
            self.front_gap() <= c.contact_gap
            and abs(self.pose.y) <= c.contact_lateral_tolerance
            and abs(self.pose.theta) <= math.radians(c.contact_heading_tolerance_deg)
        )
        if not pressed:
            self._pressed_since = None
        elif self._pressed_since is None:
            self._pressed_since = self.t
        since = self._pressed_since
        # A hair under the delay: the time is a sum of physics steps.
        self.is_charging = since is not None and self.t - since >= c.charge_delay - 1e-9

    def _check_clearance(self) -> None:
        if not self.obstacles:
            return
        c = self.config
        d = footprint_clearance(
            self.pose, self.sim.robot.front_offset, c.rear_offset, c.footprint_width, self.obstacles, self.t
        )
        self.min_clearance = min(self.min_clearance, d)
        self.collided = self.collided or self.min_clearance <= 0.0

    def _integrate(self, pose: Pose2D, wheels: NDArray[np.float64], dt: float) -> Pose2D:
        v = float(wheels.mean())
        w = float((wheels[1] - wheels[0]) / self.config.track_width)
        mid = pose.theta + 0.5 * w * dt
        return Pose2D(pose.x + v * dt * math.cos(mid), pose.y + v * dt * math.sin(mid), wrap_angle(pose.theta + w * dt))
