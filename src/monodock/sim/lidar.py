"""A 2D LiDAR by ray casting in the laser's scan plane, with sensor_msgs/LaserScan semantics."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from monodock.core.scan import LaserScan
from monodock.sim.world import World

__all__ = [
    "LidarModel",
    "simulate_scan",
]


@dataclass(frozen=True)
class LidarModel:
    """Knobs of the simulated 2D LiDAR (defaults: an RPLIDAR-class 360 degree scanner)."""

    angle_min: float = -math.pi
    angle_increment: float = math.radians(0.5)
    beams: int = 720
    range_min: float = 0.12
    range_max: float = 12.0
    range_noise: float = 0.01
    dropout: float = 0.01
    scan_time: float = 0.1
    frame_id: str = "laser"

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * (self.beams - 1)


def simulate_scan(
    world: World,
    world_T_laser: ArrayLike,
    model: LidarModel,
    rng: np.random.Generator,
    stamp: float = 0.0,
) -> LaserScan:
    """Cast the model's beams from the laser's pose in the world and return the noisy scan."""
    T = np.asarray(world_T_laser, dtype=np.float64)
    a = model.angle_min + model.angle_increment * np.arange(model.beams)
    dirs_laser = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    hits = world.cast(T[:3, 3], dirs_laser @ T[:3, :3].T)
    r = hits.t.copy()
    if model.range_noise > 0:
        r = r + rng.normal(0.0, model.range_noise, r.shape)
    r[~np.isfinite(hits.t) | (r > model.range_max)] = np.inf
    r[r < model.range_min] = -np.inf
    if model.dropout > 0:
        r[rng.random(r.shape) < model.dropout] = np.nan
    return LaserScan(
        stamp=stamp,
        frame_id=model.frame_id,
        angle_min=model.angle_min,
        angle_max=model.angle_max,
        angle_increment=model.angle_increment,
        time_increment=model.scan_time / model.beams,
        scan_time=model.scan_time,
        range_min=model.range_min,
        range_max=model.range_max,
        ranges=r.astype(np.float32),
    )
