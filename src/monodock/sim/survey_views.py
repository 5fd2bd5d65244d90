"""Simulated survey views of the dock: a person walking round it with a camera, or the robot on the floor.

``monodock calibrate layout`` surveys a dock from 10-40 views. A person photographs it from anywhere in front:
``handheld_poses`` draws cameras 0.35-1.3 m from the face's centre, within ±60° of its axis and from 15° below
to 45° above it, aimed at a point near the middle of the markers with a roll of up to ±15°, and keeps those that
see every marker whole. ``robot_poses`` puts the robot's camera on the floor in front of the dock (its mount
known), as a drive would. Each view renders through the simulator's camera, nuisances and world, so a tilted or
off-scale marker (the layout's optional keys) is seen as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.atomic import atomic_directory
from monodock.core.images import encode_png
from monodock.core.layout import ROLES
from monodock.core.pose import DockPose
from monodock.errors import ConfigError
from monodock.sim.nuisance import apply_nuisances
from monodock.sim.render import render_radiance
from monodock.sim.simulator import PoseDistribution, Simulator

__all__ = [
    "VIEW_KINDS",
    "SurveyShot",
    "handheld_poses",
    "render_shot",
    "robot_pose_of",
    "robot_poses",
    "write_view_folder",
]


@dataclass(frozen=True)
class SurveyShot:
    """One survey photograph: the camera's optical frame in the dock frame and the image (mono8)."""

    name: str
    world_T_optical: NDArray[np.float64]
    image: NDArray[np.uint8]


def _look_at(eye: NDArray[np.float64], target: NDArray[np.float64], roll: float) -> NDArray[np.float64]:
    """world_T_optical of a camera at ``eye`` looking at ``target`` (z forward, x right, y down), rolled."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z]) @ transforms.rotation_from_rpy(0.0, 0.0, roll)
    return transforms.transform(R, eye)


def _all_in_view(sim: Simulator, world_T_optical: NDArray[np.float64], margin_px: float) -> bool:
    optical_T_world = transforms.invert(world_T_optical)
    for role in ROLES:
        p = transforms.apply(optical_T_world, sim.layout.corners_in_dock(role))
        if not np.all(p[:, 2] > 0.05):
            return False
        if not sim.in_view(sim.camera.project(p), margin_px):
            return False
    return True


def handheld_poses(
    sim: Simulator,
    count: int,
    rng: np.random.Generator,
    *,
    distance: tuple[float, float] = (0.35, 1.3),
    bearing_deg: float = 60.0,
    elevation_deg: tuple[float, float] = (-15.0, 45.0),
    margin_px: float = 8.0,
) -> list[NDArray[np.float64]]:
    """``count`` camera poses (world_T_optical) of a person photographing the dock, every marker whole in view."""
    centre = np.mean([sim.layout.marker(r).centre() for r in ROLES], axis=0)
    poses: list[NDArray[np.float64]] = []
    for _ in range(200 * count):
        if len(poses) == count:
            break
        d = rng.uniform(*distance)
        bearing = math.radians(rng.uniform(-bearing_deg, bearing_deg))
        elevation = math.radians(rng.uniform(*elevation_deg))
        eye = centre + d * np.array(
            [-math.cos(elevation) * math.cos(bearing), math.cos(elevation) * math.sin(bearing), math.sin(elevation)]
        )
        if eye[2] < 0.05:  # not below the floor
            continue
        target = centre + rng.normal(0.0, 0.03, 3) * np.array([0.0, 1.0, 1.0])
        T = _look_at(eye, target, math.radians(rng.uniform(-15.0, 15.0)))
        if _all_in_view(sim, T, margin_px):
            poses.append(T)
    if len(poses) < count:
        raise RuntimeError(f"only {len(poses)} of {count} handheld views see every marker; widen the distance")
    return poses


def robot_poses(
    sim: Simulator, count: int, rng: np.random.Generator, *, depth: tuple[float, float] = (0.45, 1.6)
) -> list[NDArray[np.float64]]:
    """``count`` camera poses of the robot standing on the floor before the dock, every marker in view."""
    dist = PoseDistribution(depth=depth, lateral=(-0.5, 0.5), yaw_deg=(-35.0, 35.0), require_in_view=ROLES)
    return [sim.world_T_optical(sim.sample_pose(dist, rng=rng)) for _ in range(count)]


def render_shot(
    sim: Simulator, name: str, world_T_optical: NDArray[np.float64], rng: np.random.Generator
) -> SurveyShot:
    """One view rendered with the simulator's world, camera and nuisances."""
    radiance = render_radiance(sim.world, sim.camera, world_T_optical, supersample=sim.nuisances.supersample)
    return SurveyShot(name, world_T_optical, apply_nuisances(radiance, sim.nuisances, rng))


def robot_pose_of(sim: Simulator, world_T_optical: NDArray[np.float64]) -> DockPose:
    """The DockPose of the robot whose camera is at ``world_T_optical`` (a robot view's truth)."""
    world_T_base = world_T_optical @ transforms.invert(sim.robot.base_T_optical())
    return DockPose.from_matrix(transforms.invert(world_T_base))


VIEW_KINDS = ("handheld", "robot")


def write_view_folder(out: str | Path, sim: Simulator, kind: str, count: int, seed: int, *, force: bool = False) -> int:
    """``count`` survey views (``handheld`` or ``robot``) as a folder, atomically: ``images/view_NNN.png``,
    ``views.csv`` (each camera's optical frame in the dock frame: position and quaternion; for robot views the true
    DockPose too) and the camera, layout and robot files the views were rendered with (the world's truth)."""
    if kind not in VIEW_KINDS:
        raise ConfigError(f"survey views are {' or '.join(VIEW_KINDS)}, got {kind!r}")
    rng = np.random.default_rng([seed, 3])
    poses = handheld_poses(sim, count, rng) if kind == "handheld" else robot_poses(sim, count, rng)
    with atomic_directory(out, force=force) as tmp:
        (tmp / "images").mkdir()
        rows = ["view,kind,x_m,y_m,z_m,qx,qy,qz,qw,dock_x_m,dock_y_m,dock_yaw_deg"]
        for k, T in enumerate(poses):
            name = f"view_{k:03d}.png"
            shot = render_shot(sim, name, T, np.random.default_rng([seed, 4, k]))
            (tmp / "images" / name).write_bytes(encode_png(shot.image))
            qx, qy, qz, qw = transforms.quaternion_from_matrix(T[:3, :3])
            truth = robot_pose_of(sim, T) if kind == "robot" else None
            dock = f"{truth.x:.6f},{truth.y:.6f},{truth.yaw_deg:.5f}" if truth is not None else ",,"
            rows.append(
                f"{name},{kind},{T[0, 3]:.6f},{T[1, 3]:.6f},{T[2, 3]:.6f},{qx:.8f},{qy:.8f},{qz:.8f},{qw:.8f},{dock}"
            )
        (tmp / "views.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
        sim.camera.save(tmp / "camera.yaml")
        sim.layout.save(tmp / "layout.yaml")
        sim.robot.save(tmp / "robot.yaml")
    return len(poses)
