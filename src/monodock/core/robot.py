"""The robot description: where the camera and the LiDAR sit on the base, and how big the robot is."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.config import load_yaml, write_text_atomic, yaml_text
from monodock.core.settings import Policy, from_mapping, setting, to_mapping
from monodock.errors import ConfigError

__all__ = ["Mount", "OdometryCalibration", "RobotConfig"]

# What a robot file may hold (docs/user-guide.md, "What every file may hold"): sensors within 5 m of base_link,
# angles within ±π, speeds a wheeled base can have.
MAX_MOUNT_OFFSET = 5.0
MAX_LINEAR_SPEED = 5.0  # m/s
MAX_ANGULAR_SPEED = 10.0  # rad/s
_OFFSET = (-MAX_MOUNT_OFFSET, MAX_MOUNT_OFFSET)
_ANGLE = (-math.pi, math.pi)


@dataclass(frozen=True)
class Mount:
    """A sensor body's pose in base_link: metres and URDF roll/pitch/yaw radians (pitch > 0 looks down).

    In a robot file x, y and z must be given; the angles default to 0.
    """

    x: float = setting(0.0, required=True, range=_OFFSET, unit="m")
    y: float = setting(0.0, required=True, range=_OFFSET, unit="m")
    z: float = setting(0.0, required=True, range=_OFFSET, unit="m")
    roll: float = setting(0.0, range=_ANGLE, unit="rad")
    pitch: float = setting(0.0, range=_ANGLE, unit="rad")
    yaw: float = setting(0.0, range=_ANGLE, unit="rad")

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


@dataclass(frozen=True)
class OdometryCalibration:
    """How the wheel odometry is off, as ``monodock calibrate mount`` measures it (the optional ``odometry`` key).

    Attributes:
        distance_scale: true distance per odometry distance (in the print's lengths: the camera's ruler).
        rotation_scale: true turn = (1 + this) x the odometry's turn (a track width's error), plus the drift.
        drift_per_m: heading error per metre driven, radians (unequal wheels).
    """

    distance_scale: float = setting(1.0, range=(0.8, 1.25))
    rotation_scale: float = setting(0.0, range=(-0.2, 0.2))
    drift_per_m: float = setting(0.0, range=(-0.5, 0.5), unit="rad/m")

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


# The papers' robot: camera 17 cm behind the front edge (the robot file's example, docs/user-guide.md).
_CAMERA_MOUNT = Mount(0.17, 0.0, 0.25)
_LASER_MOUNT = Mount(0.17, 0.0, 0.20)
_NO_ODOMETRY_ERROR = OdometryCalibration()


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
        odometry: how the wheel odometry is off (``calibrate mount``); none by default, and then not written.

    The robot file (docs/user-guide.md) is read by ``core.settings.from_mapping`` and written by ``to_mapping``: the
    mounts and front_offset must be given, the rest may be.
    """

    SETTINGS: ClassVar[Policy] = Policy(what="robot")

    camera_mount: Mount = setting(_CAMERA_MOUNT, required=True)
    laser_mount: Mount = setting(_LASER_MOUNT, required=True)
    front_offset: float = setting(0.34, required=True, range=(0.0, MAX_MOUNT_OFFSET), unit="m")
    max_linear_speed: float = setting(0.3, positive=True, range=(0.0, MAX_LINEAR_SPEED), unit="m/s")
    max_angular_speed: float = setting(1.0, positive=True, range=(0.0, MAX_ANGULAR_SPEED), unit="rad/s")
    odometry: OdometryCalibration = setting(_NO_ODOMETRY_ERROR, omit_default=True)

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
    def load(cls, path: str | os.PathLike[str]) -> RobotConfig:
        """Read a robot YAML file."""
        return from_mapping(cls, load_yaml(path, "robot"), str(path))

    def save(self, path: str | os.PathLike[str], *, force: bool = False) -> None:
        """Write the robot YAML atomically."""
        text = yaml_text(to_mapping(self), flow=None)
        write_text_atomic(Path(path), text, force=force)
