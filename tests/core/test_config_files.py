"""The files a user touches (camera, dock layout, robot) and the frame conventions behind them.

Ground truth: the literal file formats of ROS camera_calibration_parsers, OpenCV FileStorage and docs/user-guide.md,
the URDF roll/pitch/yaw convention and the REP 103 optical frame, written out independently here.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import Mount, RobotConfig
from monodock.core.settings import from_mapping, to_mapping
from monodock.errors import ConfigError

# --- camera -------------------------------------------------------------------------------------

# The example of the ROS wiki page of camera_calibration_parsers (values of image_geometry's unit test).
ROS_CAMERA_INFO_YAML = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [430.15433020105519, 0, 311.71339830549732, 0, 430.60920415473657, 221.06824942698509, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.363528858080088, 0.16117037733986861, -8.1109585007538829e-05, -0.00044776712298447841, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [0.99806560714807102, 0.0068562422224214027, 0.061790256276695904, -0.0067522959054715113, 0.99997541519165112, -0.0018909025066874664, -0.061801701660692349, 0.0014700186639396652, 0.99808736527268516]
projection_matrix:
  rows: 3
  cols: 4
  data: [295.53402059708782, 0, 285.55760765075684, 0, 0, 295.53402059708782, 223.29617881774902, 0, 0, 0, 1, 0]
"""  # noqa: E501


def test_camera_save_load_round_trip(tmp_path: Path) -> None:
    """A camera written as camera_info YAML reads back equal, numbers and all."""
    cam = CameraModel.from_intrinsics(
        1280, 720, 901.25, 899.5, 640.3, 361.7, (-0.21, 0.043, 0.0011, -0.0007, 0.0125), name="front"
    )
    path = tmp_path / "front.yaml"
    cam.save(path)

    back = CameraModel.load(path)

    assert back == cam
    np.testing.assert_array_equal(back.matrix, cam.matrix)
    np.testing.assert_array_equal(back.dist, cam.dist)


def test_camera_reads_ros_camera_info_yaml(tmp_path: Path) -> None:
    """The ROS wiki's camera_info YAML gives fx, fy, cx, cy and D from camera_matrix (not P)."""
    path = tmp_path / "narrow_stereo.yaml"
    path.write_text(ROS_CAMERA_INFO_YAML, encoding="utf-8")

    cam = CameraModel.load(path)

    assert (cam.width, cam.height) == (640, 480)
    assert cam.name == "narrow_stereo"
    assert cam.distortion_model == "plumb_bob"
    np.testing.assert_allclose(
        [cam.fx, cam.fy, cam.cx, cam.cy],
        [430.15433020105519, 430.60920415473657, 311.71339830549732, 221.06824942698509],
        rtol=1e-15,
    )
    np.testing.assert_allclose(
        cam.dist, [-0.363528858080088, 0.16117037733986861, -8.1109585007538829e-05, -0.00044776712298447841, 0.0]
    )


# OpenCV 5's FileStorage writes YAML files headed "%YAML 1.2"; camera.py only recognises OpenCV 4's
# "%YAML:1.0" header and hands the file to PyYAML, which rejects the !!opencv-matrix tag (see the report).
K_FS = np.array([[812.5, 0.0, 402.25], [0.0, 810.75, 297.5], [0.0, 0.0, 1.0]])
D_FS = np.array([[-0.17, 0.031, 0.0009, -0.0004, 0.002]])


def _write_filestorage(path: Path, *, with_k: bool = True) -> None:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 800)
    fs.write("image_height", 600)
    if with_k:
        fs.write("camera_matrix", K_FS)
    fs.write("distortion_coefficients", D_FS)
    fs.release()


@pytest.mark.parametrize(
    "suffix",
    [
        "xml",
        "json",
        "yaml",
    ],
)
def test_camera_reads_opencv_filestorage(tmp_path: Path, suffix: str) -> None:
    """A calibration written by cv2.FileStorage (camera_matrix, distortion_coefficients, size) reads back."""
    path = tmp_path / f"calib.{suffix}"
    _write_filestorage(path)

    cam = CameraModel.load(path)

    assert (cam.width, cam.height) == (800, 600)
    np.testing.assert_allclose(cam.matrix, K_FS, rtol=1e-15)
    np.testing.assert_allclose(cam.dist, D_FS.ravel(), rtol=1e-15)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (812.5, 810.75, 402.25, 297.5)


