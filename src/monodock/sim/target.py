"""Simulated views of the diamond calibration target (``monodock.calibrate.target``) for tests and benches."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.calibrate.target import S_AXIS, T_AXIS, DiamondTarget, TargetView
from monodock.core import transforms
from monodock.core.pose import DockPose
from monodock.sim.world import INK_BLACK, PAPER_WHITE, Patch, Surface, World, rectangle

__all__ = ["render_target_views", "target_surface", "target_world"]


def target_surface(target: DiamondTarget, world_T_target: NDArray[np.float64], name: str = "diamond_target") -> Surface:
    """The board as a simulator surface with its markers, posed by ``world_T_target`` (4x4)."""

    R, t = world_T_target[:3, :3], world_T_target[:3, 3]
    left = R @ np.array([-target.half_diagonal, 0.0, 0.0]) + t
    surf = rectangle(name, left, R @ S_AXIS, R @ T_AXIS, target.side, target.side, PAPER_WHITE)
    d = target.aruco_dictionary()
    cells = int(d.markerSize) + 2
    patches = []
    for mid, (cs, ct) in zip(target.marker_ids, target.marker_centres, strict=True):
        bits = (cv2.aruco.generateImageMarker(d, mid, cells, borderBits=1) > 127).astype(np.float64)
        h = target.marker_size / 2.0
        values = INK_BLACK + bits * (PAPER_WHITE - INK_BLACK)
        patches.append(Patch(cs - h, ct - h, target.marker_size, target.marker_size, values))
    return surf.with_patches(*patches)


def target_world(target: DiamondTarget, base_T_target: NDArray[np.float64]) -> World:
    """A world of the target in front of a grey wall 4 m ahead, in base_link coordinates (robot at the origin)."""
    wall = rectangle("wall", (4.0, 6.0, 3.0), (0, -1, 0), (0, 0, -1), 12.0, 3.5, 0.5)
    return World((wall, target_surface(target, base_T_target)))


def render_target_views(
    sim: Any,
    target: DiamondTarget,
    count: int,
    *,
    seed: int,
    depth: tuple[float, float] = (0.6, 1.3),
    yaw_deg: float = 35.0,
    height_offset: tuple[float, float] = (0.22, 0.28),
) -> list[TargetView]:
    """Simulated views of the target at random poses in front of a robot standing at the world origin.

    The target stands upright ``depth`` metres ahead of the camera, turned up to ``yaw_deg`` about the
    vertical, laterally within the camera's view, its centre ``height_offset`` from the true laser height.

    Args:
        sim: a monodock.sim.Simulator (its robot, camera, nuisances and LiDAR are used).
        target: the board.
        count: how many views.
        seed: drives the poses and the sensors' noise.
    """
    rng = np.random.default_rng(seed)
    pose = DockPose(0.0, 0.0, 0.0)  # base_link == world
    laser_z = float(sim.robot.base_T_laser()[2, 3])
    cam_x = float(sim.robot.base_T_optical()[0, 3])
    hfov = math.atan2(sim.camera.width / 2.0, sim.camera.fx)
    views = []
    for k in range(count):
        x = cam_x + float(rng.uniform(*depth))
        lateral = (x - cam_x) * math.tan(hfov) - target.half_diagonal - 0.05
        y = float(rng.uniform(-1.0, 1.0)) * max(lateral, 0.0)
        z = laser_z + float(rng.uniform(*height_offset))
        yaw = math.radians(float(rng.uniform(-yaw_deg, yaw_deg)))
        # Target frame: x right (robot's -y), y up, z towards the robot (-x), turned by yaw about the vertical.
        R0 = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        base_T_target = transforms.transform(transforms.rotation_from_rpy(0.0, 0.0, yaw) @ R0, (x, y, z))
        world = target_world(target, base_T_target)
        vrng = np.random.default_rng([seed, k])
        image = sim.render(pose, world, vrng)
        scan = sim.scan(pose, world, float(k), vrng)
        views.append(TargetView(image, scan, base_T_target))
    return views
