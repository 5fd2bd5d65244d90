"""LiDAR labels, model features and the back-projected lateral offset against the simulator's ground truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.pose import DockPose
from monodock.core.projection import project_to_image, scan_in_base
from monodock.core.robot import Mount, RobotConfig
from monodock.core.scan import LaserScan
from monodock.estimation.regression import lateral_by_back_projection
from monodock.learning.label import LidarLabel, label_frame, points_across_marker
from monodock.perception.detect import MarkerDetector
from monodock.perception.features import FEATURE_NAMES, feature_vector, model_feature_names, model_features
from monodock.sim import LidarModel, Nuisances, PoseDistribution, RoomGeometry, Simulator
from monodock.sim.world import rectangle

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
    dxm = np.array([lab.x_line_marker - p.x for p, lab in rows])
    dy = np.array([lab.y - p.y for p, lab in rows])
    dym = np.array([lab.y_marker - p.y for p, lab in rows])
    dyaw = np.degrees([lab.yaw - p.yaw for p, lab in rows])
    dyaw_marker = np.degrees([lab.yaw_marker - p.yaw for p, lab in rows])
    # One return with sigma 1 cm: MAE ~0.8 cm; the line through ~5-20 points across marker 2 is several
    # times better, the line through the whole face (30-150 points) better again.
    assert np.mean(np.abs(dx)) < 0.013
    assert np.mean(np.abs(dxm)) < 0.006
    assert np.mean(np.abs(dym)) < 0.004
    assert np.mean(np.abs(dxl)) < 0.003
    assert np.mean(np.abs(dy)) < 0.002
    # The marker-2 line: unbiased, but several degrees off a frame over one marker's width (docs/benchmarks.md).
    assert abs(np.mean(dyaw_marker)) < 2.5
    assert 2.0 < np.mean(np.abs(dyaw_marker)) < 12.0
    # The face line: ~0.4 degrees.
    assert abs(np.mean(dyaw)) < 0.25
    assert np.mean(np.abs(dyaw)) < 0.7
    assert all(lab.face_points > 2 * lab.points for lab in labels)


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


def _face_width(sim: Simulator) -> float:
    """The simulated charger face's true width (the label code is not told it)."""
    return float(sim.world.surfaces[sim.world.surface_index("charger_face")].s_len)


def _scan_label(sim: Simulator, pose: DockPose, seed: int, scan: LaserScan | None = None) -> LidarLabel:
    """The label of a pose's scan, with marker 2's true corners: the LiDAR side alone, no render."""
    s = scan if scan is not None else sim.scan(pose, rng=np.random.default_rng(seed))
    return label_frame(sim.true_corners(pose)["center"], s, sim.camera, sim.robot)


