"""LiDAR labels, model features and the back-projected lateral offset against the simulator's ground truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monodock import transforms
from monodock.camera import CameraModel
from monodock.detect import MarkerDetector
from monodock.features import FEATURE_NAMES, feature_vector, model_feature_names, model_features
from monodock.label import LidarLabel, label_frame, points_across_marker, project_to_image, scan_in_base
from monodock.pose import DockPose
from monodock.regression import lateral_by_back_projection
from monodock.robot import Mount, RobotConfig
from monodock.scan import LaserScan
from monodock.sim import LidarModel, Nuisances, PoseDistribution, Simulator

FAST = Nuisances().updated(supersample=4)


def _labelled(sim: Simulator, n: int, seed: int) -> list[tuple[DockPose, LidarLabel]]:
    det = MarkerDetector(sim.layout)
    out = []
    for i in range(n):
        pose = sim.sample_pose(PoseDistribution())
        frame = sim.frame(pose, 0.0, np.random.default_rng([seed, i]))
        d = det.detect(frame.image)
        if "center" in d.observations:
            out.append((pose, label_frame(d.observations["center"].corners, frame.scan, sim.camera, sim.robot)))
    return out


def test_labels_match_truth_within_lidar_noise() -> None:
    """Depth within the 1 cm range noise, yaw unbiased, lateral from the line within millimetres."""
    sim = Simulator(nuisances=FAST, seed=21)
    rows = _labelled(sim, 60, 21)
    assert len(rows) >= 55
    labels = [lab for _, lab in rows]
    assert all(lab.valid for lab in labels)
    dx = np.array([lab.x - p.x for p, lab in rows])
    dxl = np.array([lab.x_line - p.x for p, lab in rows])
    dy = np.array([lab.y - p.y for p, lab in rows])
    dyaw = np.degrees([lab.yaw - p.yaw for p, lab in rows])
    # One return with sigma 1 cm: MAE ~0.8 cm; the line through ~5-20 points is several times better.
    assert np.mean(np.abs(dx)) < 0.013
    assert np.mean(np.abs(dxl)) < 0.006
    assert np.mean(np.abs(dy)) < 0.004
    assert abs(np.mean(dyaw)) < 2.5  # unbiased; per-frame noise is several degrees over one marker's width
    assert 2.0 < np.mean(np.abs(dyaw)) < 12.0


def test_points_across_marker_lie_below_it_on_the_face() -> None:
    """The selected scan points are on the charger face within marker 2's width (dock frame |y| <= s/2)."""
    sim = Simulator(nuisances=FAST, lidar=LidarModel(range_noise=0.0, dropout=0.0), seed=4)
    det = MarkerDetector(sim.layout)
    for pose in (DockPose(1.0, 0.1, math.radians(20)), DockPose(0.6, -0.05, math.radians(-25))):
        frame = sim.frame(pose, 0.0, np.random.default_rng(0))
        corners = det.detect(frame.image).observations["center"].corners
        pts = scan_in_base(frame.scan, sim.robot)
        sel = points_across_marker(corners, pts, sim.camera, sim.robot)
        in_dock = transforms.apply(transforms.invert(pose.matrix()), pts[sel])
        half = sim.layout.marker_size / 2
        assert sel.sum() >= 5
        np.testing.assert_allclose(in_dock[:, 0], 0.0, atol=1e-6)  # on the face plane
        assert np.all(np.abs(in_dock[:, 1]) <= half + 0.01)
        # ... and the neighbours just outside were left out: the selection spans most of the marker's width.
        assert np.ptp(in_dock[:, 1]) > 0.7 * sim.layout.marker_size
        # Projected into the image they fall in marker 2's columns (the papers' Fig. 9 picture).
        px = project_to_image(pts[sel], sim.camera, sim.robot)
        assert np.all((px[:, 0] > corners[:, 0].min() - 2) & (px[:, 0] < corners[:, 0].max() + 2))


def test_labels_hold_for_a_tilted_camera_and_a_rotated_laser() -> None:
    """The 3-D selection is exact for any mount: camera pitched down and yawed, laser turned 90 degrees."""
    robot = RobotConfig(
        camera_mount=Mount(0.15, 0.03, 0.28, 0.0, math.radians(8.0), math.radians(4.0)),
        laser_mount=Mount(0.05, -0.02, 0.18, 0.0, 0.0, math.radians(90.0)),
    )
    sim = Simulator(robot=robot, nuisances=FAST, lidar=LidarModel(range_noise=0.0, dropout=0.0), seed=8)
    rows = _labelled(sim, 25, 8)
    assert len(rows) >= 20
    for pose, lab in rows:
        assert lab.valid, lab.reason
        # Detected corners are ~0.3 px off: the centre plane moves by ~1 mm per metre.
        tol = 1e-3 + 1.5e-3 * pose.x
        assert abs(lab.x_line - pose.x) < tol
        assert abs(lab.y - pose.y) < tol
        assert abs(math.degrees(lab.yaw - pose.yaw)) < 0.5
        # Noise-free nearest point: off the centre by at most half a beam spacing along the face.
        assert abs(lab.x - pose.x) < 0.02 * math.tan(abs(pose.yaw)) + 2e-3