# What OpenCV 4's FileStorage (and its calibration sample) writes.
OPENCV4_YAML = """\
%YAML:1.0
---
image_width: 800
image_height: 600
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 8.1250000000000000e+02, 0., 4.0225000000000000e+02, 0.,
       8.1075000000000000e+02, 2.9750000000000000e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -1.7000000000000001e-01, 3.1e-02, 9.0e-04, -4.0e-04, 2.0e-03 ]
"""


def test_camera_reads_opencv4_filestorage_yaml(tmp_path: Path) -> None:
    """An OpenCV 4 style FileStorage YAML ("%YAML:1.0", !!opencv-matrix) reads correctly."""
    path = tmp_path / "calibration.yml"
    path.write_text(OPENCV4_YAML, encoding="utf-8")

    cam = CameraModel.load(path)

    assert (cam.width, cam.height) == (800, 600)
    np.testing.assert_allclose(cam.matrix, K_FS, rtol=1e-15)
    np.testing.assert_allclose(cam.dist, D_FS.ravel(), rtol=1e-15)


def test_camera_reads_filestorage_image_size_sequence(tmp_path: Path) -> None:
    """A cv::Size written by FileStorage (image_size: [width, height]) gives the image size."""
    path = tmp_path / "calib.xml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K_FS)
    fs.write("distortion_coefficients", D_FS)
    fs.startWriteStruct("image_size", cv2.FILE_NODE_SEQ)
    fs.write("", 800)
    fs.write("", 600)
    fs.endWriteStruct()
    fs.release()

    cam = CameraModel.load(path)

    assert (cam.width, cam.height) == (800, 600)
    np.testing.assert_allclose(cam.matrix, K_FS, rtol=1e-15)


def test_camera_yaml_without_camera_matrix_raises(tmp_path: Path) -> None:
    """A camera_info YAML with no camera_matrix is a ConfigError that names the field."""
    data = yaml.safe_load(ROS_CAMERA_INFO_YAML)
    del data["camera_matrix"]
    path = tmp_path / "no_k.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")

    with pytest.raises(ConfigError, match="camera_matrix"):
        CameraModel.load(path)


def test_camera_filestorage_without_camera_matrix_raises(tmp_path: Path) -> None:
    """The same for an OpenCV FileStorage file."""
    path = tmp_path / "no_k.xml"
    _write_filestorage(path, with_k=False)

    with pytest.raises(ConfigError, match="camera_matrix"):
        CameraModel.load(path)


# --- dock layout --------------------------------------------------------------------------------

GUIDE_LAYOUT_YAML = """\
dictionary: DICT_4X4_50
marker_size: 0.10
markers:
  left:   {id: 1, y: 0.20,  z: 0.30}
  center: {id: 2, y: 0.00,  z: 0.30}
  right:  {id: 3, y: -0.20, z: 0.30}
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_layout_design_example_loads(tmp_path: Path) -> None:
    """The user guide's layout YAML gives the stated dictionary, size, ids and marker centres."""
    layout = DockLayout.load(_write(tmp_path, "layout.yaml", GUIDE_LAYOUT_YAML))

    assert layout.dictionary == "DICT_4X4_50"
    assert layout.marker_size == pytest.approx(0.10)
    expected = {"left": (1, 0.20, 0.30), "center": (2, 0.0, 0.30), "right": (3, -0.20, 0.30)}
    for role, (marker_id, y, z) in expected.items():
        m = layout.marker(role)
        assert (m.id, m.y, m.z) == (marker_id, pytest.approx(y), pytest.approx(z))
    assert layout.role_of(2) == "center"
    assert layout.role_of(7) is None
    # The left marker's top-left corner seen from the robot: (0, y + s/2, z + s/2) in the dock frame.
    np.testing.assert_allclose(layout.corners_in_dock("left")[0], [0.0, 0.25, 0.35], atol=1e-12)


@pytest.mark.parametrize(
    ("old", "new", "pattern"),
    [
        ("center: {id: 2,", "center: {id: 1,", r"distinct.*\[1, 1, 3\]"),
        ("DICT_4X4_50", "DICT_9X9_7", "DICT_9X9_7"),
        ("center: {id: 2, ", "center: {", r"markers\.center\.id"),
        ("right:  {id: 3,", "right:  {id: 50,", r"id 50 is not in DICT_4X4_50"),
    ],
    ids=["duplicate_ids", "unknown_dictionary", "missing_center_id", "id_outside_dictionary"],
)
def test_layout_errors_name_the_problem(tmp_path: Path, old: str, new: str, pattern: str) -> None:
    """Each broken layout raises ConfigError whose message names the problem."""
    assert old in GUIDE_LAYOUT_YAML
    path = _write(tmp_path, "bad.yaml", GUIDE_LAYOUT_YAML.replace(old, new, 1))

    with pytest.raises(ConfigError, match=pattern):
        DockLayout.load(path)


