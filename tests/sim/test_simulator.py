"""The simulator over the whole pose envelope of the issue, and its seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core import transforms
from monodock.core.pose import DockPose
from monodock.sim import Nuisances, PoseDistribution, RoomGeometry, Simulator


@pytest.mark.parametrize(
    ("depth", "yaw_deg"),
    [(0.2, 0.0), (0.2, 60.0), (3.0, -60.0), (3.0, 60.0), (1.5, -60.0)],
)
def test_envelope_frames_are_consistent(depth: float, yaw_deg: float) -> None:
    """At the edges of 0.2-3 m and +-60 deg, the frame renders and its truth matches the geometry.

    The ground-truth corners must be the projection of the layout's corners, and the LiDAR beam
    straight ahead must return the distance to the charger face (or the wall behind) along that beam.
    """
    sim = Simulator(nuisances=Nuisances.clean(), seed=1)
    sim.lidar = type(sim.lidar)(range_noise=0.0, dropout=0.0)
    pose = DockPose(depth + sim.robot.camera_mount.x, 0.0, math.radians(yaw_deg))
    frame = sim.frame(pose)
    assert frame.image.shape == (sim.camera.height, sim.camera.width)
    optical_T_dock = transforms.invert(sim.world_T_optical(pose))
    p = transforms.apply(optical_T_dock, sim.layout.corners_in_dock("center"))
    # Corners the camera can see are exact projections; the others (behind it, or so far out of the field
    # that the lens polynomial would fold them into the picture) are NaN.
    seen = sim.camera.in_view_field(p)
    c = frame.truth.corners["center"]
    np.testing.assert_allclose(c[seen], sim.camera.project(p[seen]), atol=1e-9)
    assert np.all(np.isnan(c[~seen]))
    assert np.all(np.isfinite(c[seen]))
    # The forward beam (angle 0) of the laser: where does it meet the plane x = 0 of the dock?
    world_T_laser = transforms.invert(pose.matrix()) @ sim.robot.base_T_laser()
    origin, heading = world_T_laser[:3, 3], world_T_laser[:3, 0]
    i0 = int(round(-sim.lidar.angle_min / sim.lidar.angle_increment))
    r = float(frame.scan.ranges[i0])
    t = -origin[0] / heading[0]
    hit = origin + t * heading
    if abs(hit[1]) < 0.29:  # on the charger face
        assert r == pytest.approx(t, abs=1e-5)
    else:
        assert r > t - 1e-5  # past the face's plane: the box side or the wall behind


def test_frames_reproduce_from_their_seed() -> None:
    """Same seed, same image and scan; another seed, other noise."""
    pose = DockPose(1.2, 0.05, math.radians(8.0))
    a = Simulator(seed=5).frame(pose, rng=np.random.default_rng([5, 0]))
    b = Simulator(seed=5).frame(pose, rng=np.random.default_rng([5, 0]))
    c = Simulator(seed=5).frame(pose, rng=np.random.default_rng([5, 1]))
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.scan.ranges, b.scan.ranges)
    assert np.any(a.image != c.image)


def test_pose_distribution_keeps_marker_2_in_view() -> None:
    """Every sampled pose has marker 2 fully in the image, and stays in the requested ranges."""
    sim = Simulator(seed=3)
    dist = PoseDistribution()
    for _ in range(200):
        pose = sim.sample_pose(dist)
        depth = pose.x - sim.robot.camera_mount.x
        assert dist.depth[0] <= depth <= dist.depth[1]
        assert dist.lateral[0] <= pose.y <= dist.lateral[1]
        assert abs(math.degrees(pose.yaw)) <= 30.0
        assert sim.in_view(sim.true_corners(pose)["center"], dist.margin_px)


def test_side_walls_are_seen_by_the_lidar() -> None:
    """With side walls 1 m from the axis, the beam to the left ends on the wall at 1 m."""
    sim = Simulator(nuisances=Nuisances.clean(), room=RoomGeometry(side_walls=1.0), seed=0)
    sim.lidar = type(sim.lidar)(range_noise=0.0, dropout=0.0)
    pose = DockPose(1.5, 0.0, 0.0)  # robot on the axis, facing the charger
    scan = sim.scan(pose)
    left = int(round((math.pi / 2 - sim.lidar.angle_min) / sim.lidar.angle_increment))
    assert float(scan.ranges[left]) == pytest.approx(1.0 - sim.robot.laser_mount.y, abs=1e-5)
