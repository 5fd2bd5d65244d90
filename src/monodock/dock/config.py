"""The docking config: the mission's gains, speeds, tolerances, time-outs and retries (``DockingConfig``), and
its file, one YAML mapping.

The file mirrors ``DockingConfig`` field by field, its nested sections (``planner``, ``track`` with its
``odometry``, ``measurement``) as nested mappings. Every key is optional (a missing one keeps its default) and
every key must be known: a misspelt gain is refused, not ignored. Values are checked for type, finiteness and
a broad range (0 to MAX_NUMBER, counts to MAX_COUNT) here and for their own rules by the dataclasses; any error
is one line naming the file and the key.
``monodock dock-sim --config`` and the docking node's parameters read the same schema.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from monodock.core.config import Fields, load_yaml, write_text_atomic, yaml_text
from monodock.core.pose2d import Pose2D
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


@dataclass(frozen=True)
class ChargingOffset:
    """Where base_link charges, against the nominal docked pose (front_offset before the face, on the dock's axis,
    square): x towards the charger, y left, metres; yaw_deg counter-clockwise. ``monodock teach`` measures it in the
    dock frame as this camera and layout see it, so that what is left of a layout's or a mount's bias at the face
    cancels there. All zero: dock at the nominal pose.
    """

    SIGNED: ClassVar[tuple[str, ...]] = ("x", "y", "yaw_deg")

    x: float = 0.0
    y: float = 0.0
    yaw_deg: float = 0.0

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
class DockingConfig:
    """Every gain, speed, acceleration, tolerance, time-out and retry count of docking (SI units, angles in degrees).

    The docking config file (``monodock.dock.config``, ``--config``) and the docking node's ROS parameters set
    these by name; docs/docking.md lists every field with its unit, default and what it does.
    """

    planner: PlannerConfig = field(default_factory=PlannerConfig)
    control_period: float = 0.02
    # Speed and acceleration limits; the robot's own maxima cap these.
    cruise_speed: float = 0.20
    approach_speed: float = 0.12
    turn_rate: float = 0.6
    linear_accel: float = 0.4
    angular_accel: float = 1.5
    min_speed: float = 0.02  # below this a real base's wheels stall; a non-zero command is never smaller
    min_turn_rate: float = 0.08
    creep_distance: float = 0.03  # the last metres at min_speed
    stop_lead: float = 0.1  # seconds: stop this early for the command latency and the motors' lag
    # Moving₃'s P-control: heading reference -atan(k_lateral * lateral error), turn rate k_heading * heading error.
    k_lateral: float = 4.0
    k_heading: float = 2.5
    max_correction_deg: float = 20.0
    heading_only_gap: float = 0.12  # closer than this the lateral term fades out: arrive square
    # Turning and driving on odometry.
    k_turn: float = 3.0
    turn_tolerance_deg: float = 0.3
    k_bearing: float = 2.0
    arrive_tolerance: float = 0.005
    refine_while_moving: bool = True  # frames during Moving₁ and Moving₂ refine Point A and the turns
    # Once the dock is tracked, look for the markers the detector missed where the track puts them
    # (perception.predicted: fitted in the image, code bits verified).
    predicted_markers: bool = True
    # Acquire and calculate.
    acquire: bool = True
    acquire_turn_rate: float = 0.3
    first_frame_wait: float = 0.5
    reacquire_wait: float = 3.0  # after losing the markers: stand and look this long before turning to search
    acquire_max_turn_deg: float = 370.0
    calculate_frames: int = 9
    center_tolerance_deg: float = 5.0
    # The far approach: beyond far_distance from the face centre, or far_bearing_deg off the dock's axis, make for
    # the staging point on the axis (staging_distance from the face) in legs of at most far_leg, then plan.
    far_approach: bool = True
    far_distance: float = 2.8
    far_bearing_deg: float = 50.0
    staging_distance: float = 1.5
    far_leg: float = 1.2
    far_max_legs: int = 8
    calculate_timeout: float = 3.0
    settle_speed: float = 0.005
    settle_timeout: float = 1.5
    # Retry, recovery and tolerances.
    checkpoint_gap: float = 0.25  # end of Moving₃'s early part: front edge this far from the face
    retry_lateral: float = 0.02
    retry_heading_deg: float = 4.0  # off the P-controller's heading reference
    max_retries: int = 2  # retries and recoveries together
    recover_distance: float = 0.30  # markers lost mid-approach: back off this far before looking again
    tolerance_lateral: float = 0.02
    tolerance_longitudinal: float = 0.02
    tolerance_heading_deg: float = 3.0
    # Charging.
    charge_timeout: float = 2.0  # at the face: the charger must report charging within this
    reseat_distance: float = 0.05  # not charging: back off this far and drive in again
    reseat_push: float = 0.005  # each re-seat drives this much farther in than the last (the contacts' springs)
    max_reseats: int = 2
    # Safety.
    max_reverse_speed: float = 0.10
    max_reverse_distance: float = 1.5  # no reverse leg is longer
    rear_safety_distance: float = 0.25  # stop reversing short of anything this close behind the back edge
    blocked_timeout: float = 5.0  # wait this long for the space behind to clear, then fail
    lost_timeout: float = 1.0
    mission_timeout: float = 120.0
    blind_margin: float = 0.04
    track: FilterConfig = field(default_factory=FilterConfig)  # the dock filter: odometry noise, gate, reset
    measurement: MeasurementNoise = field(default_factory=MeasurementNoise)  # frames without a covariance
    charging_offset: ChargingOffset = field(default_factory=ChargingOffset)  # the taught pose (monodock teach)

    def __post_init__(self) -> None:
        positive = (
            "control_period",
            "cruise_speed",
            "approach_speed",
            "turn_rate",
            "linear_accel",
            "angular_accel",
            "max_reverse_speed",
            "max_reverse_distance",
            "recover_distance",
            "reseat_distance",
            "far_distance",
            "far_bearing_deg",
            "staging_distance",
            "far_leg",
            "checkpoint_gap",  # at or behind the face it is never passed before contact: no retry would ever start
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"docking config: {name} must be positive, got {getattr(self, name)}")
        not_negative = (
            "rear_safety_distance",
            "blocked_timeout",
            "charge_timeout",
            "reacquire_wait",
            "lost_timeout",
            "reseat_push",
        )
        for name in not_negative:
            if not getattr(self, name) >= 0:
                raise ConfigError(f"docking config: {name} must not be negative, got {getattr(self, name)}")
        if self.staging_distance >= self.far_distance:
            raise ConfigError(
                f"docking config: staging_distance ({self.staging_distance:g} m) must be less than far_distance "
                f"({self.far_distance:g} m): the far approach must end where the manoeuvre takes over"
            )
        if self.far_bearing_deg > 90.0:
            raise ConfigError(f"docking config: far_bearing_deg must be at most 90, got {self.far_bearing_deg:g}")
        if self.far_max_legs < 1:
            raise ConfigError(f"docking config: far_max_legs must be at least 1, got {self.far_max_legs}")
        if self.min_speed > self.approach_speed:
            raise ConfigError("docking config: min_speed must not exceed approach_speed")
        if self.min_speed > self.max_reverse_speed:
            raise ConfigError("docking config: min_speed must not exceed max_reverse_speed")
        if self.recover_distance > self.max_reverse_distance or self.reseat_distance > self.max_reverse_distance:
            raise ConfigError(
                "docking config: recover_distance and reseat_distance must not exceed max_reverse_distance"
            )


D = TypeVar("D")

# Every number of the config is a non-negative distance (m), speed, rate, time (s), gain, angle (°) or noise:
# none is plausibly beyond these. The dataclasses check the finer rules.
MAX_NUMBER = 10_000.0
MAX_COUNT = 1_000


def _from_fields(cls: type[D], f: Fields) -> D:
    """An instance of the dataclass ``cls`` from a mapping: known keys typed like their defaults, others refused."""
    defaults = cls()
    known = {x.name: x for x in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in f.data if k not in known)
    if unknown:
        raise f.error(unknown[0], f"unknown key (known: {', '.join(known)})")
    values: dict[str, Any] = {}
    signed = getattr(cls, "SIGNED", ())
    for name in known:
        if not f.has(name):
            continue
        default = getattr(defaults, name)
        if dataclasses.is_dataclass(default):
            values[name] = _from_fields(type(default), f.child(name))
        elif isinstance(default, bool):
            value = f.raw(name)
            if not isinstance(value, bool):
                raise f.error(name, f"expected true or false, got {value!r}")
            values[name] = value
        elif isinstance(default, int):
            values[name] = f.integer(name, minimum=0, maximum=MAX_COUNT)
        elif isinstance(default, float):
            values[name] = f.number(name, within=(-MAX_NUMBER if name in signed else 0.0, MAX_NUMBER))
        elif isinstance(default, str):
            values[name] = f.string(name)
        else:  # pragma: no cover - every DockingConfig field is one of the above
            raise f.error(name, f"cannot be set from a file ({type(default).__name__})")
    try:
        return dataclasses.replace(defaults, **values)  # type: ignore[type-var]
    except ConfigError as exc:
        raise ConfigError(
            f"{f.source}: {_culprit(defaults, values, f)}{str(exc).removeprefix('docking config: ')}"
        ) from None


def _culprit(defaults: Any, values: dict[str, Any], f: Fields) -> str:
    """``key: `` of the one value that the dataclass's own check refuses on its own, else nothing: the checks
    in ``__post_init__`` know the rule but not the file's key."""
    for name, value in values.items():
        try:
            dataclasses.replace(defaults, **{name: value})
        except ConfigError:
            return f"{f.prefix}{name}: "
    return ""


def docking_config_from_dict(data: dict[str, Any], source: str = "docking config") -> DockingConfig:
    """A DockingConfig from a mapping (defaults for the keys it leaves out)."""
    return _from_fields(DockingConfig, Fields(data, source))


def load_docking_config(path: str | os.PathLike[str]) -> DockingConfig:
    """Read a docking config YAML file."""
    return docking_config_from_dict(load_yaml(path, "docking config"), str(path))


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"docking config: cannot write a non-finite value ({value})")
    return value


def docking_config_to_dict(config: DockingConfig) -> dict[str, Any]:
    """Every field of the config as a nested mapping (what a config file may hold)."""
    out = _plain(config)
    assert isinstance(out, dict)
    return out


def save_docking_config(config: DockingConfig, path: str | os.PathLike[str], *, force: bool = False) -> None:
    """Write the config as YAML, atomically (refused over an existing file without ``force``)."""
    text = yaml_text(docking_config_to_dict(config))
    write_text_atomic(Path(path), text, force=force)
