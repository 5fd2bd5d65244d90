"""The robot description: where the camera and the LiDAR sit on the base, and how big the robot is."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.config import Fields, load_yaml, write_text_atomic, yaml_text
from monodock.errors import ConfigError

__all__ = ["Mount", "OdometryCalibration", "RobotConfig"]


@dataclass(frozen=True)
class Mount:
    """A sensor body's pose in base_link: metres and URDF roll/pitch/yaw radians (pitch > 0 looks down)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    def matrix(self) -> NDArray[np.float64]:
        """base_T_sensor as a 4x4 transform."""
        return transforms.transform(
            transforms.rotation_from_rpy(self.roll, self.pitch, self.yaw), (self.x, self.y, self.z)
        )

    @classmethod
    def from_matrix(cls, T: NDArray[np.float64]) -> Mount:
        """The mount of a base_T_sensor 4x4 transform."""
        r, p, y = transforms.rpy_from_rotation(T[:3, :3])
        return cls(float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), r, p, y)

    @classmethod
    def from_fields(cls, f: Fields) -> Mount:
        """A mount from its mapping: x, y, z within MAX_MOUNT_OFFSET metres, angles within ±π (default 0)."""
        position = [f.number(k, within=(-MAX_MOUNT_OFFSET, MAX_MOUNT_OFFSET), unit="m") for k in ("x", "y", "z")]
        angles = [f.number(k, 0.0, within=(-math.pi, math.pi), unit="rad") for k in ("roll", "pitch", "yaw")]
        f.warn_unknown(_MOUNT_KEYS)
        return cls(*position, *angles)

    def to_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in _MOUNT_KEYS}


_MOUNT_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")

# What a robot file may hold (docs/user-guide.md, "What every file may hold"): sensors within 5 m of base_link,
# angles within ±π, speeds a wheeled base can have.
MAX_MOUNT_OFFSET = 5.0
MAX_LINEAR_SPEED = 5.0  # m/s
MAX_ANGULAR_SPEED = 10.0  # rad/s


_ROBOT_KEYS = ("camera_mount", "laser_mount", "front_offset", "max_linear_speed", "max_angular_speed", "odometry")
_ODOMETRY_KEYS = ("distance_scale", "rotation_scale", "drift_per_m")


@dataclass(frozen=True)
class OdometryCalibration:
    """How the wheel odometry is off, as ``monodock calibrate mount`` measures it (the optional ``odometry`` key).

    Attributes:
        distance_scale: true distance per odometry distance (in the print's lengths: the camera's ruler).
        rotation_scale: true turn = (1 + this) x the odometry's turn (a track width's error), plus the drift.
        drift_per_m: heading error per metre driven, radians (unequal wheels).
    """

    distance_scale: float = 1.0
    rotation_scale: float = 0.0
    drift_per_m: float = 0.0

    @property
    def identity(self) -> bool:
        return self == OdometryCalibration()

    def corrected(self, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        """Odometry poses (N, 3: x, y, yaw) re-integrated from their increments with the errors taken out, from the
        first pose: what the wheels really did."""
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if self.identity or len(p) < 2:
            return p.copy()
        yaw = np.unwrap(p[:, 2])
        dth = np.diff(yaw)
        mid = yaw[:-1] + 0.5 * dth
        dx, dy = np.diff(p[:, 0]), np.diff(p[:, 1])
        ds = self.distance_scale * (dx * np.cos(mid) + dy * np.sin(mid))
        dl = self.distance_scale * (-dx * np.sin(mid) + dy * np.cos(mid))
        dth = (1.0 + self.rotation_scale) * dth + self.drift_per_m * ds
        new_yaw = yaw[0] + np.concatenate([[0.0], np.cumsum(dth)])
        m = new_yaw[:-1] + 0.5 * dth
        x = p[0, 0] + np.concatenate([[0.0], np.cumsum(ds * np.cos(m) - dl * np.sin(m))])
        y = p[0, 1] + np.concatenate([[0.0], np.cumsum(ds * np.sin(m) + dl * np.cos(m))])
        return np.column_stack([x, y, new_yaw])

    @classmethod
    def from_fields(cls, f: Fields) -> OdometryCalibration:
        out = cls(
            f.number("distance_scale", 1.0, within=(0.8, 1.25)),
            f.number("rotation_scale", 0.0, within=(-0.2, 0.2)),
            f.number("drift_per_m", 0.0, within=(-0.5, 0.5), unit="rad/m"),
        )
        f.warn_unknown(_ODOMETRY_KEYS)
        return out

    def to_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in _ODOMETRY_KEYS}


