"""rclpy for the nodes, or one clear line on how to get it: the rest of monodock never needs ROS 2."""

from __future__ import annotations

try:
    # The one module-level import of rclpy: the nodes import it from here (nothing else in monodock does).
    import rclpy  # type: ignore[import-not-found, unused-ignore]
    from rclpy.lifecycle import LifecycleNode  # type: ignore[import-not-found, unused-ignore]
    from rclpy.node import Node  # type: ignore[import-not-found, unused-ignore]
except ImportError as _exc:  # the message should say what to do, not only what is missing
    raise ModuleNotFoundError(
        "monodock's ROS 2 nodes need rclpy: pip install ros-kilted-rclpy ros-kilted-rmw-fastrtps-cpp and the "
        "message packages (docs/ros2.md), or source a ROS 2 installation; the rest of monodock works without it",
        name="rclpy",
    ) from _exc

__all__ = ["LifecycleNode", "Node", "rclpy"]
