"""The camera mount from /tf_static (monodock.ros.tf), without a graph: the URDF-like chains a robot publishes,
composed, against the mount the robot file says; the warnings a wrong file gets, once."""

from __future__ import annotations

import importlib.util
import math
from typing import Any

import numpy as np
import pytest

from monodock.core import transforms
from monodock.core.robot import Mount, RobotConfig

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("tf2_msgs") is None, reason="tf2_msgs is not installed (built with monodock)"
)


class _Logger:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, text: str) -> None:
        self.lines.append(("info", text))

    def warning(self, text: str) -> None:
        self.lines.append(("warning", text))


class _Node:
    """What CameraMountFromTF uses of a node: its logger (the subscription is the graph tests')."""

    def __init__(self) -> None:
        self.logger = _Logger()
        self.callback: Any = None

    def get_logger(self) -> _Logger:
        return self.logger


def _tf_static(*edges: tuple[str, str, np.ndarray]) -> Any:
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    from monodock.ros.tf import set_transform

    return TFMessage(transforms=[set_transform(TransformStamped(), p, c, T, 0.0) for p, c, T in edges])


def _urdf_like(robot: RobotConfig) -> list[tuple[str, str, np.ndarray]]:
    """base_footprint -> base_link -> mast -> camera_link -> camera_optical_frame, as a URDF might put it, and a
    laser on another branch; composed, base_link -> optical is the robot's mount."""
    mast = transforms.transform(transforms.rotation_from_rpy(0.0, 0.0, 0.3), (0.05, -0.02, 0.15))
    link = robot.base_T_camera_link()
    optical = np.eye(4)
    optical[:3, :3] = transforms.LINK_R_OPTICAL
    return [
        ("base_footprint", "base_link", transforms.transform(np.eye(3), (0.0, 0.0, 0.04))),
        ("base_link", "laser", robot.base_T_laser()),
        ("base_link", "mast", mast),
        ("mast", "camera_link", transforms.invert(mast) @ link),
        ("camera_link", "camera_optical_frame", optical),
    ]


def _mount(**kwargs: Any) -> Any:
    from monodock.ros.tf import CameraMountFromTF

    node = _Node()
    mount = CameraMountFromTF(node, "base_link", subscribe=False, **kwargs)
    node.callback = mount.on_tf_static
    return node, mount


def test_the_chain_composes_to_the_robot_s_optical_frame() -> None:
    robot = RobotConfig(camera_mount=Mount(0.12, -0.03, 0.31, 0.01, 0.2, -0.05))
    node, mount = _mount()
    node.callback(_tf_static(*_urdf_like(robot)))
    np.testing.assert_allclose(mount.lookup("base_link", "camera_optical_frame"), robot.base_T_optical(), atol=1e-12)
    # Up and across the tree: base_footprint is 4 cm below base_link; the laser to the camera through base_link.
    above = mount.lookup("base_footprint", "camera_optical_frame")
    np.testing.assert_allclose(above[:3, 3], robot.base_T_optical()[:3, 3] + (0.0, 0.0, 0.04), atol=1e-12)
    across = mount.lookup("laser", "camera_optical_frame")
    np.testing.assert_allclose(across, transforms.invert(robot.base_T_laser()) @ robot.base_T_optical(), atol=1e-12)
    assert mount.lookup("base_link", "nowhere") is None
    assert mount.lookup("/base_link", "/camera_optical_frame") is not None  # tf2 drops a leading slash


def test_a_wrong_robot_file_is_replaced_by_tf_static_and_warned_once() -> None:
    true = RobotConfig(camera_mount=Mount(0.17, 0.0, 0.25, 0.0, 0.1, 0.0))
    wrong = RobotConfig(camera_mount=Mount(0.17, 0.02, 0.25, 0.0, 0.1, math.radians(1.0)))
    node, mount = _mount()
    assert mount.robot(wrong, "camera_optical_frame") == wrong  # nothing on /tf_static yet: the file's
    node.callback(_tf_static(*_urdf_like(true)))
    for _ in range(3):
        used = mount.robot(wrong, "camera_optical_frame")
        np.testing.assert_allclose(used.base_T_optical(), true.base_T_optical(), atol=1e-12)
        assert used.front_offset == wrong.front_offset  # only the camera mount comes from TF
    warnings = [text for kind, text in node.logger.lines if kind == "warning"]
    assert len(warnings) == 1
    assert "are 2.0 cm and 1.00° apart; estimating with /tf_static's" in warnings[0]
    assert mount.robot(wrong, "") == wrong  # an image without a frame: the file's


def test_camera_mount_source_robot_keeps_the_file_and_a_close_file_is_not_warned() -> None:
    true = RobotConfig.default()
    off = RobotConfig(camera_mount=Mount(0.17, 0.0, 0.25, 0.0, 0.0, math.radians(0.8)))
    node, mount = _mount(source="robot")
    node.callback(_tf_static(*_urdf_like(true)))
    assert mount.robot(off, "camera_optical_frame") == off
    assert "estimating with the robot file's" in node.logger.lines[-1][1]
    close = RobotConfig(camera_mount=Mount(0.175, 0.0, 0.25))  # 5 mm: within the 1 cm tolerance
    node, mount = _mount()
    node.callback(_tf_static(*_urdf_like(true)))
    used = mount.robot(close, "camera_optical_frame")
    np.testing.assert_allclose(used.base_T_optical(), true.base_T_optical(), atol=1e-12)
    assert [kind for kind, _ in node.logger.lines] == ["info"]


def test_a_malformed_tree_does_not_hang_or_break_the_lookup() -> None:
    node, mount = _mount()
    loop = transforms.transform(np.eye(3), (0.1, 0.0, 0.0))
    node.callback(_tf_static(("a", "b", loop), ("b", "a", loop), ("base_link", "c", loop)))
    assert mount.lookup("base_link", "a") is None
    msg = _tf_static(("base_link", "camera_optical_frame", loop))
    msg.transforms[0].transform.rotation.w = 0.0  # a zero quaternion: skipped, said once
    node.callback(msg)
    node.callback(msg)
    assert mount.lookup("base_link", "camera_optical_frame") is None
    assert sum("skipped" in text for _, text in node.logger.lines) == 1