def _dock_points(sim: Simulator, pose: DockPose, ranges: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Where beams of these ranges land, in the dock frame (the truth's frame), shape (N, 3)."""
    dock_T_laser = transforms.invert(pose.matrix()) @ sim.robot.base_T_laser()
    local = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    with np.errstate(invalid="ignore"):
        return np.asarray(transforms.apply(dock_T_laser, local * ranges[:, None]))


def test_face_line_angle_is_several_times_better_than_the_marker_line_at_1_to_2_m() -> None:
    """A line over one marker is ~8 degrees off, over the 60 cm face ~0.4; against truth."""
    sim = Simulator(seed=31)  # the default LiDAR: 1 cm range noise, 0.5 degree beams, 1 % dropouts
    poses = [sim.sample_pose(PoseDistribution(depth=(1.0, 2.0))) for _ in range(80)]
    rows = [(p, _scan_label(sim, p, i)) for i, p in enumerate(poses)]
    assert all(lab.valid for _, lab in rows)
    face = np.abs(np.degrees([lab.yaw - p.yaw for p, lab in rows]))
    marker = np.abs(np.degrees([lab.yaw_marker - p.yaw for p, lab in rows]))
    assert face.mean() < 0.7
    assert np.percentile(face, 95) < 1.5
    assert marker.mean() > 5 * face.mean()
    # Depth and lateral at marker 2's centre plane gain too.
    assert np.mean([abs(lab.x_line - p.x) for p, lab in rows]) < 0.6 * np.mean(
        [abs(lab.x_line_marker - p.x) for p, lab in rows]
    )
    assert np.mean([abs(lab.y - p.y) for p, lab in rows]) < 0.6 * np.mean([abs(lab.y_marker - p.y) for p, lab in rows])
    # The segment found is the face, all of it and nothing beyond (the charger's sides, the wall behind).
    width = _face_width(sim)
    spans = np.array([lab.face_span for _, lab in rows])
    assert np.all(spans <= width + 0.03)
    assert np.median(spans) > 0.95 * width
    assert np.all(spans > 0.8 * width)


def test_clutter_beside_the_face_does_not_bias_the_line() -> None:
    """A box beside the charger, its front 6 cm proud of the face and its side touching the face's edge:
    the segment stops at the box and the line keeps the face's angle."""
    half = _face_width(Simulator()) / 2
    front = rectangle("box_front", (-0.06, half + 0.3, 0.5), (0, -1, 0), (0, 0, -1), 0.3, 0.5, 0.4)
    side = rectangle("box_side", (-0.06, half, 0.5), (1, 0, 0), (0, 0, -1), 0.06, 0.5, 0.4)
    sim = Simulator(room=RoomGeometry(extra=(front, side)), seed=5)
    # Robot to the box's side of the axis, so that the LiDAR sees the box's side and front.
    poses = [sim.sample_pose(PoseDistribution(depth=(0.6, 1.8), lateral=(0.0, 0.4))) for _ in range(40)]
    rows = [(p, _scan_label(sim, p, i)) for i, p in enumerate(poses)]
    assert all(lab.valid for _, lab in rows)
    err = np.abs(np.degrees([lab.yaw - p.yaw for p, lab in rows]))
    assert err.mean() < 0.6
    assert err.max() < 1.6
    # With the box the segment would be ~0.9 m long.
    assert max(lab.face_span for _, lab in rows) <= 2 * half + 0.03
    assert np.mean([abs(lab.x_line - p.x) for p, lab in rows]) < 0.003


def test_spikes_and_a_mixed_return_next_to_the_face_are_rejected() -> None:
    """Returns 3 cm off the face join the segment (within its tolerance); the MAD rejection drops them.

    A noise-free scan, so that the line must come out exact: seven spikes towards one end of the face and
    a mixed return just past its edge, between the face and the wall behind (a real LiDAR's edge effect).
    """
    sim = Simulator(lidar=LidarModel(range_noise=0.0, dropout=0.0), seed=3)
    pose = DockPose(1.3, 0.05, math.radians(12))
    scan = sim.scan(pose, rng=np.random.default_rng(0))
    r = scan.ranges.astype(np.float64)
    a = scan.angles()
    pts = _dock_points(sim, pose, r, a)
    face = np.flatnonzero(np.isfinite(r) & (np.abs(pts[:, 0]) < 1e-6))
    bad = r.copy()
    spikes = face[(pts[face, 1] > 0.1) & (pts[face, 1] < 0.25)][::3]
    bad[spikes] -= 0.03
    # The beam just past the face's left end: put its return 3 cm behind the face plane.
    edge = int(face.max()) + 1
    ray = _dock_points(sim, pose, np.array([0.0, 1.0]), a[[edge, edge]])
    bad[edge] = (0.03 - ray[0, 0]) / (ray[1, 0] - ray[0, 0])
    assert _dock_points(sim, pose, bad[[edge]], a[[edge]])[0, 0] == pytest.approx(0.03)
    lab = _scan_label(sim, pose, 0, dataclasses.replace(scan, ranges=bad.astype(np.float32)))
    assert lab.valid
    assert lab.face_rejected >= len(spikes) + 1
    assert abs(math.degrees(lab.yaw - pose.yaw)) < 0.02
    assert abs(lab.x_line - pose.x) < 1e-3
    assert abs(lab.y - pose.y) < 1e-3
    assert lab.face_points >= len(face) - len(spikes) - 1


def test_face_across_the_seam_of_a_rear_facing_scanner() -> None:
    """A 360 degree scanner mounted backwards sees the face across its first and last beams."""
    robot = RobotConfig(laser_mount=Mount(0.17, 0.0, 0.20, 0.0, 0.0, math.pi))
    sim = Simulator(robot=robot, lidar=LidarModel(range_noise=0.0, dropout=0.0), seed=6)
    for pose in (DockPose(1.0, 0.1, math.radians(15)), DockPose(1.8, -0.2, math.radians(-20))):
        lab = _scan_label(sim, pose, 0)
        assert lab.valid, lab.reason
        assert lab.face_span > 0.95 * _face_width(sim)
        assert abs(math.degrees(lab.yaw - pose.yaw)) < 0.02


def test_scans_without_enough_face_returns_give_no_label() -> None:
    """NaN, inf and too few returns on the face: an invalid label with a reason, never a number."""
    sim = Simulator(seed=9)
    pose = DockPose(1.2, 0.05, math.radians(10))
    scan = sim.scan(pose, rng=np.random.default_rng(0))
    for bad in (np.nan, np.inf, -np.inf, 0.0):
        lab = _scan_label(sim, pose, 0, dataclasses.replace(scan, ranges=np.full_like(scan.ranges, bad)))
        assert not lab.valid
        assert lab.reason
        assert math.isnan(lab.yaw)
        assert math.isnan(lab.x)
    # Four returns left, all across marker 2: enough for the papers' label, too few for a face line.
    pts = scan_in_base(dataclasses.replace(scan, ranges=np.nan_to_num(scan.ranges, nan=np.inf)), sim.robot)
    across = points_across_marker(sim.true_corners(pose)["center"], pts, sim.camera, sim.robot)
    valid = np.flatnonzero(np.isfinite(scan.ranges) & (scan.ranges >= scan.range_min))
    keep = valid[across][:4]
    four = np.full_like(scan.ranges, np.nan)
    four[keep] = scan.ranges[keep]
    lab = _scan_label(sim, pose, 0, dataclasses.replace(scan, ranges=four))
    assert not lab.valid
    assert "face" in lab.reason
    assert math.isnan(lab.yaw)
    assert math.isnan(lab.y)
    # Every other beam dropped: the segment steps over the holes and still spans the face.
    holes = scan.ranges.copy()
    holes[1::2] = np.nan
    lab = _scan_label(sim, pose, 0, dataclasses.replace(scan, ranges=holes))
    assert lab.valid
    assert lab.face_span > 0.9 * _face_width(sim)
    assert abs(math.degrees(lab.yaw - pose.yaw)) < 1.0


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
