"""Golden characterisation of the settings files (issue 40, step 0): the exact one-line error of one bad input per
key and rule, the exact warning for an unknown key, and the exact bytes the writers write.

These pin today's behaviour so that moving the files onto one settings schema (``core.settings``) changes nothing a
user sees. Every test goes through the files' public entry points (``load``/``save``, ``load_dock_file``,
``bundle_metadata``, summary.json), never through the per-class ``to_dict``/``from_dict`` being retired. The
written files are in ``tests/data/settings``; ``python tests/core/test_settings_golden.py`` rewrites them (only
for a deliberate format change, reviewed as such).
"""

from __future__ import annotations

import copy
import logging
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from monodock.calibrate.target import DiamondTarget
from monodock.core.camera import CameraModel
from monodock.core.config import json_text, parse_yaml, yaml_text
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.core.settings import setting
from monodock.dock.database import load_dock_file
from monodock.errors import ConfigError, InputError
from monodock.learning.dataset import Dataset
from monodock.learning.pipeline import bundle_metadata

DATA = Path(__file__).resolve().parent.parent / "data" / "settings"
DELETE = object()  # a mutation that removes the key

# --- the files a mutation starts from: every optional key present, so each can be broken ---------------------------

ROBOT = """\
camera_mount: {x: 0.17, y: 0.01, z: 0.25, roll: 0.001, pitch: 0.05, yaw: -0.02}
laser_mount: {x: 0.12, y: -0.03, z: 0.19, roll: 0.0, pitch: 0.0174, yaw: 0.0349}
front_offset: 0.34
max_linear_speed: 0.3
max_angular_speed: 1.0
odometry: {distance_scale: 1.013, rotation_scale: -0.021, drift_per_m: 0.004}
"""

LAYOUT = """\
dictionary: DICT_4X4_50
marker_size: 0.1
markers:
  left: {id: 1, y: 0.2, z: 0.3, x: 0.002, roll: 0.01, pitch: -0.02, yaw: 0.03, size: 0.098}
  center: {id: 2, y: 0.0, z: 0.3}
  right: {id: 3, y: -0.2, z: 0.3, yaw: -0.05}
  far: {id: 7, y: 0.0, z: 0.62, size: 0.3}
edge_offset_px: -0.4
"""

TARGET = """\
side: 0.5
marker_size: 0.16
dictionary: DICT_4X4_50
markers:
  - {id: 20, s: 0.13, t: 0.13}
  - {id: 21, s: 0.37, t: 0.13}
"""

DOCKS = """\
docks:
  home:
    type: monodock
    frame: map
    pose: [1.0, 2.0, 0.5]
    id: 7
    layout: home_layout.yaml
"""

CAMERA = """\
image_width: 640
image_height: 480
camera_name: sim_camera
camera_matrix: {rows: 3, cols: 3, data: [615.0, 0.0, 322.4, 0.0, 613.0, 237.1, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.12, 0.08, 0.0006, -0.0004, -0.02]}
"""

FILES: dict[str, tuple[str, str, Callable[[str], Any]]] = {
    # kind: (the file's name as the error names it, its text, its loader)
    "robot": ("robot.yaml", ROBOT, RobotConfig.load),
    "layout": ("layout.yaml", LAYOUT, DockLayout.load),
    "target": ("target.yaml", TARGET, DiamondTarget.load),
    "docks": ("docks.yaml", DOCKS, load_dock_file),
    "camera": ("camera.yaml", CAMERA, CameraModel.load),
}


def _mutated(text: str, path: str, value: Any) -> str:
    data = copy.deepcopy(parse_yaml(text, "golden"))
    *parents, last = path.split(".") if path else [""]
    node: Any = data
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node[p]
    key: Any = int(last) if isinstance(node, list) else last
    if value is DELETE:
        del node[key]
    elif path:
        node[key] = value
    else:
        data = value
    return yaml_text(data, flow=None)


def _load(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str, text: str) -> Any:
    name, _, loader = FILES[kind]
    monkeypatch.chdir(tmp_path)
    Path(name).write_text(text, encoding="utf-8")
    return loader(name)