def test_layout_dict_round_trip() -> None:
    """to_mapping -> from_mapping gives the same layout, optional keys included."""
    layout = from_mapping(
        DockLayout,
        {
            "dictionary": "DICT_5X5_100",
            "marker_size": 0.08,
            "markers": {
                "left": {"id": 11, "y": 0.25, "z": 0.22},
                "center": {"id": 42, "y": 0.01, "z": 0.31},
                "right": {"id": 99, "y": -0.18, "z": 0.22},
            },
            "note": "spare charger",
        },
        "layout",
    )

    back = from_mapping(DockLayout, to_mapping(layout), "layout")

    assert back == layout
    assert to_mapping(back) == to_mapping(layout)
    assert "note" not in to_mapping(back), "a key the schema does not know is dropped, never copied on"
    assert [m.id for m in back.markers] == [11, 42, 99]


SURVEYED_LAYOUT_YAML = """\
dictionary: DICT_4X4_50
marker_size: 0.10
edge_offset_px: -0.15
markers:
  left:   {id: 1, y: 0.20, z: 0.30, x: -0.004, roll: 0.01, pitch: -0.02, yaw: 0.2, size: 0.098}
  center: {id: 2, y: 0.00, z: 0.30}
  right:  {id: 3, y: -0.20, z: 0.30, size: 0.102}
survey: {views_used: 24, rms_px: 0.03}
"""


def test_surveyed_layout_keys_place_tilt_and_size_each_marker(tmp_path: Path) -> None:
    """A marker's x, tilt (URDF order about the dock's axes through its centre) and own side move its corners where
    the geometry says, written out here on its own; the centre keeps the layout's size; the survey's record is read
    past; the file round-trips."""
    layout = DockLayout.load(_write(tmp_path, "surveyed.yaml", SURVEYED_LAYOUT_YAML))

    h = 0.098 / 2
    R = transforms.rotation_from_rpy(0.01, -0.02, 0.2)
    # The untilted top-left corner sits at (0, +h, +h) from the centre (the robot's left is +y, up is +z).
    expected = np.array([-0.004, 0.20, 0.30]) + R @ np.array([0.0, h, h])
    np.testing.assert_allclose(layout.corners_in_dock("left")[0], expected, atol=1e-12)
    assert layout.side("left") == pytest.approx(0.098)
    assert layout.side("center") == pytest.approx(0.10)
    assert layout.side("right") == pytest.approx(0.102)
    assert layout.edge_offset == pytest.approx(-0.15)
    assert not layout.flat
    np.testing.assert_allclose(np.ptp(layout.corners_in_dock("right")[:, 1]), 0.102, atol=1e-12)
    assert from_mapping(DockLayout, to_mapping(layout), "layout") == layout
    assert "survey" not in to_mapping(layout)


@pytest.mark.parametrize(
    ("old", "new", "pattern"),
    [
        ("yaw: 0.2,", "yaw: 1.2,", r"markers\.left\.yaw: must be within"),
        ("size: 0.098", "size: 3.0", r"markers\.left\.size: must be within"),
        ("edge_offset_px: -0.15", "edge_offset_px: 7", r"edge_offset_px: must be within"),
        ("x: -0.004,", "x: near,", r"markers\.left\.x: expected a number"),
    ],
    ids=["tilt_beyond_45_deg", "side_beyond_2_m", "edge_offset_beyond_2_px", "x_not_a_number"],
)
def test_surveyed_layout_errors_name_the_key(tmp_path: Path, old: str, new: str, pattern: str) -> None:
    assert old in SURVEYED_LAYOUT_YAML
    with pytest.raises(ConfigError, match=pattern):
        DockLayout.load(_write(tmp_path, "bad.yaml", SURVEYED_LAYOUT_YAML.replace(old, new, 1)))


# --- robot --------------------------------------------------------------------------------------

GUIDE_ROBOT_YAML = """\
camera_mount: {x: 0.17, y: 0.0, z: 0.25, roll: 0.0, pitch: 0.0, yaw: 0.0}
laser_mount:  {x: 0.17, y: 0.0, z: 0.20, roll: 0.0, pitch: 0.0, yaw: 0.0}
front_offset: 0.34
"""


