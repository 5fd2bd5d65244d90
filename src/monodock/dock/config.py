"""The docking config: the mission's gains, speeds, tolerances, time-outs and retries (``DockingConfig``), and
its file, one YAML mapping.

Each value is declared once, as a ``core.settings`` setting (unit, rule, what it is for); the file, the docking
node's ROS parameters (the flat names: ``cruise_speed``, ``planner.standoff``) and docs/docking.md's table follow
from that declaration. The file mirrors ``DockingConfig`` field by field, its nested sections (``planner``,
``track`` with its ``odometry``, ``measurement``, ``charging_offset``) as nested mappings. Every key is optional (a
missing one keeps its default) and every key must be known: a misspelt gain is refused, not ignored. Values are
checked for type, finiteness and a broad range (0 to MAX_NUMBER, counts to MAX_COUNT) when read and for their own
rules whenever a config is built; any error is one line naming the file and the key.
``monodock dock-sim --config`` and the docking node's parameters read the same schema.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from monodock.core.config import load_yaml, write_text_atomic, yaml_text
from monodock.core.pose2d import Pose2D
from monodock.core.settings import Policy, check_fields, from_mapping, section, setting, to_mapping
from monodock.dock.planner import PlannerConfig
from monodock.dock.pose_filter import FilterConfig, MeasurementNoise
from monodock.errors import ConfigError

__all__ = [
    "ChargingOffset",
    "DockingConfig",
    "docking_config_from_dict",
    "docking_config_to_dict",
    "load_docking_config",
    "save_docking_config",
]


# Every number of the config is a non-negative distance (m), speed, rate, time (s), gain, angle (°) or noise
# (a signed one for an offset): none is plausibly beyond these. The declarations hold the finer rules.
MAX_NUMBER = 10_000.0
MAX_COUNT = 1_000

# How the docking config's file is read (its sections too): every key optional and known, the broad ranges above,
# each setting's rule checked whenever a config is built, an error told with the key that causes it.
_POLICY = Policy(
    what="docking config",
    unknown="refuse",
    checks="construct",
    culprit=True,
    numbers=(0.0, MAX_NUMBER),
    counts=(0, MAX_COUNT),
    units_in_errors=False,
    live=True,  # each mission reads the config afresh: the node's parameters may change between missions
)


@dataclass(frozen=True)
class ChargingOffset:
    """Where base_link charges, against the nominal docked pose (front_offset before the face, on the dock's axis,
    square): x towards the charger, y left, metres; yaw_deg counter-clockwise. ``monodock teach`` measures it in the
    dock frame as this camera and layout see it, so that what is left of a layout's or a mount's bias at the face
    cancels there. All zero: dock at the nominal pose.
    """

    x: float = setting(
        0.0,
        unit="m",
        signed=True,
        help=(
            "the taught charging pose (`monodock teach`): base_link this much further towards the charger than the "
            "nominal docked pose"
        ),
    )
    y: float = setting(0.0, unit="m", signed=True, help="… this much to the dock's left")
    yaw_deg: float = setting(
        0.0,
        unit="°",
        signed=True,
        help="… turned this much counter-clockwise; every frame is read in the frame this docks in",
    )

    def __post_init__(self) -> None:
        if abs(self.x) > 0.2 or abs(self.y) > 0.2 or abs(self.yaw_deg) > 20.0:
            raise ConfigError(
                "docking config: charging_offset beyond 20 cm or 20 degrees of the nominal docked pose is not a "
                f"contact's tolerance but another dock, got x {self.x} y {self.y} yaw_deg {self.yaw_deg}"
            )

    def dock_T_target(self, front_offset: float) -> Pose2D:
        """The frame the mission docks in (docked there is (front_offset, 0, 0) as a DockPose), in the dock frame."""
        taught = Pose2D(-front_offset + self.x, self.y, math.radians(self.yaw_deg))
        return taught.compose(Pose2D(front_offset, 0.0, 0.0))


@dataclass(frozen=True)
class LimitSettings:
    """Speed and acceleration limits; the robot's own maxima cap these."""

    SETTINGS: ClassVar[Policy] = _POLICY

    control_period: float = setting(0.02, unit="s", positive=True, help="the control loop's period")
    cruise_speed: float = setting(0.20, unit="m/s", positive=True, help="speed on the legs to Point A")
    approach_speed: float = setting(0.12, unit="m/s", positive=True, help="Moving₃'s speed")
    turn_rate: float = setting(0.6, unit="rad/s", positive=True, help="largest turn rate")
    linear_accel: float = setting(0.4, unit="m/s²", positive=True, help="acceleration and braking limit")
    angular_accel: float = setting(1.5, unit="rad/s²", positive=True, help="angular acceleration limit")
    min_speed: float = setting(0.02, unit="m/s", help="smallest non-zero speed command (a real base stalls below)")
    min_turn_rate: float = setting(0.08, unit="rad/s", help="smallest non-zero turn command on the spot")
    creep_distance: float = setting(0.03, unit="m", help="the last distance before the face, at `min_speed`")
    stop_lead: float = setting(0.1, unit="s", help="stop this early for the command latency and the motors' lag")

    def __post_init__(self) -> None:
        check_fields(self)
        if self.min_speed > self.approach_speed:
            raise ConfigError("docking config: min_speed must not exceed approach_speed")