# (kind, key path, bad value, the exact line). One bad input per key and rule.
ERRORS: list[tuple[str, str, Any, str]] = [
    ("robot", "", [1, 2], "robot.yaml: expected a YAML mapping at the top level"),
    ("robot", "camera_mount", DELETE, "robot.yaml: missing field 'camera_mount'"),
    ("robot", "camera_mount", "a", "robot.yaml: camera_mount: expected a mapping, got str"),
    ("robot", "camera_mount.x", DELETE, "robot.yaml: missing field 'camera_mount.x'"),
    ("robot", "camera_mount.x", "a", "robot.yaml: camera_mount.x: expected a number, got 'a'"),
    ("robot", "camera_mount.x", 1e308, "robot.yaml: camera_mount.x: must be within -5 to 5 m, got 1e+308"),
    ("robot", "camera_mount.y", DELETE, "robot.yaml: missing field 'camera_mount.y'"),
    ("robot", "camera_mount.y", "a", "robot.yaml: camera_mount.y: expected a number, got 'a'"),
    ("robot", "camera_mount.y", 5.5, "robot.yaml: camera_mount.y: must be within -5 to 5 m, got 5.5"),
    ("robot", "camera_mount.z", DELETE, "robot.yaml: missing field 'camera_mount.z'"),
    ("robot", "camera_mount.z", "a", "robot.yaml: camera_mount.z: expected a number, got 'a'"),
    ("robot", "camera_mount.z", 5.5, "robot.yaml: camera_mount.z: must be within -5 to 5 m, got 5.5"),
    ("robot", "camera_mount.roll", "a", "robot.yaml: camera_mount.roll: expected a number, got 'a'"),
    (
        "robot",
        "camera_mount.roll",
        3.2,
        "robot.yaml: camera_mount.roll: must be within -3.14159 to 3.14159 rad, got 3.2",
    ),
    ("robot", "camera_mount.pitch", "a", "robot.yaml: camera_mount.pitch: expected a number, got 'a'"),
    (
        "robot",
        "camera_mount.pitch",
        1e300,
        "robot.yaml: camera_mount.pitch: must be within -3.14159 to 3.14159 rad, got 1e+300",
    ),
    ("robot", "camera_mount.yaw", "a", "robot.yaml: camera_mount.yaw: expected a number, got 'a'"),
    ("robot", "camera_mount.yaw", 3.2, "robot.yaml: camera_mount.yaw: must be within -3.14159 to 3.14159 rad, got 3.2"),
    ("robot", "camera_mount.y", math.inf, "robot.yaml: camera_mount.y: expected a finite number, got inf"),
    ("robot", "laser_mount", DELETE, "robot.yaml: missing field 'laser_mount'"),
    ("robot", "laser_mount", [0.1], "robot.yaml: laser_mount: expected a mapping, got list"),
    ("robot", "laser_mount.x", DELETE, "robot.yaml: missing field 'laser_mount.x'"),
    ("robot", "laser_mount.x", -5.01, "robot.yaml: laser_mount.x: must be within -5 to 5 m, got -5.01"),
    ("robot", "laser_mount.y", DELETE, "robot.yaml: missing field 'laser_mount.y'"),
    ("robot", "laser_mount.y", -5.01, "robot.yaml: laser_mount.y: must be within -5 to 5 m, got -5.01"),
    ("robot", "laser_mount.z", DELETE, "robot.yaml: missing field 'laser_mount.z'"),
    ("robot", "laser_mount.z", -5.01, "robot.yaml: laser_mount.z: must be within -5 to 5 m, got -5.01"),
    (
        "robot",
        "laser_mount.roll",
        -3.2,
        "robot.yaml: laser_mount.roll: must be within -3.14159 to 3.14159 rad, got -3.2",
    ),
    (
        "robot",
        "laser_mount.pitch",
        -3.2,
        "robot.yaml: laser_mount.pitch: must be within -3.14159 to 3.14159 rad, got -3.2",
    ),
    ("robot", "laser_mount.yaw", -3.2, "robot.yaml: laser_mount.yaw: must be within -3.14159 to 3.14159 rad, got -3.2"),
    ("robot", "front_offset", DELETE, "robot.yaml: missing field 'front_offset'"),
    ("robot", "front_offset", -0.01, "robot.yaml: front_offset: must be within 0 to 5 m, got -0.01"),
    ("robot", "front_offset", 7.0, "robot.yaml: front_offset: must be within 0 to 5 m, got 7.0"),
    ("robot", "front_offset", "far", "robot.yaml: front_offset: expected a number, got 'far'"),
    ("robot", "front_offset", True, "robot.yaml: front_offset: expected a number, got True"),
    ("robot", "max_linear_speed", 0.0, "robot.yaml: max_linear_speed: must be positive, got 0.0"),
    ("robot", "max_linear_speed", 50.0, "robot.yaml: max_linear_speed: must be within 0 to 5 m/s, got 50.0"),
    ("robot", "max_linear_speed", "x", "robot.yaml: max_linear_speed: expected a number, got 'x'"),
    ("robot", "max_angular_speed", -1.0, "robot.yaml: max_angular_speed: must be positive, got -1.0"),
    ("robot", "max_angular_speed", 20.0, "robot.yaml: max_angular_speed: must be within 0 to 10 rad/s, got 20.0"),
    ("robot", "max_angular_speed", None, "robot.yaml: max_angular_speed: expected a number, got None"),
    ("robot", "odometry", "none", "robot.yaml: odometry: expected a mapping, got str"),
    (
        "robot",
        "odometry.distance_scale",
        2.0,
        "robot.yaml: odometry.distance_scale: must be within 0.8 to 1.25, got 2.0",
    ),
    ("robot", "odometry.distance_scale", "a", "robot.yaml: odometry.distance_scale: expected a number, got 'a'"),
    (
        "robot",
        "odometry.rotation_scale",
        0.5,
        "robot.yaml: odometry.rotation_scale: must be within -0.2 to 0.2, got 0.5",
    ),
    (
        "robot",
        "odometry.drift_per_m",
        -1.0,
        "robot.yaml: odometry.drift_per_m: must be within -0.5 to 0.5 rad/m, got -1.0",
    ),
    ("layout", "", "just text", "layout.yaml: expected a YAML mapping at the top level"),
    ("layout", "dictionary", DELETE, "layout.yaml: missing field 'dictionary'"),
    ("layout", "dictionary", 5, "layout.yaml: dictionary: expected a string, got 5"),
    (
        "layout",
        "dictionary",
        "DICT_9X9_7",
        "layout.yaml: dictionary: unknown ArUco dictionary 'DICT_9X9_7' (e.g. DICT_4X4_50)",
    ),
    ("layout", "dictionary", "ARUCO", "layout.yaml: dictionary: unknown ArUco dictionary 'ARUCO' (e.g. DICT_4X4_50)"),
    ("layout", "marker_size", DELETE, "layout.yaml: missing field 'marker_size'"),
    ("layout", "marker_size", 3.0, "layout.yaml: marker_size: must be within 0.005 to 2 m, got 3.0"),
    ("layout", "marker_size", 0.001, "layout.yaml: marker_size: must be within 0.005 to 2 m, got 0.001"),
    ("layout", "marker_size", "big", "layout.yaml: marker_size: expected a number, got 'big'"),
    (
        "layout",
        "marker_size",
        10000000000000000000000000000000000000000,
        "layout.yaml: marker_size: must be within 0.005 to 2 m, got an integer of about 41 digits",
    ),
    ("layout", "markers", DELETE, "layout.yaml: missing field 'markers'"),
    ("layout", "markers", ["left"], "layout.yaml: markers: expected a mapping, got list"),
    ("layout", "markers", {}, "layout.yaml: markers.left: missing: every dock carries the papers' left, center, right"),
    (
        "layout",
        "markers.center",
        DELETE,
        "layout.yaml: markers.center: missing: every dock carries the papers' left, center, right",
    ),
    ("layout", "markers.center", [1, 2], "layout.yaml: markers.center: expected a mapping, got list"),
    (
        "layout",
        "markers.Far",
        {"id": 9, "y": 1.0, "z": 0.3},
        "layout.yaml: markers.Far: unknown marker role (expected left, center, right, or another "
        "marker's name: lower-case letters, digits and _)",
    ),
    ("layout", "markers.center.id", DELETE, "layout.yaml: missing field 'markers.center.id'"),
    ("layout", "markers.center.id", -1, "layout.yaml: markers.center.id: must be at least 0, got -1"),
    ("layout", "markers.center.id", 1.5, "layout.yaml: markers.center.id: expected an integer, got 1.5"),
    ("layout", "markers.center.id", "2", "layout.yaml: markers.center.id: expected an integer, got '2'"),
    ("layout", "markers.center.id", 50, "layout.yaml: marker center: id 50 is not in DICT_4X4_50 (0..49)"),
    ("layout", "markers.center.id", 1, "layout.yaml: marker ids must be distinct, got [1, 1, 3, 7]"),
    ("layout", "markers.left.y", DELETE, "layout.yaml: missing field 'markers.left.y'"),
    ("layout", "markers.left.y", 5.5, "layout.yaml: markers.left.y: must be within -5 to 5 m, got 5.5"),
    (
        "layout",
        "markers.left.y",
        0.05,
        "layout.yaml: markers left and center overlap (centres 0.050 m apart, sides 0.099 m on average)",
    ),
    ("layout", "markers.center.z", DELETE, "layout.yaml: missing field 'markers.center.z'"),
    ("layout", "markers.center.z", -6.0, "layout.yaml: markers.center.z: must be within -5 to 5 m, got -6.0"),
    ("layout", "markers.left.x", 9.0, "layout.yaml: markers.left.x: must be within -5 to 5 m, got 9.0"),
    (
        "layout",
        "markers.left.roll",
        0.8,
        "layout.yaml: markers.left.roll: must be within -0.785398 to 0.785398 rad, got 0.8",
    ),
    (
        "layout",
        "markers.left.pitch",
        -0.8,
        "layout.yaml: markers.left.pitch: must be within -0.785398 to 0.785398 rad, got -0.8",
    ),
    (
        "layout",
        "markers.right.yaw",
        1.0,
        "layout.yaml: markers.right.yaw: must be within -0.785398 to 0.785398 rad, got 1.0",
    ),
    ("layout", "markers.far.size", 2.5, "layout.yaml: markers.far.size: must be within 0.005 to 2 m, got 2.5"),
    ("layout", "markers.far.size", 0.0, "layout.yaml: markers.far.size: must be within 0.005 to 2 m, got 0.0"),
    ("layout", "edge_offset_px", 2.5, "layout.yaml: edge_offset_px: must be within -2 to 2 px, got 2.5"),
    ("layout", "edge_offset_px", "0.1", "layout.yaml: edge_offset_px: expected a number, got '0.1'"),
    ("layout", "markers.right", "here", "layout.yaml: markers.right: expected a mapping, got str"),
    (
        "layout",
        "markers.left",
        {"id": 1, "y": 0.2, "z": 0.3, "size": -0.1},
        "layout.yaml: markers.left.size: must be within 0.005 to 2 m, got -0.1",
    ),
    (
        "layout",
        "markers.center",
        {"id": 2, "y": 0.2, "z": 0.3},
        "layout.yaml: markers left and center overlap (centres 0.000 m apart, sides 0.099 m on average)",
    ),
    ("target", "", 3, "target.yaml: expected a YAML mapping at the top level"),
    ("target", "side", 0.01, "target.yaml: side: must be within 0.05 to 5 m, got 0.01"),
    ("target", "side", 10.0, "target.yaml: side: must be within 0.05 to 5 m, got 10.0"),
    ("target", "side", "a", "target.yaml: side: expected a number, got 'a'"),
    ("target", "marker_size", 0.001, "target.yaml: marker_size: must be within 0.005 to 2 m, got 0.001"),
    ("target", "marker_size", 3.0, "target.yaml: marker_size: must be within 0.005 to 2 m, got 3.0"),
    ("target", "dictionary", 5, "target.yaml: dictionary: expected a string, got 5"),
    ("target", "markers", "x", "target.yaml: markers: expected a list of {id, s, t}"),
    ("target", "markers", [], "target.yaml: markers: expected a list of {id, s, t}"),
    ("target", "markers", [3], "target.yaml: markers[0]: expected a mapping, got int"),
    ("target", "markers.0.id", DELETE, "target.yaml: missing field 'markers[0].id'"),
    ("target", "markers.0.id", -1, "target.yaml: markers[0].id: must be at least 0, got -1"),
    ("target", "markers.0.id", "20", "target.yaml: markers[0].id: expected an integer, got '20'"),
    ("target", "markers.1.s", DELETE, "target.yaml: missing field 'markers[1].s'"),
    ("target", "markers.1.s", 0.6, "target.yaml: markers[1].s: must be within 0 to 0.5 m, got 0.6"),
    ("target", "markers.1.s", -0.1, "target.yaml: markers[1].s: must be within 0 to 0.5 m, got -0.1"),
    ("target", "markers.0.t", 0.51, "target.yaml: markers[0].t: must be within 0 to 0.5 m, got 0.51"),
    ("target", "side", 0.2, "target.yaml: markers[1].s: must be within 0 to 0.2 m, got 0.37"),
    ("docks", "", {"chargers": {}}, "dock database docks.yaml: does not contain 'docks'"),
    ("docks", "docks", [1], "dock database docks.yaml: docks: expected a mapping, got list"),
    ("docks", "docks.home", "x", "dock database docks.yaml: docks.home: expected a mapping, got str"),
    ("docks", "docks.home.type", DELETE, "dock database docks.yaml: missing field 'docks.home.type'"),
    ("docks", "docks.home.type", 3, "dock database docks.yaml: docks.home.type: expected a string, got 3"),
    ("docks", "docks.home.frame", 4, "dock database docks.yaml: docks.home.frame: expected a string, got 4"),
    ("docks", "docks.home.pose", DELETE, "dock database docks.yaml: missing field 'docks.home.pose'"),
    (
        "docks",
        "docks.home.pose",
        [1.0, 2.0],
        "dock database docks.yaml: docks.home.pose: expected a list of 3 numbers, got [1.0, 2.0]",
    ),
    (
        "docks",
        "docks.home.pose",
        [1.0, "a", 2.0],
        "dock database docks.yaml: docks.home.pose: expected finite numbers, got 'a'",
    ),
    (
        "docks",
        "docks.home.pose",
        [1.0, 2.0, math.inf],
        "dock database docks.yaml: docks.home.pose: expected finite numbers, got inf",
    ),
    ("docks", "docks.home.id", True, "dock database docks.yaml: docks.home.id: expected a string, got True"),
    ("docks", "docks.home.id", [1], "dock database docks.yaml: docks.home.id: expected a string, got [1]"),
    ("docks", "docks.home.layout", 1.5, "dock database docks.yaml: docks.home.layout: expected a string, got 1.5"),
    ("camera", "", ["a"], "camera.yaml: expected a YAML mapping at the top level"),
    ("camera", "image_width", DELETE, "camera.yaml: missing field 'width'"),
    ("camera", "image_width", 0, "camera.yaml: image_width: must be at least 1, got 0"),
    ("camera", "image_width", 20000, "camera.yaml: image_width: must be at most 16384, got 20000"),
    ("camera", "image_width", 640.5, "camera.yaml: image_width: expected an integer, got 640.5"),
    ("camera", "image_height", DELETE, "camera.yaml: missing field 'height'"),
    ("camera", "image_height", -2, "camera.yaml: image_height: must be at least 1, got -2"),
    ("camera", "image_height", 16385, "camera.yaml: image_height: must be at most 16384, got 16385"),
    ("camera", "camera_matrix", DELETE, "camera.yaml: missing field 'camera_matrix'"),
    ("camera", "camera_matrix", [1.0, 2.0], "camera.yaml: camera_matrix: expected a list of 9 numbers, got [1.0, 2.0]"),
    (
        "camera",
        "camera_matrix",
        {"rows": 3, "cols": 3, "data": [1.0]},
        "camera.yaml: camera_matrix.data: expected a list of 9 numbers, got [1.0]",
    ),
    ("camera", "camera_matrix", {"rows": 3}, "camera.yaml: missing field 'camera_matrix.data'"),
    ("camera", "camera_matrix", "K", "camera.yaml: camera_matrix: expected a list of 9 numbers, got 'K'"),
    (
        "camera",
        "camera_matrix.data",
        [615.0, 0.0, 322.4, 0.0, 613.0, 237.1, 0.0, 0.0, math.nan],
        "camera.yaml: camera_matrix.data: expected finite numbers, got nan",
    ),
    (
        "camera",
        "camera_matrix.data",
        [-615.0, 0.0, 322.4, 0.0, 613.0, 237.1, 0.0, 0.0, 1.0],
        "camera.yaml: camera_matrix: focal lengths must be positive, got fx=-615.0, fy=613.0",
    ),
    (
        "camera",
        "camera_matrix.data",
        [15.0, 0.0, 322.4, 0.0, 613.0, 237.1, 0.0, 0.0, 1.0],
        "camera.yaml: camera_matrix: fx must be within 0.1-10 times the image's longer side (64 to 6400 px), got 15",
    ),
    (
        "camera",
        "camera_matrix.data",
        [615.0, 0.0, 322.4, 0.0, 9613.0, 237.1, 0.0, 0.0, 1.0],
        "camera.yaml: camera_matrix: fy must be within 0.1-10 times the image's longer side (64 to 6400 px), got 9613",
    ),
    (
        "camera",
        "camera_matrix.data",
        [615.0, 0.0, 700.0, 0.0, 613.0, 237.1, 0.0, 0.0, 1.0],
        "camera.yaml: camera_matrix: cx must be on the image (0 to 640 px), got 700",
    ),
    (
        "camera",
        "camera_matrix.data",
        [615.0, 0.0, 322.4, 0.0, 613.0, -1.0, 0.0, 0.0, 1.0],
        "camera.yaml: camera_matrix: cy must be on the image (0 to 480 px), got -1",
    ),
    (
        "camera",
        "camera_matrix.data",
        [615.0, 3.0, 322.4, 0.0, 613.0, 237.1, 0.0, 0.0, 1.0],
        "camera.yaml: camera_matrix: skew must be 0 (OpenCV's PnP ignores it; at most 0.001 fx), got 3",
    ),
    (
        "camera",
        "camera_matrix.data",
        [615.0, 0.0, 322.4, 0.0, 613.0, 237.1, 0.0, 0.0, 2.0],
        "camera.yaml: camera_matrix: expected [fx s cx; 0 fy cy; 0 0 1], got [615.0, 0.0, 322.4, 0.0, "
        "613.0, 237.1, 0.0, 0.0, 2.0]",
    ),
    (
        "camera",
        "distortion_model",
        "x",
        "camera.yaml: distortion_model: 'x' is not supported (plumb_bob, rational_polynomial)",
    ),
    ("camera", "distortion_model", 3, "camera.yaml: distortion_model: expected a string, got 3"),
    (
        "camera",
        "distortion_model",
        "rational_polynomial",
        "camera.yaml: distortion_coefficients.data: expected a list of 8 numbers, got [-0.12, 0.08, "
        "0.0006, -0.0004, -0.02]",
    ),
    ("camera", "distortion_coefficients", DELETE, "camera.yaml: missing field 'distortion_coefficients'"),
    (
        "camera",
        "distortion_coefficients",
        [0.1, 0.2, 0.3],
        "camera.yaml: distortion_coefficients: expected a list of 4 or 5 numbers, got [0.1, 0.2, 0.3]",
    ),
    (
        "camera",
        "distortion_coefficients",
        "none",
        "camera.yaml: distortion_coefficients: expected a list of 4 or 5 numbers, got 'none'",
    ),
    ("camera", "camera_name", 7, "camera.yaml: camera_name: expected a string, got 7"),
    (
        "camera",
        "distortion_coefficients.data",
        [-0.9, 0.0, 0.0, 0.0, 0.0],
        "camera.yaml: distortion_coefficients: the lens cannot be inverted over the image (a pixel "
        "comes back 1.8e+02 px off)",
    ),
]


