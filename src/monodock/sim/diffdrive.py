"""A simulated differential-drive robot at the charger, implementing the docking controller's robot interface.

What a cheap base does that an ideal one does not, each from the seeded generator:
- commands arrive after a latency and the motors follow them with a first-order lag;
- each wheel's ground speed differs from what its encoder reports, by a fixed per-run factor (tyre wear,
  slip, wheel-radius error) and per-step noise, so odometry drifts, in heading most of all;
- the camera exposes at its own rate and phase, and a frame arrives a latency after its exposure; the robot's
  own motion during the exposure blurs it; frames can be dropped or arrive late;
- the charger face is solid: the robot cannot drive through it, and its wheels slip when it pushes.

The pose truth lives in the dock frame. The controller sees only odometry (the integral of the encoders,
in a frame that starts at the robot's start pose) and camera images rendered from the true pose. Frames are
rendered when the controller first asks for them, so states that do not look cost nothing.

Fault hooks, for fault tables: ``drop_frames``, ``delay_frames``, ``jump_odometry``, ``slip_wheel``; with
``hide_markers`` (occlusion) and ``Obstacle(appear=...)`` (someone stepping behind the robot).

With ``blank_undetectable``, a frame in which no dock marker can be detected (each has a corner beyond the
image's border over the whole exposure: ArUco rejects a marker that touches the border) is not rendered: the
camera's nuisances are applied to a blank image instead, which draws the same random numbers as a render, and
``undetectable(stamp)`` says so, so that a caller that trusts the simulator may skip the detection it knows
finds nothing (dock-sim does, in the blind zone at the face).
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

from monodock.core.compiled import inlined, kernel
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.dock.interface import CameraFrame, Odometry
from monodock.errors import ConfigError
from monodock.sim.faults import DelayWindow, Obstacle, SlipWindow, cone_range, footprint_clearance
from monodock.sim.nuisance import apply_nuisances
from monodock.sim.render import render_radiance
from monodock.sim.simulator import Simulator
from monodock.sim.world import PAPER_WHITE

__all__ = [
    "DiffDriveConfig",
    "Exposure",
    "SimulatedRobot",
    "TruthSample",
]


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
        camera_latency: from the middle of the exposure (the frame's stamp) to the frame's arrival.
        exposure_time: how long the shutter is open, seconds (0: no motion blur). Must be shorter than a frame.
        frame_drop_rate: chance that an exposure is never delivered (USB bandwidth, a driver that lost it).
        latency_spike_rate: chance that a frame arrives ``latency_spike`` seconds later than ``camera_latency``.
        latency_spike: that extra delay, seconds.
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
    exposure_time: float = 0.008
    frame_drop_rate: float = 0.0
    latency_spike_rate: float = 0.0
    latency_spike: float = 0.3
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
            "exposure_time",
            "latency_spike",
        ):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"diff drive: {name} must not be negative, got {getattr(self, name)}")
        if not self.exposure_time < 1.0 / self.camera_rate:
            raise ConfigError(f"diff drive: exposure_time {self.exposure_time} s is not shorter than a frame")
        for name in ("frame_drop_rate", "latency_spike_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"diff drive: {name} must be in [0, 1], got {getattr(self, name)}")
        if not 0 < self.rear_fov_deg < 180:
            raise ConfigError(f"diff drive: rear_fov_deg must be in (0, 180), got {self.rear_fov_deg}")


@dataclass(frozen=True)
class Exposure:
    """One exposure of the camera: the robot's true poses at its start, middle (the stamp) and end, and when
    its frame arrives (seconds of robot time).

    Attributes:
        stamp: the middle of the exposure, the frame's stamp.
        start, mid, end: the robot's true pose in the dock frame at ``stamp - exposure_time / 2``, ``stamp`` and
            ``stamp + exposure_time / 2``.
        arrival: when the frame reaches the robot without the fault hooks: ``stamp + camera_latency``, plus
            ``latency_spike`` for a spiked frame (never before the exposure's end).
        dropped: the camera's own drop (``frame_drop_rate``); ``drop_frames`` windows come on top.
    """

    stamp: float
    start: Pose2D
    mid: Pose2D
    end: Pose2D
    arrival: float
    dropped: bool = False


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
        blank_undetectable: deliver a blank frame (the sensor's noise on the charger face's white, no render)
            when no dock marker can be detected in it (``undetectable``); off: every frame is rendered.
        wheel_scale: each wheel's (left, right) ground speed against its encoder, fixed: the same robot in several
            runs (a commissioning drive, then dockings); None draws it per run from ``wheel_scale_sd``.

    Charging: the charger reports current once its spring contacts have pressed the robot's pads for
    ``charge_delay`` (0.3 s, the charger's current sense) without a break. They press when the front edge is
    within ``contact_gap`` (2 mm, the springs' travel) of the face, base_link within
    ``contact_lateral_tolerance`` of the dock's axis and the heading within ``contact_heading_tolerance_deg``.
    The lateral tolerance is 15 mm, half the width of a 3 cm pad: a real robot 2 cm off the axis touches the
    face but its springs land beside the pads, so it does not charge although ``contact()`` says touch. The
    heading tolerance, 4 degrees, is where the second pad lifts off the springs' travel.

    Camera: each exposure lasts ``exposure_time``; its stamp is its middle. ``exposure_log`` keeps the true
    poses at its start, middle and end (``exposures`` the stamp and middle pose, dropped frames included: the
    camera took them). A frame is blurred by the robot's motion over its exposure (``_MotionBlur``: one
    render, a few warps induced by the charger's face plane; skipped when the streak is under 0.2 px, so a
    still robot's frame is the plain render). ``latest_frame`` applies the frame faults (``frame_drop_rate``,
    ``latency_spike_rate``, ``drop_frames``, ``delay_frames``). ``RealTimeRunner`` paces its own deliveries:
    it renders every exposure and delivers it ``camera_latency`` later, so the frame faults do not reach it.

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
    blank_undetectable: bool = False
    wheel_scale: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        c = self.config
        self.t = 0.0
        self.pose = self.start
        self.odom = Pose2D(0.0, 0.0, 0.0)
        drawn = 1.0 + self.rng.normal(0.0, c.wheel_scale_sd, size=2)
        self.wheels = drawn if self.wheel_scale is None else np.asarray(self.wheel_scale, dtype=np.float64)
        self.wheel_speed = np.zeros(2)  # encoder speeds (left, right), m/s at the rim
        self.odom_velocity = (0.0, 0.0)
        self.commands: deque[tuple[float, float, float]] = deque()  # (time it takes effect, v, w)
        self.target = (0.0, 0.0)
        self.next_exposure = float(self.rng.uniform(0.0, 1.0 / c.camera_rate))
        self.exposures: deque[tuple[float, Pose2D]] = deque(maxlen=64)  # (stamp, mid pose), every exposure
        # The exposures' windows and arrivals; long enough to hold a frame delayed by seconds.
        self.exposure_log: deque[Exposure] = deque(maxlen=256)
        self._open: tuple[float, Pose2D, Pose2D | None] | None = None  # (stamp, start, mid) being exposed
        self._frame: CameraFrame | None = None
        self._blur = _MotionBlur(self.sim)
        self._drops: list[tuple[float, float]] = []
        self._delays: list[DelayWindow] = []
        self._slips: list[SlipWindow] = []
        self.touching = False
        self.impact_speed: float | None = None
        self.pushed = 0.0  # how far the wheels drove on while the front edge pressed the face, metres
        self.truth: list[TruthSample] = [TruthSample(0.0, self.pose, self.odom)]
        self.frames_rendered = 0
        self.frames_blank = 0  # frames delivered blank (blank_undetectable), not rendered
        self._blank_stamps: deque[float] = deque(maxlen=64)
        self.render_seconds = 0.0  # wall time spent rendering, for the speed figures
        self.render_cpu_seconds = 0.0  # CPU time of this process spent rendering (a loaded machine inflates wall)
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
        """The newest frame that has arrived; rendered on first request.

        Like a camera driver that keeps only the newest image: a late frame that arrives after a newer one is
        discarded, so the frames the robot sees never go back in time, and a late frame holds back nothing.
        """
        held = self._frame.stamp if self._frame is not None else -math.inf
        for e in reversed(self.exposure_log):
            if e.stamp <= held:
                break
            if not self._is_dropped(e) and self.arrival(e) <= self.t:
                self._frame = CameraFrame(e.stamp, self._image(e))
                break
        return self._frame

    def undetectable(self, stamp: float) -> bool:
        """Whether the frame exposed at ``stamp`` was delivered blank because no dock marker can be detected in it
        (``blank_undetectable``): a detector would find none of the dock's markers there, by the truth."""
        return stamp in self._blank_stamps

    def _image(self, e: Exposure) -> NDArray[np.uint8]:
        """The frame of an exposure: rendered, or blank when ``blank_undetectable`` and no marker can be seen."""
        if not (self.blank_undetectable and self._markers_cut(e)):
            return self.render(e.stamp, e.mid)
        t0, c0 = time.perf_counter(), time.process_time()
        cam = self.sim.camera
        blank = np.full((cam.height, cam.width), PAPER_WHITE, dtype=np.float32)
        image = apply_nuisances(blank, self.sim.nuisances, self.rng)  # the render's random draws, in its order
        self.render_seconds += time.perf_counter() - t0
        self.render_cpu_seconds += time.process_time() - c0
        self.frames_blank += 1
        self._blank_stamps.append(e.stamp)
        return image

    def _markers_cut(self, e: Exposure) -> bool:
        """Whether every dock marker has a corner beyond the same border of the image, by ``_CUT_MARGIN_PX`` or
        more, at both the start and the end of the exposure (so throughout it: the corner moves along a near
        straight line in a few milliseconds), or not in the camera's field at all."""
        start = {role: _beyond(quad, self.sim) for role, quad in self.sim.true_corners(self.dock_pose(e.start)).items()}
        if not all(start.values()):
            return False  # a marker whole in the image at the start: most frames end here, after one projection
        end = self.sim.true_corners(self.dock_pose(e.end))
        return all(start[role] & _beyond(end[role], self.sim) for role in self.sim.layout.roles)

    def deliver(self, frame: CameraFrame) -> None:
        """Hand over a frame rendered ahead (the real-time runner renders each exposure when it happens)."""
        self._frame = frame

    def arrival(self, exposure: Exposure) -> float:
        """When the frame of this exposure reaches the robot, with the ``delay_frames`` windows, seconds."""
        extra = sum(w.extra for w in self._delays if w.t0 <= exposure.stamp < w.t1)
        return exposure.arrival + extra

    def _is_dropped(self, exposure: Exposure) -> bool:
        return exposure.dropped or any(t0 <= exposure.stamp < t1 for t0, t1 in self._drops)

    def sleep(self, seconds: float) -> None:
        steps = max(1, round(seconds / self.config.physics_dt))
        for _ in range(steps):
            self._step(self.config.physics_dt)
        self.truth.append(TruthSample(self.t, self.pose, self.odom))

    # --- fault hooks ----------------------------------------------------------------------------

    def drop_frames(self, t0: float, t1: float) -> None:
        """No frame exposed (stamped) in [t0, t1) seconds is ever delivered by ``latest_frame``."""
        self._drops.append((float(t0), float(t1)))

    def delay_frames(self, t0: float, t1: float, extra: float) -> None:
        """Frames exposed in [t0, t1) seconds arrive ``extra`` seconds later than they would (windows add up);
        a newer frame that arrives first supersedes them."""
        if not extra >= 0:
            raise ValueError(f"frame delay must not be negative, got {extra}")
        self._delays.append(DelayWindow(float(t0), float(t1), float(extra)))

    def jump_odometry(self, dx: float, dy: float, dtheta: float) -> None:
        """The odometry pose jumps by (dx m, dy m, dtheta rad) in the odometry frame, now (an encoder glitch,
        a reset); the true pose does not move."""
        o = self.odom
        self.odom = Pose2D(o.x + dx, o.y + dy, wrap_angle(o.theta + dtheta))

    def slip_wheel(self, side: str, factor: float, t0: float, t1: float) -> None:
        """During [t0, t1) seconds the ``side`` ("left" or "right") wheel's ground speed is ``factor`` times what
        it would be (a wet patch, a cable under the tyre); its encoder does not know, so odometry does not
        either."""
        if side not in ("left", "right"):
            raise ValueError(f"wheel side must be 'left' or 'right', got {side!r}")
        if not factor >= 0:
            raise ValueError(f"slip factor must not be negative, got {factor}")
        self._slips.append(SlipWindow(0 if side == "left" else 1, float(factor), float(t0), float(t1)))

    # --- what the simulator knows ---------------------------------------------------------------

    def dock_pose(self, pose: Pose2D | None = None) -> DockPose:
        """The true DockPose (dock in base_link) of a robot pose in the dock frame."""
        p = pose or self.pose
        return DockPose.from_robot_in_dock(p.x, p.y, p.theta)

    def render(self, stamp: float, pose: Pose2D) -> NDArray[np.uint8]:
        """The camera image of a robot at ``pose`` (dock frame), exposed at ``stamp``.

        When ``stamp`` is one of the robot's exposures (``exposure_log``) with ``pose`` its middle, the image is
        motion-blurred by the robot's motion during that exposure.
        """
        dock_pose = self.dock_pose(pose)
        t0, c0 = time.perf_counter(), time.process_time()
        exposure = next((e for e in reversed(self.exposure_log) if e.stamp == stamp and e.mid == pose), None)
        streak = self._blur.streak(exposure) if exposure is not None else None
        if streak is not None:
            image = self._blur.render(dock_pose, streak, self.rng)
        else:
            image = self.sim.render(dock_pose, rng=self.rng)
        self.render_seconds += time.perf_counter() - t0
        self.render_cpu_seconds += time.process_time() - c0
        self.frames_rendered += 1
        if self.hide_markers is not None and self.hide_markers(stamp, pose):
            corners = self.sim.true_corners(dock_pose)
            for role in self.sim.layout.roles:
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
        ground = self.wheel_speed * self.wheels * (1.0 + self.rng.normal(0.0, c.wheel_noise_sd, size=2))
        for slip in self._slips:
            if slip.t0 <= self.t < slip.t1:
                ground[slip.wheel] *= slip.factor
        self.odom = self._integrate(self.odom, self.wheel_speed, dt)
        self.odom_velocity = (
            _mean2(self.wheel_speed),
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
        t_before = self.t
        self.t += dt
        self._check_contacts()
        self._check_clearance()
        self._expose(t_before, before)

    def _expose(self, t_before: float, before: Pose2D) -> None:
        """Record the exposures' poses that fell in the step from ``t_before`` (pose ``before``) to now."""
        c = self.config
        half = 0.5 * c.exposure_time

        def at(t: float) -> Pose2D:  # the pose at a time within the step, interpolated
            f = min(max((t - t_before) / (self.t - t_before), 0.0), 1.0)
            return _lerp(before, self.pose, f)

        while True:
            stamp = self.next_exposure
            if self._open is None:
                if self.t < stamp - half:
                    return
                self._open = (stamp, at(stamp - half), None)
            _, start, mid = self._open
            if mid is None and self.t >= stamp:
                mid = at(stamp)
                self._open = (stamp, start, mid)
            if mid is None or self.t < stamp + half:
                return
            # Both draws only when asked for, so that a robot without these faults keeps its random sequence.
            dropped = c.frame_drop_rate > 0 and bool(self.rng.random() < c.frame_drop_rate)
            spiked = c.latency_spike_rate > 0 and bool(self.rng.random() < c.latency_spike_rate)
            arrival = max(stamp + c.camera_latency + (c.latency_spike if spiked else 0.0), stamp + half)
            self.exposure_log.append(Exposure(stamp, start, mid, at(stamp + half), arrival, dropped))
            self.exposures.append((stamp, mid))
            self._open = None
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
        v = _mean2(wheels)
        w = float((wheels[1] - wheels[0]) / self.config.track_width)
        mid = pose.theta + 0.5 * w * dt
        return Pose2D(pose.x + v * dt * math.cos(mid), pose.y + v * dt * math.sin(mid), wrap_angle(pose.theta + w * dt))


def _mean2(pair: NDArray[np.float64]) -> float:
    """The mean of the two wheels' speeds: numpy's mean of two, (a + b) / 2 (the same two roundings), without its
    few microseconds of overhead, twice a physics step (a docking run takes thousands of steps)."""
    return float((pair[0] + pair[1]) / 2.0)


_CUT_MARGIN_PX = 2.0  # beyond the lens blur's reach: the dark border of a cut marker runs into the image's edge


def _beyond(corners: NDArray[np.float64], sim: Simulator) -> set[tuple[int, str]]:
    """(corner, side) of the marker's corners that lie beyond a side of the image by ``_CUT_MARGIN_PX`` or more;
    (corner, "field") for a corner outside the camera's field (NaN)."""
    w, h, m = sim.camera.width - 0.5, sim.camera.height - 0.5, _CUT_MARGIN_PX
    out: set[tuple[int, str]] = set()
    for i, (x, y) in enumerate(corners):
        if not (math.isfinite(x) and math.isfinite(y)):
            out.add((i, "field"))
            continue
        if x <= -0.5 - m:
            out.add((i, "left"))
        if x >= w + m:
            out.add((i, "right"))
        if y <= -0.5 - m:
            out.add((i, "top"))
        if y >= h + m:
            out.add((i, "bottom"))
    return out


def _lerp(a: Pose2D, b: Pose2D, f: float) -> Pose2D:
    """The pose a fraction ``f`` of the way from a to b (straight, heading the short way round)."""
    return Pose2D(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y), wrap_angle(a.theta + f * wrap_angle(b.theta - a.theta)))


_BLUR_MIN_PX = 0.2  # a streak shorter than this is invisible under the lens blur and the noise: skip the warps
_BLUR_MAX_SAMPLES = 8
_BLUR_SPACING_PX = 1.5
_BLUR_GRID_PX = 32  # the warp is computed exactly every 32 px and interpolated between: it is smooth
_FAR = 20.0  # metres: rays that miss the face plane, or meet it farther, move as if at this distance


class _MotionBlur:
    """Motion blur from the robot's own motion during an exposure, for the price of one render and a few warps.

    The scene is rendered once at the exposure's middle pose, as radiance (linear light, before the sensor's
    noise and 8-bit rounding: a real sensor integrates light while it moves and adds its noise once). The
    images at poses spread evenly over the exposure are then warps of it, and the blurred image is their mean.
    Each warp is the one the charger's face plane (x = 0 in the dock frame, where the markers lie) induces
    between the two camera poses, H = K (R - t n^T / d) K^-1, computed point by point through the lens
    (undistort, move, distort again) on a coarse grid and interpolated: exact on the face plane at any lens
    distortion. Other surfaces (floor, walls) are warped as if they lay in that plane; their streaks are
    wrong in length by the ratio of depths, which matters little for a blur of a few pixels.
    """

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        cam = sim.camera
        w, h = cam.width, cam.height
        gw, gh = -(-w // _BLUR_GRID_PX), -(-h // _BLUR_GRID_PX)
        # Grid nodes where cv2.resize's linear interpolation puts them, so that resizing reproduces them.
        gx = (np.arange(gw) + 0.5) * w / gw - 0.5
        gy = (np.arange(gh) + 0.5) * h / gh - 0.5
        self.grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
        self.grid_shape = (gh, gw)
        self.rays: NDArray[np.float64] | None = None  # the grid's undistorted rays (z = 1); computed when needed
        # How cv2.resize (OpenCV 5.1, INTER_LINEAR) spreads the grid over the pixels, column by column and row
        # by row: the two nodes and their weights (the columns' clamped at the borders, the rows' not).
        self.columns = _resize_taps(w, gw, clamp_weights=True)
        self.rows = _resize_taps(h, gh, clamp_weights=False)

    def _optical(self, pose: Pose2D) -> NDArray[np.float64]:
        """world_T_optical of the robot at ``pose`` in the dock frame."""
        return self.sim.world_T_optical(DockPose.from_robot_in_dock(*pose))

    def _shift(self, mid: NDArray[np.float64], sub: NDArray[np.float64]) -> NDArray[np.float64]:
        """For the grid's pixels in the image at ``sub`` (a world_T_optical), how far (px, shape (N, 2)) the
        same points of the face plane lie in the image at ``mid``."""
        if self.rays is None:
            n = self.sim.camera.normalize(self.grid)
            self.rays = np.column_stack([n, np.ones(len(n))])
        R, o = sub[:3, :3], sub[:3, 3]
        dirs = self.rays @ R.T  # in the dock frame
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = -o[0] / dirs[:, 0]  # where each ray meets x = 0
        depth = np.where((depth > 0) & (depth < _FAR), depth, _FAR)
        points = o + depth[:, None] * dirs
        mid_inv = np.linalg.inv(mid)
        in_mid = points @ mid_inv[:3, :3].T + mid_inv[:3, 3]
        px = self.sim.camera.project(in_mid)
        return np.asarray(px - self.grid, dtype=np.float64)

    def streak(self, e: Exposure) -> _Streak | None:
        """Where the grid's pixels of the middle image were at the exposure's start and end; None when the streak
        is under ``_BLUR_MIN_PX`` everywhere (a still robot's frame is then the plain render, bit for bit)."""
        if e.start == e.end:
            return None
        mid = self._optical(e.mid)
        start = self._shift(mid, self._optical(e.start))
        end = self._shift(mid, self._optical(e.end))
        length = float(np.max(np.hypot(*(end - start).T), initial=0.0))
        if not length >= _BLUR_MIN_PX:  # also when the geometry gave NaN
            return None
        return _Streak(start, end, length)

    def render(self, pose: DockPose, streak: _Streak, rng: np.random.Generator) -> NDArray[np.uint8]:
        """The mono8 image at DockPose ``pose`` (the exposure's middle), blurred along ``streak``; the same random
        draws as ``Simulator.render``.

        The samples sit at the centres of equal parts of the exposure, at most 1.5 px apart (the lens blur fills
        the gaps; streaks longer than ``_BLUR_MAX_SAMPLES`` x 1.5 px show as ghosts rather than a smooth
        streak). A sample's shift is the start's or the end's scaled: over a few milliseconds the pose, and so
        the shift, moves along a straight line to first order.
        """
        sim = self.sim
        radiance = render_radiance(
            sim.world, sim.camera, sim.world_T_optical(pose), supersample=sim.nuisances.supersample
        )
        return apply_nuisances(self.blur(radiance, streak), sim.nuisances, rng)

    def blur(self, radiance: NDArray[np.float32], streak: _Streak) -> NDArray[np.float32]:
        """The mean of the warps of ``radiance`` along ``streak``, float32.

        Where the radiance is flat within a warp's reach every warp gives the pixel back, so only the pixels near
        an edge (a few percent: the renderer's images are piecewise flat) are warped, by a compiled kernel that
        does what cv2.resize, cv2.scaleAdd and cv2.remap (INTER_LINEAR, BORDER_REPLICATE) of OpenCV 5.1 do,
        operation for operation in float32: the same image, bit for bit, as warping the whole image with them
        (``tests/sim/test_diffdrive.py``), at a fraction of the cost.
        """
        k = min(_BLUR_MAX_SAMPLES, max(2, math.ceil(streak.length / _BLUR_SPACING_PX)))
        grids = np.stack([streak.start, streak.end]).reshape(2, *self.grid_shape, 2).astype(np.float32)
        # Flat pixels: the sum of k copies of themselves times 1/k, as the warps' mean gives them.
        total = radiance.copy()
        for _ in range(k - 1):
            total += radiance
        total *= np.float32(1.0 / k)
        # A pixel's warps read the pixels within `reach` of it: a shift is at most max|grids| px (float32 rounding
        # adds far less than 0.01), so both bilinear taps lie within floor(that) + 1. The pixel is flat for its warps
        # when no two neighbours differ there: no edge mark (a pixel differing from its right or lower neighbour)
        # within `reach`. The tightest such box: the fewer pixels warped, the less the blur costs.
        reach = int(float(np.max(np.abs(grids))) + 0.01) + 1
        edges = np.zeros(radiance.shape, dtype=np.uint8)
        edges[:, :-1] |= radiance[:, :-1] != radiance[:, 1:]
        edges[:-1, :] |= radiance[:-1, :] != radiance[1:, :]
        box = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
        near = np.asarray(cv2.dilate(edges, box, anchor=(reach, reach)), dtype=np.uint8)
        _warp_mean(radiance, near, grids, *self.columns, *self.rows, k, total)
        return total


def _resize_taps(
    size: int, nodes: int, *, clamp_weights: bool
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32], NDArray[np.float32]]:
    """For each of ``size`` pixels, the two grid nodes cv2.resize (INTER_LINEAR, OpenCV 5.1) mixes and their
    float32 weights: the node index clamped at the borders, and the weight too (``clamp_weights``: its
    horizontal pass) or not (its vertical pass)."""
    f = ((np.arange(size) + 0.5) * (nodes / size) - 0.5).astype(np.float32)
    i0 = np.floor(f).astype(np.int64)
    a = (f - i0.astype(np.float32)).astype(np.float32)
    if clamp_weights:
        a = np.where((i0 < 0) | (i0 >= nodes - 1), np.float32(0.0), a).astype(np.float32)
    lo, hi = np.clip(i0, 0, nodes - 1), np.clip(i0 + 1, 0, nodes - 1)
    return lo, hi, (np.float32(1.0) - a).astype(np.float32), a


@inlined
def _fma(a: np.float32, b: np.float32, c: np.float32) -> np.float32:
    """a * b + c rounded once to float32 (the product is exact in float64; the sum's double rounding is ~1e-9
    likely): what OpenCV's fused multiply-adds give."""
    return np.float32(np.float64(a) * np.float64(b) + np.float64(c))


@kernel
def _warp_mean(
    radiance: NDArray[np.float32], near: NDArray[np.uint8], grids: NDArray[np.float32],
    col0: NDArray[np.int64], col1: NDArray[np.int64], colw0: NDArray[np.float32], colw1: NDArray[np.float32],
    row0: NDArray[np.int64], row1: NDArray[np.int64], roww0: NDArray[np.float32], roww1: NDArray[np.float32],
    k: int, out: NDArray[np.float32],
) -> None:  # fmt: skip
    """``out`` where ``near`` is set: the mean of the k warps of ``radiance`` by the shifts ``grids`` ((start,
    end), grid rows, grid columns, (x, y)) spread over the image as cv2.resize spreads them, each warp the
    identity map plus 2|u| times a shift (cv2.scaleAdd) sampled bilinearly with the border replicated
    (cv2.remap), in the order and the float32 operations OpenCV 5.1 uses."""
    h, w = radiance.shape
    inv_k = np.float32(1.0 / k)
    alphas = np.empty(k, dtype=np.float32)
    which = np.empty(k, dtype=np.int64)  # -1: the middle sample, the radiance itself; 0: towards start, 1: end
    for i in range(k):
        u = (i + 0.5) / k - 0.5
        alphas[i] = np.float32(2.0 * abs(u))
        which[i] = -1 if abs(u) < 1e-9 else (1 if u > 0 else 0)
    # cv2.resize's horizontal pass: each grid row spread over the image's columns.
    gs, gh = grids.shape[0], grids.shape[1]
    across = np.empty((gs, gh, w, 2), dtype=np.float32)
    for g in range(gs):
        for r in range(gh):
            for x in range(w):
                for c in range(2):
                    across[g, r, x, c] = grids[g, r, col0[x], c] * colw0[x] + grids[g, r, col1[x], c] * colw1[x]
    for y in range(h):
        r0, r1, rw0, rw1 = row0[y], row1[y], roww0[y], roww1[y]
        for x in range(w):
            if near[y, x] == 0:
                continue
            total = np.float32(0.0)
            for i in range(k):
                g = which[i]
                if g < 0:
                    total += radiance[y, x]
                    continue
                # Its vertical pass, then cv2.scaleAdd: the map's point.
                mx = _fma(across[g, r0, x, 0] * rw0 + across[g, r1, x, 0] * rw1, alphas[i], np.float32(x))
                my = _fma(across[g, r0, x, 1] * rw0 + across[g, r1, x, 1] * rw1, alphas[i], np.float32(y))
                fx, fy = math.floor(mx), math.floor(my)
                ax, ay = mx - np.float32(fx), my - np.float32(fy)
                x0, x1 = min(max(fx, 0), w - 1), min(max(fx + 1, 0), w - 1)
                y0, y1 = min(max(fy, 0), h - 1), min(max(fy + 1, 0), h - 1)
                a, b, c, d = radiance[y0, x0], radiance[y0, x1], radiance[y1, x0], radiance[y1, x1]
                upper = _fma(ax, b - a, a)
                lower = _fma(ax, d - c, c)
                total += _fma(ay, lower - upper, upper)
            out[y, x] = total * inv_k


@dataclass(frozen=True)
class _Streak:
    """Shifts (px, (N, 2)) of the blur grid's pixels from the middle image to the exposure's start and end, and
    the longest start-to-end streak, px."""

    start: NDArray[np.float64]
    end: NDArray[np.float64]
    length: float