@dataclass(frozen=True)
class ApproachSettings:
    """Moving₃'s P-control (heading reference -atan(k_lateral * lateral error), turn rate k_heading * heading
    error), and turning and driving on odometry."""

    k_lateral: float = setting(4.0, unit="1/m", help="Moving₃: heading reference −atan(k_lateral · lateral error)")
    k_heading: float = setting(2.5, unit="1/s", help="Moving₃: turn rate per radian of heading error")
    max_correction_deg: float = setting(20.0, unit="°", help="Moving₃: largest heading reference")
    heading_only_gap: float = setting(0.12, unit="m", help="Moving₃: the lateral term fades out this close to the face")
    k_turn: float = setting(3.0, unit="1/s", help="turns on odometry: turn rate per radian left")
    turn_tolerance_deg: float = setting(0.3, unit="°", help="a turn is done within this")
    k_bearing: float = setting(2.0, unit="1/s", help="legs on odometry: turn rate per radian of bearing to the target")
    arrive_tolerance: float = setting(0.005, unit="m", help="a leg is done within this of its end")
    refine_while_moving: bool = setting(True, help="frames during Moving₁ and Moving₂ refine Point A and the turns")
    predicted_markers: bool = setting(
        True,
        help=(
            "once the dock is tracked, fit the markers the detector missed where the track predicts them "
            '(code bits verified; "Markers the detector misses")'
        ),
    )


@dataclass(frozen=True)
class SearchSettings:
    """Acquire and Calculate: finding the dock and the frames a plan is made from."""

    acquire: bool = setting(True, help="turn on the spot to find the dock when it is not in view")
    acquire_turn_rate: float = setting(0.3, unit="rad/s", help="that turn's rate")
    first_frame_wait: float = setting(0.5, unit="s", help="stand this long at the start for the first frames")
    reacquire_wait: float = setting(
        3.0, unit="s", non_negative=True, help="after a recovery, stand this long before turning to search"
    )
    acquire_max_turn_deg: float = setting(
        370.0,
        unit="°",
        help="give up searching after turning this far (`not-found`; `dock-lost` when it had seen the dock)",
    )
    calculate_frames: int = setting(
        9, range=(1, MAX_COUNT), unit="frames", help="Calculate's median is over this many frames"
    )
    center_tolerance_deg: float = setting(
        5.0, unit="°", help="fewer than three markers and the dock this far off the heading: face it first"
    )