@pytest.mark.parametrize(
    ("kind", "path", "value", "line"),
    ERRORS,
    ids=[f"{k}:{p}={'DELETE' if v is DELETE else v!r}" for k, p, v, _ in ERRORS],
)
def test_one_bad_input_is_this_exact_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str, path: str, value: Any, line: str
) -> None:
    text = _mutated(FILES[kind][1], path, value)
    with pytest.raises((ConfigError, InputError)) as exc:
        _load(tmp_path, monkeypatch, kind, text)
    assert str(exc.value) == line


# (kind, key path of an unknown key, the exact warning; None: read past without one).
WARNINGS: list[tuple[str, str, str | None]] = [
    (
        "robot",
        "wheel_base",
        "robot.yaml: unknown key 'wheel_base' is ignored (known: camera_mount, laser_mount, "
        "front_offset, max_linear_speed, max_angular_speed, odometry)",
    ),
    (
        "robot",
        "camera_mount.w",
        "robot.yaml: unknown key 'camera_mount.w' is ignored (known: x, y, z, roll, pitch, yaw)",
    ),
    (
        "robot",
        "odometry.scale",
        "robot.yaml: unknown key 'odometry.scale' is ignored (known: distance_scale, rotation_scale, drift_per_m)",
    ),
    (
        "layout",
        "note",
        "layout.yaml: unknown key 'note' is ignored (known: dictionary, marker_size, markers, edge_offset_px, survey)",
    ),
    (
        "layout",
        "markers.far.role",
        "layout.yaml: unknown key 'markers.far.role' is ignored (known: id, y, z, x, roll, pitch, yaw, size)",
    ),
    ("target", "board", "target.yaml: unknown key 'board' is ignored (known: side, marker_size, dictionary, markers)"),
    (
        "docks",
        "docks.home.plugin",
        "dock database docks.yaml: unknown key 'docks.home.plugin' is ignored (known: type, frame, pose, id, layout)",
    ),
    ("docks", "version", None),
    (
        "camera",
        "lens",
        "camera.yaml: unknown key 'lens' is ignored (known: image_width, image_height, width, height, "
        "camera_name, camera_matrix, K, k, distortion_model, distortion_coefficients, D, d, "
        "rectification_matrix, projection_matrix, R, P, r, p, header, binning_x, binning_y, roi)",
    ),
]


