"""ROS 2 nodes: the detector, the docking mission and the simulated robot (they need rclpy)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.ros.detector import run_detector
    from monodock.ros.dock_node import run_dock
    from monodock.ros.recorder import run_recorder
    from monodock.ros.sim_node import run_sim

__all__ = [
    "run_detector",
    "run_dock",
    "run_recorder",
    "run_sim",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