def test_robot_design_example_loads(tmp_path: Path) -> None:
    """The user guide's robot YAML gives the stated mounts and front_offset."""
    robot = RobotConfig.load(_write(tmp_path, "robot.yaml", GUIDE_ROBOT_YAML))

    assert robot.camera_mount == Mount(0.17, 0.0, 0.25, 0.0, 0.0, 0.0)
    assert robot.laser_mount == Mount(0.17, 0.0, 0.20, 0.0, 0.0, 0.0)
    assert robot.front_offset == pytest.approx(0.34)
    np.testing.assert_allclose(robot.base_T_optical()[:3, 3], [0.17, 0.0, 0.25])
    np.testing.assert_allclose(robot.base_T_laser()[:3, 3], [0.17, 0.0, 0.20])


def test_robot_without_front_offset_raises(tmp_path: Path) -> None:
    """A robot file missing front_offset is a ConfigError naming the field."""
    text = GUIDE_ROBOT_YAML.replace("front_offset: 0.34\n", "")
    with pytest.raises(ConfigError, match="front_offset"):
        RobotConfig.load(_write(tmp_path, "robot.yaml", text))


def test_optical_frame_of_a_straight_mount() -> None:
    """Zero-rotation mount (REP 103): optical z -> base +x, optical x -> base -y (right), y -> base -z (down)."""
    robot = RobotConfig(camera_mount=Mount(0.2, 0.03, 0.3))
    R = robot.base_T_optical()[:3, :3]

    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(R @ [0.0, 1.0, 0.0], [0.0, 0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(robot.base_T_optical()[:3, 3], [0.2, 0.03, 0.3])


@pytest.mark.parametrize("pitch_deg", [3.0, 10.0, 25.0])
def test_positive_pitch_looks_down(pitch_deg: float) -> None:
    """URDF: pitch > 0 tilts the optical axis below the horizon by exactly the pitch, still straight ahead."""
    p = math.radians(pitch_deg)
    robot = RobotConfig(camera_mount=Mount(0.17, 0.0, 0.25, 0.0, p, 0.0))

    axis = robot.base_T_optical()[:3, :3] @ [0.0, 0.0, 1.0]

    np.testing.assert_allclose(axis, [math.cos(p), 0.0, -math.sin(p)], atol=1e-15)


def test_positive_yaw_looks_left() -> None:
    """URDF: yaw > 0 turns the optical axis counter-clockwise, to the robot's left (+y)."""
    y = math.radians(20.0)
    robot = RobotConfig(camera_mount=Mount(0.17, 0.0, 0.25, 0.0, 0.0, y))

    axis = robot.base_T_optical()[:3, :3] @ [0.0, 0.0, 1.0]

    np.testing.assert_allclose(axis, [math.cos(y), math.sin(y), 0.0], atol=1e-15)


# --- transforms and DockPose --------------------------------------------------------------------


def _rx(a: float) -> np.ndarray:
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def _ry(a: float) -> np.ndarray:
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def _rz(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def test_rpy_round_trip_and_urdf_order() -> None:
    """rotation_from_rpy = Rz(yaw) Ry(pitch) Rx(roll), and rpy_from_rotation recovers the angles."""
    rng = np.random.default_rng(20240611)
    for _ in range(200):
        roll, yaw = rng.uniform(-math.pi + 1e-6, math.pi - 1e-6, 2)
        pitch = rng.uniform(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)

        R = transforms.rotation_from_rpy(roll, pitch, yaw)

        np.testing.assert_allclose(R, _rz(yaw) @ _ry(pitch) @ _rx(roll), atol=1e-14)
        np.testing.assert_allclose(transforms.rpy_from_rotation(R), (roll, pitch, yaw), atol=1e-9)


def test_dock_pose_of_robots_at_known_places() -> None:
    """A robot 1 m in front of the charger, offset to the dock's left and turned, sees the dock as geometry says."""
    # Facing the charger square on, 1 m away: the dock is 1 m ahead.
    p = DockPose.from_robot_in_dock(-1.0, 0.0, 0.0)
    assert (p.x, p.y, p.yaw) == pytest.approx((1.0, 0.0, 0.0), abs=1e-12)
    # Standing 0.3 m to the dock's +y, still facing +x: the docking point is on the robot's right.
    p = DockPose.from_robot_in_dock(-1.0, 0.3, 0.0)
    assert (p.x, p.y, p.yaw) == pytest.approx((1.0, -0.3, 0.0), abs=1e-12)
    # At the dock origin, turned 90 degrees left: the dock's x axis points to the robot's right.
    p = DockPose.from_robot_in_dock(0.0, 0.0, math.pi / 2)
    assert (p.x, p.y, p.yaw) == pytest.approx((0.0, 0.0, -math.pi / 2), abs=1e-12)


def test_dock_pose_robot_in_dock_inverse() -> None:
    """DockPose.from_robot_in_dock and robot_in_dock undo each other on random poses."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        x, y = rng.uniform(-3.0, 3.0, 2)
        yaw = rng.uniform(-math.pi + 1e-6, math.pi - 1e-6)

        pose = DockPose.from_robot_in_dock(x, y, yaw)

        np.testing.assert_allclose(pose.robot_in_dock(), (x, y, yaw), atol=1e-12)
        again = DockPose.from_robot_in_dock(*pose.robot_in_dock())
        np.testing.assert_allclose((again.x, again.y, again.yaw), (pose.x, pose.y, pose.yaw), atol=1e-12)


# Variants met in the wild: the camera_calibration_parsers wiki example (prosilica), a file with the
# distortion as a plain list and no distortion_model, and the hybrid that OpenCV-based tools write
# (a %YAML:1.0 header, !!opencv-matrix for K and D, plain mappings for the rest).
CAMERA_VARIANTS = {
    "prosilica": (
        "image_width: 2448\nimage_height: 2050\ncamera_name: prosilica\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        "  data: [4827.94, 0, 1223.5, 0, 4835.62, 1024.5, 0, 0, 1]\ndistortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.41527, 0.31874, -0.00197, 0.00071, 0]\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        "projection_matrix:\n  rows: 3\n  cols: 4\n"
        "  data: [4827.94, 0, 1223.5, 0, 0, 4835.62, 1024.5, 0, 0, 0, 1, 0]\n",
        (2448, 2050, 4827.94, 4835.62, 1223.5, 1024.5, [-0.41527, 0.31874, -0.00197, 0.00071, 0.0]),
    ),
    "plain_list": (
        "image_width: 800\nimage_height: 600\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        "  data: [579.3, 0.0, 382.7, 0.0, 578.0, 294.3, 0.0, 0.0, 1.0]\n"
        "distortion_coefficients: [-0.1747, 0.1064, 0.0052, -0.0003, 0.0]\n",
        (800, 600, 579.3, 578.0, 382.7, 294.3, [-0.1747, 0.1064, 0.0052, -0.0003, 0.0]),
    ),
    "opencv_hybrid": (
        "%YAML:1.0\nimage_width: 640\nimage_height: 480\ncamera_name: narrow_stereo/left\n"
        "camera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
        "  data: [369.40269, 0, 310.549287, 0, 371.158263, 230.099198, 0, 0, 1]\n"
        "distortion_model: plumb_bob\ndistortion_coefficients: !!opencv-matrix\n  rows: 1\n  cols: 5\n  dt: d\n"
        "  data: [-0.331914, 0.068294, -0.00294, 0.004949, 0]\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n",
        (640, 480, 369.40269, 371.158263, 310.549287, 230.099198, [-0.331914, 0.068294, -0.00294, 0.004949, 0.0]),
    ),
}


@pytest.mark.parametrize("name", sorted(CAMERA_VARIANTS))
def test_camera_file_variants(tmp_path: Path, name: str) -> None:
    """Each variant's literal numbers come back as written."""
    text, (w, h, fx, fy, cx, cy, d) = CAMERA_VARIANTS[name]
    path = tmp_path / f"{name}.yaml"
    path.write_text(text, encoding="utf-8")

    cam = CameraModel.load(path)

    assert (cam.width, cam.height) == (w, h)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [fx, fy, cx, cy], rtol=1e-12)
    np.testing.assert_allclose(cam.dist, d, rtol=1e-12)


def test_camera_four_coefficient_plumb_bob(tmp_path: Path) -> None:
    """k1 k2 p1 p2 without k3 (OpenCV accepts it) reads with k3 = 0."""
    path = tmp_path / "c.yaml"
    path.write_text(
        "image_width: 320\nimage_height: 240\n"
        "camera_matrix: {rows: 3, cols: 3, data: [300, 0, 160, 0, 300, 120, 0, 0, 1]}\n"
        "distortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, cols: 4, data: [-0.2, 0.05, 0.001, 0.002]}\n",
        encoding="utf-8",
    )
    np.testing.assert_array_equal(CameraModel.load(path).dist, [-0.2, 0.05, 0.001, 0.002, 0.0])


def test_atomic_outputs_get_the_permissions_of_any_new_file(tmp_path: Path) -> None:
    """Temp files and folders are private; what they become must not be (a robot's other users read them)."""
    import os
    import stat

    from monodock.core.atomic import atomic_directory, write_text_atomic

    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "f.yaml", "a: 1\n")
        with atomic_directory(tmp_path / "d") as d:
            (d / "x").write_text("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "f.yaml").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755
