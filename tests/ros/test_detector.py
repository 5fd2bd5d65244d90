"""The detector node (ros.detector) against stand-ins for rclpy, and the rule that only the ROS modules need rclpy."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from monodock.core.pose import DockPose
from monodock.estimation.estimator import Estimator
from monodock.estimation.pnp import PoseEstimate, estimate_board
from monodock.io.nav2 import (
    planar_covariance,
)
from monodock.sim import Simulator


def test_no_monodock_module_needs_rclpy() -> None:
    """Every module but the ROS 2 ones (the two nodes and their command lines) imports with rclpy blocked; those
    then name rclpy."""
    script = """
import importlib, pkgutil, sys
sys.modules["rclpy"] = None  # any import of rclpy now fails
import monodock
ros = ("monodock.cli.ros_nodes", "monodock.cli.ros_sim", "monodock.ros._rclpy", "monodock.ros.detector",
       "monodock.ros.dock_node", "monodock.ros.sim_node")
names = [m.name for m in pkgutil.walk_packages(monodock.__path__, "monodock.") if m.name not in ros]
for name in names:
    importlib.import_module(name)
assert "monodock.io.live" in names and "monodock.io.nav2" in names and "monodock.dock.controller" in names
for name in ros:
    try:
        importlib.import_module(name)
    except ImportError as exc:
        print(name, exc)
    else:
        raise SystemExit(name + " imported without rclpy")
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()[-6:]
    assert [line.split()[0] for line in lines] == [
        "monodock.cli.ros_nodes",
        "monodock.cli.ros_sim",
        "monodock.ros._rclpy",
        "monodock.ros.detector",
        "monodock.ros.dock_node",
        "monodock.ros.sim_node",
    ]
    assert all("rclpy" in line for line in lines)


def test_ros_node_without_rclpy_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    """Importing the ROS node without rclpy is a clear ImportError naming rclpy (rclpy blocked, installed or not:
    the test process never loads the real one)."""
    monkeypatch.setitem(sys.modules, "rclpy", None)
    monkeypatch.setitem(sys.modules, "rclpy.node", None)
    for name in ("monodock.ros._rclpy", "monodock.ros.detector"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    with pytest.raises(ImportError, match="rclpy") as info:
        import monodock.ros.detector  # noqa: F401
    assert info.value.name == "rclpy"
    for name in ("monodock.ros._rclpy", "monodock.ros.detector"):
        monkeypatch.delitem(sys.modules, name, raising=False)


def test_ros_node_publishes_the_covariance_beside_the_pose(
    drive: tuple[Simulator, list[DockPose], Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The live node, against stand-ins for rclpy and the message packages (ROS 2 is not installed here): an
    image in, a PoseStamped out matching the truth and, with a covariance, a PoseWithCovarianceStamped of the
    same pose with the 6x6 layout of monodock.io.nav2; without one, the pose alone."""
    import array
    import importlib
    import sys
    import types

    sim, poses, _, folder = drive

    class Msg(types.SimpleNamespace):
        def __init__(self, **kw: object) -> None:
            super().__init__(**kw)

    class Stamped(Msg):
        def __init__(self, **kw: object) -> None:
            super().__init__(header=Msg(stamp=None, frame_id=""), **kw)

    published: dict[str, list[Any]] = {}
    callbacks: dict[str, Any] = {}

    class Node:
        def __init__(self, _name: str) -> None:
            pass

        def create_publisher(self, _type: object, topic: str, _depth: int) -> object:
            return Msg(publish=published.setdefault(topic, []).append)

        def create_subscription(self, _type: object, topic: str, callback: object, _depth: int) -> None:
            callbacks[topic] = callback

        def get_logger(self) -> object:
            return Msg(warning=pytest.fail, info=lambda _text: None)

    def module(name: str, **attrs: object) -> None:
        mod = types.ModuleType(name)
        mod.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, mod)

    module("rclpy")
    module("rclpy.node", Node=Node)
    module("rclpy.qos", qos_profile_sensor_data=1)
    module(
        "geometry_msgs.msg",
        Point=Msg,
        Pose=Msg,
        Quaternion=Msg,
        PoseStamped=Stamped,
        PoseWithCovariance=Msg,
        PoseWithCovarianceStamped=Stamped,
    )
    module("sensor_msgs.msg", CameraInfo=object, CompressedImage=object, Image=object)
    for name in ("monodock.ros._rclpy", "monodock.ros.detector"):  # imported afresh against the stand-ins
        monkeypatch.delitem(sys.modules, name, raising=False)
    ros_node = importlib.import_module("monodock.ros.detector")
    for name in ("monodock.ros._rclpy", "monodock.ros.detector"):  # forgotten afterwards: built on stand-ins
        monkeypatch.delitem(sys.modules, name)
    options = ros_node.DetectorOptions(
        layout=str(folder / "layout.yaml"), robot=str(folder / "robot.yaml"), image_topic="/cam"
    )
    node = ros_node.DockPoseNode(options)
    cov = np.array([[2e-6, 1e-7, 0.0], [1e-7, 1e-6, -2e-7], [0.0, -2e-7, 3e-5]])
    attach = [True]

    def board_with_covariance(det: Any) -> PoseEstimate:
        e = estimate_board(det, sim.camera, sim.layout, sim.robot)
        return dataclasses.replace(e, method="fused", covariance=cov if attach[0] else None)

    node.estimator = Estimator(sim.camera, sim.layout, sim.robot, ("fused",), extra={"fused": board_with_covariance})
    node.method = "fused"
    image = sim.frame(poses[0], 0.0, np.random.default_rng(1)).image
    h, w = image.shape
    header = Msg(stamp=Msg(sec=3, nanosec=250_000_000), frame_id="camera")
    raw = Msg(header=header, height=h, width=w, encoding="mono8", is_bigendian=0, step=w)
    raw.data = array.array("B", image.tobytes())
    callbacks["/cam"](raw)
    attach[0] = False
    callbacks["/cam"](raw)
    plain, with_cov = published["detected_dock_pose"], published["detected_dock_pose_with_covariance"]
    assert (len(plain), len(with_cov)) == (2, 1)
    out, both = plain[0], with_cov[0]
    assert out.header.stamp is header.stamp
    assert both.header.stamp is header.stamp
    assert out.header.frame_id == both.header.frame_id == "base_link"
    assert both.pose.pose is out.pose
    assert abs(out.pose.position.x - poses[0].x) < 0.01
    assert abs(out.pose.position.y - poses[0].y) < 0.01
    assert abs(2 * math.atan2(out.pose.orientation.z, out.pose.orientation.w) - poses[0].yaw) < math.radians(1.0)
    np.testing.assert_allclose(planar_covariance(both.pose.covariance), cov)
    assert sum(abs(v) for v in both.pose.covariance) == pytest.approx(float(np.abs(cov).sum()))
