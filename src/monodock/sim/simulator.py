"""The simulated robot at the charger: camera frames, LiDAR scans and their exact ground truth."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.core.scan import LaserScan
from monodock.sim.lidar import LidarModel, simulate_scan
from monodock.sim.nuisance import Nuisances, add_glare, apply_nuisances
from monodock.sim.render import render_radiance
from monodock.sim.scene import add_clutter, occluder_for
from monodock.sim.world import ChargerGeometry, RoomGeometry, World, build_dock_world

__all__ = ["FrameTruth", "PoseDistribution", "SimFrame", "Simulator"]


@dataclass(frozen=True)
class FrameTruth:
    """What the simulator knows exactly about one frame.

    Attributes:
        pose: the DockPose (dock in base_link).
        corners: each marker's true corners in pixels through the lens, ArUco order, shape (4, 2);
            NaN where a corner is behind the camera or far outside its field of view.
        in_view: whether all four corners of the marker fall inside the image.
        visible_fraction: share of the marker's face that the camera actually sees (in view, not occluded).
    """

    pose: DockPose
    corners: dict[str, NDArray[np.float64]]
    in_view: dict[str, bool]
    visible_fraction: dict[str, float]


@dataclass(frozen=True)
class SimFrame:
    """One simulated moment: the camera image (mono8), the LiDAR scan and the truth."""

    image: NDArray[np.uint8]
    scan: LaserScan
    truth: FrameTruth


@dataclass(frozen=True)
class PoseDistribution:
    """Where to put the robot: uniform in depth, lateral offset and yaw, kept only if markers are in view.

    ``depth`` is the papers' depth, measured from the camera: DockPose.x minus the camera mount's x.
    ``lateral`` is the DockPose y (the papers' K), ``yaw_deg`` the DockPose yaw.
    """

    depth: tuple[float, float] = (0.25, 2.50)
    lateral: tuple[float, float] = (-0.40, 0.40)
    yaw_deg: tuple[float, float] = (-30.0, 30.0)
    require_in_view: tuple[str, ...] = ("center",)
    margin_px: float = 3.0


@dataclass
class Simulator:
    """A charger in a room, a robot with a camera and a 2D LiDAR, and a seeded random generator."""

    layout: DockLayout = field(default_factory=DockLayout.default)
    camera: CameraModel = field(default_factory=CameraModel.default)
    robot: RobotConfig = field(default_factory=RobotConfig.default)
    nuisances: Nuisances = field(default_factory=Nuisances)
    lidar: LidarModel = field(default_factory=LidarModel)
    charger: ChargerGeometry = field(default_factory=ChargerGeometry)
    room: RoomGeometry = field(default_factory=RoomGeometry)
    seed: int = 0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        world = build_dock_world(self.layout, self.charger, self.room)
        if self.nuisances.clutter:
            world = add_clutter(world, self.layout, np.random.default_rng([self.seed, 1]))
        self.world: World = world

    # --- frames ---------------------------------------------------------------------------------

    def world_T_optical(self, pose: DockPose) -> NDArray[np.float64]:
        """Camera optical frame in the world (dock) frame for a robot at this DockPose."""
        return transforms.invert(pose.matrix()) @ self.robot.base_T_optical()

    def true_corners(self, pose: DockPose) -> dict[str, NDArray[np.float64]]:
        """Each marker's exact corner pixels (through the lens); NaN for corners the camera cannot see: behind
        it, or so far outside its field that the lens polynomial would fold them back into the image."""
        optical_T_world = transforms.invert(self.world_T_optical(pose))
        out = {}
        for role in self.layout.roles:
            p = transforms.apply(optical_T_world, self.layout.corners_in_dock(role))
            px = self.camera.project(p)
            px[~self.camera.in_view_field(p)] = np.nan
            out[role] = px
        return out

    def in_view(self, corners: NDArray[np.float64], margin_px: float = 0.0) -> bool:
        """Whether all four corners lie inside the image, ``margin_px`` from its border."""
        if not np.all(np.isfinite(corners)):
            return False
        lo = -0.5 + margin_px
        return bool(
            np.all(corners[:, 0] >= lo)
            and np.all(corners[:, 0] <= self.camera.width - 0.5 - margin_px)
            and np.all(corners[:, 1] >= lo)
            and np.all(corners[:, 1] <= self.camera.height - 0.5 - margin_px)
        )

    def _visible_fraction(self, world: World, pose: DockPose, role: str) -> float:
        """Share of a 9x9 grid of points on the marker that the camera sees unoccluded and inside the image."""
        T = self.world_T_optical(pose)
        centre = T[:3, 3]
        g = (np.arange(9) + 0.5) / 9 - 0.5
        ga, gb = np.meshgrid(g * self.layout.side(role), g * self.layout.side(role))
        grid = np.stack([ga.ravel(), gb.ravel(), np.zeros(ga.size)], axis=1)
        pts = transforms.apply(self.layout.dock_T_marker(role), grid)
        dirs = pts - centre
        dist = np.linalg.norm(dirs, axis=1)
        hits = world.cast(centre, dirs / dist[:, None])
        # The marker is painted on the face, or on a card of its own when it stands off the face or is tilted.
        names = {s.name for s in world.surfaces}
        face = world.surface_index(f"marker_{role}" if f"marker_{role}" in names else "charger_face")
        seen = (hits.surface == face) & (np.abs(hits.t - dist) < 1e-6)
        px = self.camera.project(transforms.apply(transforms.invert(T), pts))
        optical_z = transforms.apply(transforms.invert(T), pts)[:, 2]
        inside = (
            (optical_z > 0)
            & (px[:, 0] >= -0.5)
            & (px[:, 0] <= self.camera.width - 0.5)
            & (px[:, 1] >= -0.5)
            & (px[:, 1] <= self.camera.height - 0.5)
        )
        return float(np.mean(seen & inside))

    def sample_pose(
        self, dist: PoseDistribution | None = None, max_tries: int = 10_000, rng: np.random.Generator | None = None
    ) -> DockPose:
        """A DockPose from the distribution whose required markers are all in view.

        ``rng`` (default: the simulator's own) is the generator to draw from.
        """
        d = dist or PoseDistribution()
        g = rng or self.rng
        for _ in range(max_tries):
            depth = g.uniform(*d.depth)
            pose = DockPose(
                depth + self.robot.camera_mount.x,
                float(g.uniform(*d.lateral)),
                math.radians(float(g.uniform(*d.yaw_deg))),
            )
            corners = self.true_corners(pose)
            if all(self.in_view(corners[r], d.margin_px) for r in d.require_in_view):
                return pose
        raise RuntimeError("pose distribution never keeps the required markers in view; widen it")

    def render(
        self, pose: DockPose, world: World | None = None, rng: np.random.Generator | None = None
    ) -> NDArray[np.uint8]:
        """The camera image (mono8) for a robot at this DockPose, with the simulator's nuisances."""
        rng = rng or self.rng
        radiance = render_radiance(
            world or self.world,
            self.camera,
            self.world_T_optical(pose),
            supersample=self.nuisances.supersample,
        )
        # Drawn only when asked for: without glare the frame's random draws are what they always were.
        if self.nuisances.glare_probability > 0 and rng.random() < self.nuisances.glare_probability:
            quads = [c for c in self.true_corners(pose).values() if self.in_view(c)]
            radiance = add_glare(radiance, quads, rng)
        return apply_nuisances(radiance, self.nuisances, rng)

    def scan(
        self,
        pose: DockPose,
        world: World | None = None,
        stamp: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> LaserScan:
        """The LiDAR scan for a robot at this DockPose."""
        world_T_laser = transforms.invert(pose.matrix()) @ self.robot.base_T_laser()
        return simulate_scan(world or self.world, world_T_laser, self.lidar, rng or self.rng, stamp)

    def frame(self, pose: DockPose, stamp: float = 0.0, rng: np.random.Generator | None = None) -> SimFrame:
        """Image, scan and truth for one robot pose; an occluder is added with the configured chance.

        ``rng`` (default: the simulator's own) drives every random draw of this frame, so a frame can be
        reproduced on its own, in any process, from its seed.
        """
        rng = rng or self.rng
        world = self.world
        if self.nuisances.occluder_probability > 0 and rng.random() < self.nuisances.occluder_probability:
            world = world.with_surfaces(occluder_for(self.layout, self.world_T_optical(pose)[:3, 3], rng))
        corners = self.true_corners(pose)
        truth = FrameTruth(
            pose=pose,
            corners=corners,
            in_view={r: self.in_view(c) for r, c in corners.items()},
            visible_fraction={r: self._visible_fraction(world, pose, r) for r in self.layout.roles},
        )
        return SimFrame(self.render(pose, world, rng), self.scan(pose, world, stamp, rng), truth)
