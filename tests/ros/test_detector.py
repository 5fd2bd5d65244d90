"""The rule that only the ROS modules need rclpy, and what of the detector's module can be tested without it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from monodock.core.camera import CameraModel


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


def test_camera_mismatch_names_what_disagrees_beyond_one_percent(monkeypatch: pytest.MonkeyPatch) -> None:
    """The detector's check of camera_info against the camera in use (a pure function of its module, imported here
    against stand-ins for rclpy; the node itself is tested over DDS in test_detector_graph.py)."""
    import importlib
    import types

    stand_ins = (("rclpy", {}), ("rclpy.node", {"Node": object}), ("rclpy.lifecycle", {"LifecycleNode": object}))
    for name, attrs in stand_ins:
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    for name in ("monodock.ros._rclpy", "monodock.ros.detector"):  # imported afresh against the stand-ins
        monkeypatch.delitem(sys.modules, name, raising=False)
    mismatch = importlib.import_module("monodock.ros.detector").camera_mismatch
    for name in ("monodock.ros._rclpy", "monodock.ros.detector"):  # forgotten afterwards: built on stand-ins
        monkeypatch.delitem(sys.modules, name)

    def lens(fx: float = 615.0, cx: float = 322.4, k1: float = -0.2, size: tuple[int, int] = (640, 480)) -> CameraModel:
        return CameraModel.from_intrinsics(*size, fx, 613.0, cx, 237.1, (k1, 0.05, 0.0, 0.0, 0.0))

    used = lens()
    assert mismatch(used, lens()) is None
    assert mismatch(used, lens(fx=615.0 * 1.005)) is None
    assert mismatch(used, lens(fx=615.0 * 1.02)) == "fx 627.30, not 615.00"
    assert mismatch(used, lens(cx=330.0)) == "cx 330.00, not 322.40"
    assert mismatch(used, lens(size=(320, 240))) == "image size 320x240, not 640x480"
    assert mismatch(used, lens(k1=-0.202)) is None  # 0.1 % of the radius at the corners
    assert mismatch(used, lens(k1=-0.25)).startswith("its distortion moves the image's edge by up to")
    undistorted = CameraModel.from_intrinsics(640, 480, 615.0, 613.0, 322.4, 237.1)
    assert "distortion" in mismatch(undistorted, used)


@pytest.mark.parametrize("node", ["detector", "dock"])
def test_a_params_file_that_names_a_key_twice_is_one_line(node: str, tmp_path: Path) -> None:
    """rcl's parser keeps the last of a key named twice without a word; the nodes read a params file with monodock's
    YAML loader first (issue 24), before rclpy starts anything (a subprocess: the real rclpy is imported)."""
    params = tmp_path / "params.yaml"
    params.write_text("monodock_detector:\n  ros__parameters:\n    method: board\n    method: pnp\n")
    main = "detector_main" if node == "detector" else "dock_main"
    script = f"import sys; from monodock.cli.ros_nodes import {main}; sys.exit({main}(sys.argv[1:]))"
    done = subprocess.run(
        [sys.executable, "-c", script, "--ros-args", "--params-file", str(params)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    prog = "monodock-ros" if node == "detector" else "monodock-dock-ros"
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"{prog}: error: {params}: key 'method' appears twice (lines 3 and 4); each key may appear once"
    ]