@dataclass(frozen=True)
class RobotConfig:
    """Sensor mounts in base_link, the distance from base_link to the front edge, and speed limits.

    Attributes:
        camera_mount: pose of ``camera_link`` (x forward, y left, z up); the optical frame follows by
            the fixed REP 103 rotation.
        laser_mount: pose of the 2D LiDAR's ``laser`` frame.
        front_offset: base_link to the robot's front edge, metres; docked means DockPose (front_offset, 0, 0).
        max_linear_speed: m/s.
        max_angular_speed: rad/s.
        odometry: how the wheel odometry is off (``calibrate mount``); none by default.
    """

    camera_mount: Mount = Mount(0.17, 0.0, 0.25)
    laser_mount: Mount = Mount(0.17, 0.0, 0.20)
    front_offset: float = 0.34
    max_linear_speed: float = 0.3
    max_angular_speed: float = 1.0
    odometry: OdometryCalibration = OdometryCalibration()

    def __post_init__(self) -> None:
        if self.front_offset < 0:
            raise ConfigError(f"front_offset must not be negative, got {self.front_offset}")

    @classmethod
    def default(cls) -> RobotConfig:
        """The papers' robot: camera 17 cm behind the front edge (the robot file's example, docs/user-guide.md)."""
        return cls()

    def base_T_camera_link(self) -> NDArray[np.float64]:
        """Pose of camera_link in base_link."""
        return self.camera_mount.matrix()

    def base_T_optical(self) -> NDArray[np.float64]:
        """Pose of the camera's optical frame (z forward, x right, y down) in base_link."""
        T = self.camera_mount.matrix()
        T[:3, :3] = T[:3, :3] @ transforms.LINK_R_OPTICAL
        return T

    def base_T_laser(self) -> NDArray[np.float64]:
        """Pose of the laser frame in base_link."""
        return self.laser_mount.matrix()

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "robot") -> RobotConfig:
        """Build from the robot YAML mapping (docs/user-guide.md); errors name the field."""
        f = Fields(data, source)
        d = cls()
        try:
            robot = cls(
                camera_mount=Mount.from_fields(f.child("camera_mount")),
                laser_mount=Mount.from_fields(f.child("laser_mount")),
                front_offset=f.number("front_offset", within=(0.0, MAX_MOUNT_OFFSET), unit="m"),
                max_linear_speed=f.number(
                    "max_linear_speed", d.max_linear_speed, positive=True, within=(0.0, MAX_LINEAR_SPEED), unit="m/s"
                ),
                max_angular_speed=f.number(
                    "max_angular_speed",
                    d.max_angular_speed,
                    positive=True,
                    within=(0.0, MAX_ANGULAR_SPEED),
                    unit="rad/s",
                ),
                odometry=OdometryCalibration.from_fields(f.child("odometry"))
                if f.has("odometry")
                else OdometryCalibration(),
            )
            f.warn_unknown(_ROBOT_KEYS)
            return robot
        except ConfigError as exc:
            if str(exc).startswith(source):
                raise
            raise ConfigError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> RobotConfig:
        """Read a robot YAML file."""
        return cls.from_dict(load_yaml(path, "robot"), str(path))

    def to_dict(self) -> dict[str, Any]:
        """The robot YAML mapping (docs/user-guide.md)."""
        return {
            "camera_mount": self.camera_mount.to_dict(),
            "laser_mount": self.laser_mount.to_dict(),
            "front_offset": self.front_offset,
            "max_linear_speed": self.max_linear_speed,
            "max_angular_speed": self.max_angular_speed,
            **({} if self.odometry.identity else {"odometry": self.odometry.to_dict()}),
        }

    def save(self, path: str | os.PathLike[str], *, force: bool = False) -> None:
        """Write the robot YAML atomically."""
        text = yaml_text(self.to_dict(), flow=None)
        write_text_atomic(Path(path), text, force=force)
