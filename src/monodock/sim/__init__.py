"""The simulator: an exact camera and 2D LiDAR view of the charger, with ground truth."""

from __future__ import annotations

from monodock.sim.lidar import LidarModel, simulate_scan
from monodock.sim.nuisance import Nuisances, apply_nuisances
from monodock.sim.render import render_radiance
from monodock.sim.simulator import FrameTruth, PoseDistribution, SimFrame, Simulator
from monodock.sim.world import ChargerGeometry, Patch, RoomGeometry, Surface, World, build_dock_world

__all__ = [
    "ChargerGeometry",
    "FrameTruth",
    "LidarModel",
    "Nuisances",
    "Patch",
    "PoseDistribution",
    "RoomGeometry",
    "SimFrame",
    "Simulator",
    "Surface",
    "World",
    "apply_nuisances",
    "build_dock_world",
    "render_radiance",
    "simulate_scan",
]
