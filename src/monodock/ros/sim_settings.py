"""The simulated robot node's settings (``monodock.ros.sim_node``), apart from rclpy: what a test or a recipe needs
to know of it (its start, its frames, its battery's current) without loading ROS."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CHARGING_CURRENT", "DRAIN_CURRENT", "SimSettings"]

# sensor_msgs/BatteryState.current, A: positive while the contacts charge, as Nav2's SimpleChargingDock reads it
# (current > charging_threshold), negative otherwise.
CHARGING_CURRENT = 1.5
DRAIN_CURRENT = -0.8


@dataclass(frozen=True)
class SimSettings:
    """The node's settings: ROS parameters of the same names (``PARAMETERS``), and the frames of its messages."""

    start: tuple[float, float, float] = (-1.8, 0.0, 0.0)  # x, y (m), yaw (rad) of base_link in the dock frame
    seed: int = 0
    layout: str = ""
    robot: str = ""
    camera: str = ""
    camera_rate: float = 15.0
    cmd_vel_timeout: float = 0.5
    enable_stamped_cmd_vel: bool = True  # cmd_vel is TwistStamped (Kilted's default, as the docking node sends it)
    nuisances: str = "default"  # the camera's: "default" (a cheap indoor webcam) or "clean" (the exact render)
    frame_id: str = "base_link"
    camera_frame_id: str = "camera_optical_frame"
    odom_frame: str = "odom"
    camera_frame: str = "camera_link"
    rear_range_frame: str = "rear_range"
