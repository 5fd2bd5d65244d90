"""The simulated robot node's settings (``monodock.ros.sim_node``), apart from rclpy: what a test or a recipe needs
to know of it (its start, its frames, its battery's current) without loading ROS."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from monodock.core.settings import Policy, setting

__all__ = ["CHARGING_CURRENT", "DRAIN_CURRENT", "SimSettings"]

# sensor_msgs/BatteryState.current, A: positive while the contacts charge, as Nav2's SimpleChargingDock reads it
# (current > charging_threshold), negative otherwise.
CHARGING_CURRENT = 1.5
DRAIN_CURRENT = -0.8


@dataclass(frozen=True)
class SimSettings:
    """The node's settings: ROS parameters of the same names (``sim_node.PARAMETERS``, derived from these
    declarations), and the frames of its messages."""

    SETTINGS: ClassVar[Policy] = Policy(what="simulated robot", live=True)  # writable, though a change does nothing

    start: tuple[float, float, float] = setting(
        (-1.8, 0.0, 0.0), help="x, y (m), yaw (rad) of base_link in the dock frame"
    )
    seed: int = setting(0, help="the simulator's random seed")
    layout: str = setting("", help="dock layout YAML; empty: the built-in default")
    robot: str = setting("", help="robot YAML; empty: the built-in default")
    camera: str = setting("", help="camera file (ROS camera_info YAML or OpenCV); empty: the built-in default")
    camera_rate: float = setting(15.0, positive=True, help="frames per second")
    cmd_vel_timeout: float = setting(
        0.5, positive=True, help="simulated seconds of cmd_vel silence before the base stops"
    )
    enable_stamped_cmd_vel: bool = setting(
        True, help="cmd_vel is geometry_msgs/TwistStamped (Kilted's default, as monodock_dock sends it); false: Twist"
    )
    nuisances: str = setting(
        "default",
        choices=("default", "clean"),
        help="the camera's nuisances: default (a cheap indoor webcam) or clean (the exact render)",
    )
    # Frames (two simulated robots on one graph need their own): odometry's, /tf's and the images'.
    frame_id: str = setting("base_link", help="the robot's base frame (odometry's child, /tf's odom -> this)")
    camera_frame_id: str = setting(
        "camera_optical_frame", help="the images' frame, the camera's optical frame, on /tf_static"
    )
    odom_frame: str = setting("odom", help="the odometry frame (odometry's and /tf's parent)")
    camera_frame: str = setting("camera_link", help="the camera body's frame (x forward, y left, z up) on /tf_static")
    rear_range_frame: str = setting("rear_range", help="the rear range sensor's frame (its messages' frame_id)")