@dataclass(frozen=True)
class FarApproachSettings:
    """The far approach: beyond far_distance from the face centre, or far_bearing_deg off the dock's axis, make for
    the staging point on the axis (staging_distance from the face) in legs of at most far_leg, then plan."""

    SETTINGS: ClassVar[Policy] = _POLICY

    far_approach: bool = setting(
        True, help="beyond `far_distance` or `far_bearing_deg`, make for the staging point first (the far approach)"
    )
    far_distance: float = setting(
        2.8, unit="m", positive=True, help="base_link farther than this from the face centre: the far approach"
    )
    far_bearing_deg: float = setting(
        50.0,
        unit="°",
        positive=True,
        help="base_link more than this off the dock's axis (seen from the face centre): the far approach",
    )
    staging_distance: float = setting(
        1.5,
        unit="m",
        positive=True,
        help="the far approach's goal: base_link this far before the face, on the axis (less than `far_distance`)",
    )
    far_leg: float = setting(
        1.2,
        unit="m",
        positive=True,
        help="the longest far-approach drive before the robot faces the dock and calculates again",
    )
    far_max_legs: int = setting(8, help="after this many legs still beyond the manoeuvre's range: `approach-stalled`")

    def __post_init__(self) -> None:
        check_fields(self)
        if self.staging_distance >= self.far_distance:
            raise ConfigError(
                f"docking config: staging_distance ({self.staging_distance:g} m) must be less than far_distance "
                f"({self.far_distance:g} m): the far approach must end where the manoeuvre takes over"
            )
        if self.far_bearing_deg > 90.0:
            raise ConfigError(f"docking config: far_bearing_deg must be at most 90, got {self.far_bearing_deg:g}")
        if self.far_max_legs < 1:
            raise ConfigError(f"docking config: far_max_legs must be at least 1, got {self.far_max_legs}")


@dataclass(frozen=True)
class SettleSettings:
    """Calculate's time-out, and standing still before a judgement."""

    calculate_timeout: float = setting(
        3.0, unit="s", help="Calculate takes what came in this long; nothing: re-acquire"
    )
    settle_speed: float = setting(0.005, unit="m/s", help="the odometry reads still below this (rad/s: 5 ×)")
    settle_timeout: float = setting(1.5, unit="s", help="a base that never reads still is taken as still after this")


@dataclass(frozen=True)
class RetrySettings:
    """The checkpoint's retry, the recovery and the docked tolerances."""

    checkpoint_gap: float = setting(0.25, unit="m", positive=True, help="the approach's checkpoint, front edge to face")
    retry_lateral: float = setting(0.02, unit="m", help="at the checkpoint, a larger lateral error retries")
    retry_heading_deg: float = setting(
        4.0, unit="°", help="at the checkpoint, a heading this far off the reference retries"
    )
    max_retries: int = setting(2, help="retries and recoveries together")
    recover_distance: float = setting(
        0.30, unit="m", positive=True, help="markers lost mid-approach: back off this far"
    )
    tolerance_lateral: float = setting(0.02, unit="m", help="docked: lateral error within this")
    tolerance_longitudinal: float = setting(0.02, unit="m", help="docked: gap (or overshoot) within this")
    tolerance_heading_deg: float = setting(
        3.0, unit="°", help="docked: heading within this (the papers report 3.07°: set 3.1 to accept it)"
    )


@dataclass(frozen=True)
class ChargingSettings:
    """Waiting for the charger, and re-seating on the contacts."""

    charge_timeout: float = setting(
        2.0, unit="s", non_negative=True, help="at the face, charging must be reported within this"
    )
    reseat_distance: float = setting(
        0.05, unit="m", positive=True, help="not charging: back off this far and drive in again"
    )
    reseat_push: float = setting(
        0.005, unit="m", non_negative=True, help="each re-seat drives this much farther in than the last"
    )
    max_reseats: int = setting(2, help="re-seats before `not-charging`")


