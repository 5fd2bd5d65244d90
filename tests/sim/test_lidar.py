"""The simulated 2D LiDAR against plane geometry worked out here.

The charger's front face is the plane x = 0 of the dock (world) frame; the laser sits at the robot's
laser_mount and scans horizontally. For each beam, the distance to that plane and where it meets it follow
from the robot's pose in the dock frame, computed here with plain trigonometry.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from monodock.core.pose import DockPose
from monodock.core.robot import Mount, RobotConfig
from monodock.core.scan import LaserScan
from monodock.sim import LidarModel, Nuisances, Simulator

FACE_HALF_WIDTH = 0.30  # the face spans at least y in [-0.3, 0.3]; stay clear of its edges
EDGE_MARGIN = 0.02

POSES = [
    DockPose(0.8, 0.1, math.radians(12.0)),
    DockPose(1.5, -0.3, math.radians(-17.0)),
    DockPose(0.6, 0.0, 0.0),
    DockPose(2.2, 0.45, math.radians(25.0)),
]

ROTATED_LASER = RobotConfig(laser_mount=Mount(0.08, -0.05, 0.20, 0.0, 0.0, math.radians(30.0)))


def _laser_in_dock(pose: DockPose, mount: Mount) -> tuple[float, float, float]:
    """(x, y, heading) of the laser in the dock frame for a robot at this DockPose.

    DockPose is the dock in base_link; the robot in the dock is its inverse: heading -yaw and position
    -R(-yaw) (x, y).
    """
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    rx = -(c * pose.x + s * pose.y)
    ry = -(-s * pose.x + c * pose.y)
    heading = -pose.yaw
    ch, sh = math.cos(heading), math.sin(heading)
    return rx + ch * mount.x - sh * mount.y, ry + sh * mount.x + ch * mount.y, heading + mount.yaw


def _face_geometry(
    scan: LaserScan, pose: DockPose, mount: Mount
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.bool_]]:
    """Beams that surely hit the charger face, their true ranges, and beams that point away from everything."""
    lx, ly, heading = _laser_in_dock(pose, mount)
    a = scan.angles() + heading
    dx, dy = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -lx / dx
    y_hit = ly + t * dy
    on_face = (dx > 0) & (np.abs(y_hit) < FACE_HALF_WIDTH - EDGE_MARGIN)
    # Every surface (face, charger body, back wall) lies at x >= 0 ahead of the laser (x < 0) and the floor
    # and the charger top are parallel to the scan plane: a beam heading towards -x meets nothing.
    away = dx < -1e-6
    return on_face, np.where(on_face, t, np.nan), away


def test_face_ranges_within_noise() -> None:
    """Beams on the charger face return the true distance within 4 sigma, with about sigma spread."""
    model = LidarModel()
    sim = Simulator(nuisances=Nuisances.clean(), lidar=model, seed=11)
    residuals = []
    for pose in POSES:
        assert pose.x - sim.robot.laser_mount.x > 0.3  # laser well in front of the face
        scan = sim.scan(pose)
        on_face, true_range, _ = _face_geometry(scan, pose, sim.robot.laser_mount)
        assert on_face.sum() >= 10
        r = scan.ranges.astype(np.float64)[on_face]
        ok = ~np.isnan(r)
        assert ok.sum() >= 0.9 * on_face.sum()
        res = r[ok] - true_range[on_face][ok]
        assert np.all(np.abs(res) < 4 * model.range_noise), np.abs(res).max()
        residuals.append(res)
    res = np.concatenate(residuals)
    assert res.size > 150
    assert abs(res.mean()) < 4 * model.range_noise / math.sqrt(res.size)
    assert 0.8 * model.range_noise < res.std() < 1.2 * model.range_noise


@pytest.mark.parametrize("robot", [RobotConfig.default(), ROTATED_LASER], ids=["default_mount", "rotated_mount"])
def test_noiseless_ranges_are_exact(robot: RobotConfig) -> None:
    """range_noise = 0, dropout = 0: face ranges are the exact distance (to float32, as LaserScan stores them)."""
    sim = Simulator(robot=robot, nuisances=Nuisances.clean(), lidar=LidarModel(range_noise=0.0, dropout=0.0), seed=3)
    for pose in POSES:
        scan = sim.scan(pose)
        assert scan.ranges.dtype == np.float32  # sensor_msgs/LaserScan ranges are float32[]
        on_face, true_range, away = _face_geometry(scan, pose, robot.laser_mount)
        assert on_face.sum() >= 10
        r = scan.ranges.astype(np.float64)[on_face]
        t = true_range[on_face]
        # Exact up to the float32 rounding of the stored value (half an ulp) plus 1e-9.
        tol = np.spacing(t.astype(np.float32)).astype(np.float64) / 2 + 1e-9
        assert np.all(np.abs(r - t) <= tol), np.abs(r - t).max()
        assert not np.isnan(scan.ranges).any()
        assert away.sum() > 100
        assert np.all(np.isposinf(scan.ranges[away]))


def test_dropouts_are_nan_at_the_configured_rate() -> None:
    """Dropped returns are NaN, at the configured rate (binomial, 5 sigma), spread over all beams."""
    for rate in (0.01, 0.15):
        model = LidarModel(dropout=rate)
        sim = Simulator(nuisances=Nuisances.clean(), lidar=model, seed=17)
        scans = [sim.scan(pose) for pose in POSES]
        nan = np.concatenate([np.isnan(s.ranges) for s in scans])
        n = nan.size
        assert abs(nan.sum() - rate * n) < 5 * math.sqrt(n * rate * (1 - rate)), (rate, nan.mean())
        if rate > 0.1:
            # Dropouts hit both beams that would see the face and beams that see nothing.
            geometry = [_face_geometry(s, p, sim.robot.laser_mount) for s, p in zip(scans, POSES, strict=True)]
            on_face = np.concatenate([g[0] for g in geometry])
            away = np.concatenate([g[2] for g in geometry])
            assert nan[on_face].any()
            assert nan[away].any()


def test_too_close_is_negative_infinity() -> None:
    """REP 117: a return nearer than range_min is -inf (the laser 8 cm from the face, range_min 12 cm)."""
    model = LidarModel(range_noise=0.0, dropout=0.0)
    sim = Simulator(nuisances=Nuisances.clean(), lidar=model)
    pose = DockPose(sim.robot.laser_mount.x + 0.08, 0.0, 0.0)
    scan = sim.scan(pose)
    on_face, true_range, _ = _face_geometry(scan, pose, sim.robot.laser_mount)
    near = on_face & (true_range < model.range_min - 1e-6)
    far = on_face & (true_range > model.range_min + 1e-6)
    assert near.sum() > 10
    assert far.sum() > 10
    assert np.all(np.isneginf(scan.ranges[near]))
    np.testing.assert_allclose(scan.ranges[far], true_range[far], rtol=1e-6)


def test_points_are_only_the_finite_returns() -> None:
    """LaserScan.points() keeps exactly the finite in-range returns, and the face points lie on x = 0."""
    sim = Simulator(nuisances=Nuisances.clean(), lidar=LidarModel(dropout=0.1, range_noise=0.0), seed=23)
    pose = POSES[0]
    scan = sim.scan(pose)
    r = scan.ranges
    assert np.isnan(r).any()
    assert np.isposinf(r).any()
    finite = np.isfinite(r)

    pts = scan.points()

    assert pts.shape == (int(finite.sum()), 2)
    assert np.all(np.isfinite(pts))
    a = scan.angles()[finite]
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), r[finite], rtol=1e-6)
    np.testing.assert_allclose(np.arctan2(pts[:, 1], pts[:, 0]), np.arctan2(np.sin(a), np.cos(a)), atol=1e-9)
    # Into the dock frame: the returns of face beams lie on the face plane x = 0.
    on_face, _, _ = _face_geometry(scan, pose, sim.robot.laser_mount)
    lx, _, heading = _laser_in_dock(pose, sim.robot.laser_mount)
    face_pts = pts[on_face[finite]]
    assert len(face_pts) > 10
    x_dock = lx + math.cos(heading) * face_pts[:, 0] - math.sin(heading) * face_pts[:, 1]
    np.testing.assert_allclose(x_dock, 0.0, atol=1e-6)