def test_label_without_returns_across_marker_is_invalid() -> None:
    sim = Simulator(nuisances=FAST, seed=2)
    pose = DockPose(1.0, 0.0, 0.0)
    frame = sim.frame(pose, 0.0, np.random.default_rng(0))
    corners = MarkerDetector(sim.layout).detect(frame.image).observations["center"].corners
    s = frame.scan
    for bad in (np.full_like(s.ranges, np.nan), np.full_like(s.ranges, np.inf)):
        lab = label_frame(corners, dataclasses.replace(s, ranges=bad), sim.camera, sim.robot)
        assert not lab.valid
        assert lab.reason
    # NaN holes in the middle of the face leave a label made of the remaining points.
    holes = s.ranges.copy()
    holes[::2] = np.nan
    lab = label_frame(corners, dataclasses.replace(s, ranges=holes), sim.camera, sim.robot)
    assert lab.valid
    assert abs(lab.x_line - pose.x) < 0.01


def test_lateral_back_projection_reduces_to_papers_formula() -> None:
    """Camera at base_link's origin, looking forward, no distortion: K = Z * P / f exactly (P: +right)."""
    camera = CameraModel.from_intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    robot = RobotConfig(camera_mount=Mount(0.0, 0.0, 0.3))
    for z, p in ((1.2, 37.5), (0.5, -120.0), (2.4, 5.0)):
        y = lateral_by_back_projection(np.array([320.0 + p, 200.0]), z, camera, robot)
        # Image x grows to the right, base_link y to the left.
        assert y == pytest.approx(-z * p / 600.0, abs=1e-9)


def test_lateral_back_projection_recovers_truth_through_lens_and_mount() -> None:
    robot = RobotConfig(camera_mount=Mount(0.12, -0.04, 0.27, 0.0, math.radians(6.0), math.radians(-3.0)))
    sim = Simulator(robot=robot, seed=3)
    for pose in (DockPose(0.9, 0.2, 0.3), DockPose(2.1, -0.35, -0.4), DockPose(0.45, 0.02, 0.1)):
        optical_T_dock = transforms.invert(robot.base_T_optical()) @ pose.matrix()
        centre = sim.camera.project(transforms.apply(optical_T_dock, np.array([[0.0, 0.0, 0.30]])))[0]
        y = lateral_by_back_projection(centre, pose.x, sim.camera, robot)
        assert y == pytest.approx(pose.y, abs=1e-9)


def test_model_features_do_not_depend_on_the_pixel_grid() -> None:
    """The same view through two different cameras gives the same model inputs (normalised coordinates)."""
    pose = DockPose(1.3, 0.15, math.radians(14))
    values = []
    for camera in (CameraModel.default(), CameraModel.from_intrinsics(1280, 720, 1010.0, 1008.0, 645.0, 356.0)):
        sim = Simulator(camera=camera, seed=0)
        corners = sim.true_corners(pose)
        raw = np.full(len(FEATURE_NAMES), np.nan)
        for role, m in (("left", "m1"), ("center", "m2"), ("right", "m3")):
            raw[FEATURE_NAMES.index(f"{m}_seen")] = 1.0
            for k, c in enumerate(("tl", "tr", "br", "bl")):
                raw[FEATURE_NAMES.index(f"{m}_{c}_u")] = corners[role][k, 0]
                raw[FEATURE_NAMES.index(f"{m}_{c}_v")] = corners[role][k, 1]
        values.append(model_features(raw, camera, "m1m2m3")[0])
    assert values[0].shape == (len(model_feature_names("m1m2m3")),)
    np.testing.assert_allclose(values[0], values[1], rtol=1e-6, atol=1e-9)


def test_model_features_of_a_missing_marker_are_nan_and_masked_sets_ignore_it() -> None:
    sim = Simulator(nuisances=FAST, seed=1)
    pose = DockPose(0.5, 0.08, 0.0)  # close and off to one side: the left marker is out of view
    frame = sim.frame(pose, 0.0, np.random.default_rng(0))
    det = MarkerDetector(sim.layout).detect(frame.image)
    assert "center" in det.observations
    assert len(det.observations) < 3
    raw = feature_vector(det, sim.camera)
    assert np.isnan(model_features(raw, sim.camera, "m1m2m3")).any()
    assert np.all(np.isfinite(model_features(raw, sim.camera, "m2")))


def test_scan_in_base_applies_the_laser_mount() -> None:
    robot = RobotConfig(laser_mount=Mount(0.2, 0.1, 0.15, 0.0, 0.0, math.pi / 2))
    scan = LaserScan(0.0, "laser", 0.0, 0.0, 1.0, 0.0, 0.1, 0.1, 10.0, np.array([2.0], dtype=np.float32))
    np.testing.assert_allclose(scan_in_base(scan, robot), [[0.2, 2.1, 0.15]], atol=1e-12)


def test_points_far_outside_the_field_are_not_projected_into_the_image() -> None:
    """65 deg off-axis the default lens polynomial folds back into the picture; such points must not land on
    a pixel (they put stray LiDAR points on overlays and hidden markers "in view")."""
    camera = CameraModel.default()
    far = np.array([[math.tan(math.radians(65.0)), 0.0, 1.0]])
    u, v = camera.project(far)[0]
    assert 0 <= u < camera.width
    assert 0 <= v < camera.height
    assert not camera.in_view_field(far)[0]
    robot = RobotConfig(camera_mount=Mount(0.0, 0.0, 0.0))
    base = far @ robot.base_T_optical()[:3, :3].T
    assert np.isnan(project_to_image(base, camera, robot)).all()
    # Every pixel corner's own ray is in the field.
    rays = camera.vertex_rays().reshape(-1, 2)
    assert camera.in_view_field(np.c_[rays, np.ones(len(rays))], margin=0.0).all()