@dataclass(frozen=True)
class ReverseSettings:
    """Reversing, bounded and watched."""

    max_reverse_speed: float = setting(0.10, unit="m/s", positive=True, help="fastest reverse")
    max_reverse_distance: float = setting(1.5, unit="m", positive=True, help="longest reverse leg")
    rear_safety_distance: float = setting(
        0.25, unit="m", non_negative=True, help="stop reversing short of anything this close behind the back edge"
    )
    blocked_timeout: float = setting(
        5.0, unit="s", non_negative=True, help="wait this long for the space behind to clear, then fail"
    )


@dataclass(frozen=True)
class WatchSettings:
    """What a mission watches: lost markers, its own time, the blind zone."""

    lost_timeout: float = setting(
        1.0, unit="s", non_negative=True, help="markers unseen this long mid-approach: recover"
    )
    mission_timeout: float = setting(120.0, unit="s", help="the whole mission's time limit")
    blind_margin: float = setting(0.04, unit="m", help="added to the computed blind zone")


@dataclass(frozen=True)
class DockingConfig:
    """Every gain, speed, acceleration, tolerance, time-out and retry count of docking (SI units, angles in degrees).

    The docking config file (``monodock.dock.config``, ``--config``) and the docking node's ROS parameters set
    these by name; docs/docking.md lists every field with its unit, default and what it does.
    """

    SETTINGS: ClassVar[Policy] = _POLICY

    planner: PlannerConfig = section(PlannerConfig, help="where Point A is")
    limits: LimitSettings = section(LimitSettings, key="")
    approach: ApproachSettings = section(ApproachSettings, key="")
    search: SearchSettings = section(SearchSettings, key="")
    far: FarApproachSettings = section(FarApproachSettings, key="")
    settle: SettleSettings = section(SettleSettings, key="")
    retry: RetrySettings = section(RetrySettings, key="")
    charging: ChargingSettings = section(ChargingSettings, key="")
    reverse: ReverseSettings = section(ReverseSettings, key="")
    watch: WatchSettings = section(WatchSettings, key="")
    track: FilterConfig = section(
        FilterConfig, help="the dock filter: odometry noise, gate, reset"
    )  # the dock filter: odometry noise, gate, reset
    measurement: MeasurementNoise = section(
        MeasurementNoise, help="a frame's error when it has no covariance of its own"
    )  # frames without a covariance
    charging_offset: ChargingOffset = section(
        ChargingOffset, help="the taught charging pose (monodock teach)"
    )  # the taught pose (monodock teach)

    def __post_init__(self) -> None:
        check_fields(self)  # every setting's declared rule (each section checks its own too: it is valid alone)
        if self.limits.min_speed > self.reverse.max_reverse_speed:
            raise ConfigError("docking config: min_speed must not exceed max_reverse_speed")
        longest = self.reverse.max_reverse_distance
        if self.retry.recover_distance > longest or self.charging.reseat_distance > longest:
            raise ConfigError(
                "docking config: recover_distance and reseat_distance must not exceed max_reverse_distance"
            )


def docking_config_from_dict(data: dict[str, Any], source: str = "docking config") -> DockingConfig:
    """A DockingConfig from a mapping (defaults for the keys it leaves out)."""
    return from_mapping(DockingConfig, data, source)


def load_docking_config(path: str | os.PathLike[str]) -> DockingConfig:
    """Read a docking config YAML file."""
    return docking_config_from_dict(load_yaml(path, "docking config"), str(path))


def docking_config_to_dict(config: DockingConfig) -> dict[str, Any]:
    """Every field of the config as a nested mapping (what a config file may hold)."""
    return to_mapping(config)


def save_docking_config(config: DockingConfig, path: str | os.PathLike[str], *, force: bool = False) -> None:
    """Write the config as YAML, atomically (refused over an existing file without ``force``)."""
    text = yaml_text(docking_config_to_dict(config))
    write_text_atomic(Path(path), text, force=force)
