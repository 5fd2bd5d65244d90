"""A wrong world: a dock and a robot as a person builds them, not as their files say.

A printed dock is never exactly where its layout file says, nor a camera where the drawing put it. ``wrong_world``
draws, from a seed, what the issue of commissioning measures against (each independently, uniform):

- each marker ±3 mm in y and z, standing 0-3 mm off the face (never into it: its card clears the face, see
  ``sim.world.marker_card``), tilted ±2° about each axis, printed at 97-103 % of its side;
- the camera mount ±1.5 cm in x, y and z and ±1.5° in roll, pitch and yaw;
- the charging contacts ±1 cm from ``front_offset`` (the robot charges with its front edge there);
- the wheels' radii, as the simulated base draws them (``DiffDriveConfig.wheel_scale_sd``), fixed for the world.

The nominal files are what the user has; the true ones are what the simulator renders and drives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from monodock.core.layout import DockLayout, MarkerSpec
from monodock.core.robot import Mount, RobotConfig
from monodock.sim.diffdrive import DiffDriveConfig

__all__ = ["WorldErrors", "WrongWorld", "wrong_world"]


@dataclass(frozen=True)
class WorldErrors:
    """The size of each error (uniform in ± this): metres, radians, relative."""

    marker_position: float = 0.003
    marker_standoff: float = 0.003
    marker_tilt: float = math.radians(2.0)
    print_scale: float = 0.03
    mount_position: float = 0.015
    mount_angle: float = math.radians(1.5)
    contacts: float = 0.01


@dataclass(frozen=True)
class WrongWorld:
    """The nominal files, the true ones, and the wheels of one world."""

    seed: int
    nominal_layout: DockLayout
    nominal_robot: RobotConfig
    layout: DockLayout
    robot: RobotConfig
    wheel_scale: tuple[float, float]


def wrong_world(
    seed: int,
    nominal_layout: DockLayout | None = None,
    nominal_robot: RobotConfig | None = None,
    errors: WorldErrors | None = None,
) -> WrongWorld:
    """The world of ``seed``: the nominal files with every error drawn."""
    layout = nominal_layout or DockLayout.default()
    robot = nominal_robot or RobotConfig.default()
    e = errors or WorldErrors()
    rng = np.random.default_rng([seed, 26])
    markers = []
    for m in layout.markers:
        roll, pitch, yaw = rng.uniform(-e.marker_tilt, e.marker_tilt, 3)
        side = layout.side(m.role) * float(rng.uniform(1.0 - e.print_scale, 1.0 + e.print_scale))
        # The card leans out of the face by its tilt: it stands off far enough to clear it, then some.
        clear = 0.5 * side * (abs(math.sin(pitch)) + abs(math.sin(yaw))) * (1.0 + 1.5 * 2 / layout.modules) + 2e-4
        markers.append(
            MarkerSpec(
                m.role,
                m.id,
                m.y + float(rng.uniform(-e.marker_position, e.marker_position)),
                m.z + float(rng.uniform(-e.marker_position, e.marker_position)),
                m.x - clear - float(rng.uniform(0.0, e.marker_standoff)),
                m.roll + float(roll),
                m.pitch + float(pitch),
                m.yaw + float(yaw),
                side,
            )
        )
    true_layout = replace(layout, markers=tuple(markers))
    c = robot.camera_mount
    dp = rng.uniform(-e.mount_position, e.mount_position, 3)
    da = rng.uniform(-e.mount_angle, e.mount_angle, 3)
    mount = Mount(
        *(float(v) for v in (c.x + dp[0], c.y + dp[1], c.z + dp[2], c.roll + da[0], c.pitch + da[1], c.yaw + da[2]))
    )
    front = robot.front_offset + float(rng.uniform(-e.contacts, e.contacts))
    true_robot = replace(robot, camera_mount=mount, front_offset=front)
    wheels = 1.0 + rng.normal(0.0, DiffDriveConfig().wheel_scale_sd, 2)
    return WrongWorld(seed, layout, robot, true_layout, true_robot, (float(wheels[0]), float(wheels[1])))