@pytest.mark.parametrize(("kind", "path", "line"), WARNINGS, ids=[f"{k}:{p}" for k, p, _ in WARNINGS])
def test_an_unknown_key_is_this_exact_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, kind: str, path: str, line: str
) -> None:
    text = _mutated(FILES[kind][1], path, 1)
    with caplog.at_level(logging.WARNING, logger="monodock.config"):
        _load(tmp_path, monkeypatch, kind, text)
    assert [r.getMessage() for r in caplog.records if r.name == "monodock.config"] == ([line] if line else [])


def test_the_files_read_as_these_values(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The rich files' values, and the silent extras: a layout's survey record, a target's empty file."""
    robot = _load(tmp_path, monkeypatch, "robot", ROBOT)
    assert (robot.camera_mount.pitch, robot.laser_mount.yaw) == (0.05, 0.0349)
    assert (robot.odometry.distance_scale, robot.odometry.rotation_scale, robot.odometry.drift_per_m) == (
        1.013,
        -0.021,
        0.004,
    )
    layout = _load(tmp_path, monkeypatch, "layout", LAYOUT + "survey: {rms_px: 0.1}\n")
    assert (layout.roles, layout.edge_offset) == (("left", "center", "right", "far"), -0.4)
    assert (layout.marker("left").size, layout.marker("center").size) == (0.098, None)
    target = _load(tmp_path, monkeypatch, "target", TARGET)
    assert (target.marker_ids, target.marker_centres) == ((20, 21), ((0.13, 0.13), (0.37, 0.13)))
    assert _load(tmp_path, monkeypatch, "target", "\n") == DiamondTarget()
    assert _load(tmp_path, monkeypatch, "target", "side: 0.6\n") == DiamondTarget(side=0.6)
    docks = _load(tmp_path, monkeypatch, "docks", DOCKS)
    assert (docks["home"].id, docks["home"].layout) == ("7", "home_layout.yaml")
    camera = _load(tmp_path, monkeypatch, "camera", CAMERA)
    assert camera == CameraModel.default()
    spelled = CAMERA.replace("image_width", "width").replace("image_height", "height")
    for matrix, coefficients in (("K", "D"), ("k", "d")):
        flat = spelled.replace("camera_matrix", matrix).replace("distortion_coefficients", coefficients)
        assert _load(tmp_path, monkeypatch, "camera", flat) == camera
    four = CAMERA.replace("cols: 5, data: [-0.12, 0.08, 0.0006, -0.0004, -0.02]", "cols: 4, data: [-0.1, 0.08, 0, 0]")
    assert _load(tmp_path, monkeypatch, "camera", four).D == (-0.1, 0.08, 0.0, 0.0, 0.0)


# --- the writers: the exact bytes ----------------------------------------------------------------------------------


def _written(tmp_path: Path, name: str, value: Any) -> str:
    path = tmp_path / name
    value.save(path)
    return path.read_text(encoding="utf-8")


def _rich_camera() -> CameraModel:
    return CameraModel.from_intrinsics(
        1280, 720, 911.25, 910.5, 640.75, 361.125, (0.1, -0.05, 0.001, 0.0002, 0.01, 0.002, -0.003, 0.004), name="wide"
    )


def _bundle_metadata() -> str:
    """A bundle's metadata (what bundle.json and a dataset carry besides their tables), from the rich files."""
    meta = {
        "layout": parse_yaml(LAYOUT, "layout"),
        "robot": parse_yaml(ROBOT, "robot"),
        "camera": parse_yaml(CAMERA, "camera"),
    }
    x = np.array([0.9, 1.4, math.nan, 2.1])
    columns = {"frame": np.arange(4), "label_x_m": x, "label_valid": np.array([True, True, False, True])}
    return json_text(bundle_metadata(Dataset(columns, meta), depth_label="point", angle_label="line", source="d"))


def _summary_json() -> str:
    """dock-sim's summary.json (core.records' converter) of a small seeded run of made-up trials."""
    from monodock.core.pose2d import Pose2D
    from monodock.dock.states import FailureReason, State
    from monodock.evaluation.dock_sim import DockSimConfig, FilterFrame, TrialResult, summarize

    rng = np.random.default_rng(5)
    results = []
    for k, (case, method) in enumerate([(1, "pnp"), (1, "board"), (6, "pnp"), (6, "board")]):
        ok = k != 2
        frames = tuple(
            FilterFrame(
                (d, 0.02, -0.01),
                (d + 0.002, 0.021, -0.012),
                None if j == 2 else (d + rng.normal(0, 0.01), 0.0, 0.0),
                3.0,
            )
            for j, d in enumerate((0.4, 0.9, 1.6))
        )
        start = Pose2D(-1.2 - 0.1 * case, 0.2, -0.05)
        results.append(
            TrialResult(
                case=case, trial=0, method=method, start=start, classified_case=case if ok else None,
                state=State.DOCKED if ok else State.FAILED, reason="" if ok else "timed out",
                failure=None if ok else FailureReason.TIMEOUT, success=ok, retries=k % 2, time_s=12.0 + k,
                lateral_cm=0.3 * k - 0.2, longitudinal_cm=0.1, heading_deg=0.4, impact_speed=None if ok else 0.02,
                frames=200 + k, wall_s=10.0, render_s=8.0, perceive_s=1.0,
                path=((start.x, start.y, start.theta), (-0.34, 0.0, 0.0)), log=((0.0, "acquire"),),
                filter_frames=frames,
            )
        )  # fmt: skip
    return summarize(results, DockSimConfig(cases=(1, 6), trials=1, methods=("pnp", "board"))).to_json()


def _written_files(tmp_path: Path) -> dict[str, str]:
    (tmp_path / "robot.yaml").write_text(ROBOT, encoding="utf-8")
    (tmp_path / "layout.yaml").write_text(LAYOUT, encoding="utf-8")
    rich_robot = RobotConfig.load(tmp_path / "robot.yaml")
    rich_layout = DockLayout.load(tmp_path / "layout.yaml")
    return {
        "robot_default.yaml": _written(tmp_path, "r0.yaml", RobotConfig.default()),
        "robot_rich.yaml": _written(tmp_path, "r1.yaml", rich_robot),
        "layout_default.yaml": _written(tmp_path, "l0.yaml", DockLayout.default()),
        "layout_rich.yaml": _written(tmp_path, "l1.yaml", rich_layout),
        "camera_default.yaml": _written(tmp_path, "c0.yaml", CameraModel.default()),
        "camera_rich.yaml": _written(tmp_path, "c1.yaml", _rich_camera()),
        "bundle_metadata.json": _bundle_metadata(),
        "summary.json": _summary_json(),
    }


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    return _written_files(tmp_path_factory.mktemp("written"))


@pytest.mark.parametrize(
    "name",
    [
        "robot_default.yaml",
        "robot_rich.yaml",
        "layout_default.yaml",
        "layout_rich.yaml",
        "camera_default.yaml",
        "camera_rich.yaml",
        "bundle_metadata.json",
        "summary.json",
    ],
)
def test_a_writer_writes_these_exact_bytes(written: dict[str, str], name: str) -> None:
    assert written[name] == (DATA / name).read_text(encoding="utf-8")


def test_what_is_written_reads_back_equal(tmp_path: Path) -> None:
    for name, loader in (("robot_rich.yaml", RobotConfig.load), ("layout_rich.yaml", DockLayout.load)):
        again = tmp_path / f"again_{name}"
        loader(DATA / name).save(again)
        assert again.read_text(encoding="utf-8") == (DATA / name).read_text(encoding="utf-8")
    assert CameraModel.load(DATA / "camera_rich.yaml") == _rich_camera()


if __name__ == "__main__":  # rewrite the golden files: only for a deliberate, reviewed format change
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        for name, text in _written_files(Path(tmp)).items():
            (DATA / name).write_text(text, encoding="utf-8")
            print(f"wrote {DATA / name}", file=sys.stderr)


# --- a new layout key is one declaration ---------------------------------------------------------------------------


@dataclass(frozen=True)
class QuietLayout(DockLayout):
    """The layout with one key more, declared once, as a new optional key of DockLayout would be."""

    quiet_zone: float = setting(
        0.0, range=(0.0, 0.05), unit="m", omit_default=True, help="white margin printed around each marker"
    )


def test_a_new_layout_key_is_read_checked_written_and_old_files_stay_as_they_were(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.chdir(tmp_path)
    for name in ("layout_default.yaml", "layout_rich.yaml"):  # written before the key: read and written as before
        old = QuietLayout.load(DATA / name)
        assert old.quiet_zone == 0.0
        old.save(name)
        assert Path(name).read_text(encoding="utf-8") == (DATA / name).read_text(encoding="utf-8")
    Path("layout.yaml").write_text(LAYOUT + "quiet_zone: 0.012\n", encoding="utf-8")
    quiet = QuietLayout.load("layout.yaml")
    assert quiet.quiet_zone == 0.012
    quiet.save("again.yaml")
    assert (
        Path("again.yaml").read_text(encoding="utf-8")
        == (DATA / "layout_rich.yaml").read_text(encoding="utf-8") + "quiet_zone: 0.012\n"
    )
    assert QuietLayout.load("again.yaml") == quiet
    for bad, line in [
        (0.2, "layout.yaml: quiet_zone: must be within 0 to 0.05 m, got 0.2"),
        ("wide", "layout.yaml: quiet_zone: expected a number, got 'wide'"),
    ]:
        Path("layout.yaml").write_text(LAYOUT + f"quiet_zone: {bad}\n", encoding="utf-8")
        with pytest.raises(ConfigError) as exc:
            QuietLayout.load("layout.yaml")
        assert str(exc.value) == line
    Path("layout.yaml").write_text(LAYOUT + "quiet: 0.01\n", encoding="utf-8")
    with caplog.at_level(logging.WARNING, logger="monodock.config"):
        QuietLayout.load("layout.yaml")
    assert [r.getMessage() for r in caplog.records] == [
        "layout.yaml: unknown key 'quiet' is ignored (known: dictionary, marker_size, markers, edge_offset_px, "
        "quiet_zone, survey)"
    ]
