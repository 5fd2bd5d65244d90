"""The docking node's options (``monodock.ros.dock_node``), apart from rclpy: each declared once as a setting, its
ROS parameter (``PARAMETERS``) and its ``monodock-dock-ros`` flag derived from that declaration."""

from __future__ import annotations

from dataclasses import dataclass

from monodock.core.settings import inherited, setting
from monodock.io.nav2 import DOCK_POSE_COVARIANCE_TOPIC, DOCK_POSE_TOPIC
from monodock.ros.lifecycle import autostart_setting, bond_heartbeat_setting
from monodock.ros.options import EstimatorOptions
from monodock.ros.parameters import Parameter, parameters_of

__all__ = ["PARAMETERS", "DockOptions"]


@dataclass(frozen=True)
class DockOptions(EstimatorOptions):
    """The node's fixed settings (its command-line flags, which set the parameters' defaults)."""

    robot: str | None = inherited(
        EstimatorOptions,
        "robot",
        help="robot YAML: mounts, front_offset, speed limits (needed without a model; overrides the model's)",
    )
    camera_info_topic: str = setting(
        "camera_info", help="sensor_msgs/CameraInfo, used when no camera file is given", cli_help=""
    )
    odom_topic: str = setting("odom", help="nav_msgs/Odometry of the base", cli_help="")
    cmd_vel_topic: str = setting(
        "cmd_vel", help="geometry_msgs/TwistStamped (Twist with enable_stamped_cmd_vel: false) to the base", cli_help=""
    )
    battery_topic: str = setting(
        "battery_state",
        help="sensor_msgs/BatteryState: current above a dock type's charging_threshold (or, with no current, "
        "CHARGING or FULL) confirms docking (empty: no charging signal)",
        cli_help="BatteryState; empty: no charging signal",
    )
    contact_topic: str = setting(
        "contact",
        help="std_msgs/Bool, true on contact with the charger (empty: none)",
        cli_help="std_msgs/Bool contact switch; empty: none",
    )
    rear_range_topic: str = setting(
        "rear_range",
        help="sensor_msgs/Range behind the robot, watched while reversing (empty: none)",
        cli_help="sensor_msgs/Range behind; empty: none",
    )
    pose_topic: str = setting(
        DOCK_POSE_TOPIC,
        help="PoseStamped of the dock filter's estimate in base_link (for Nav2's docking server)",
        cli_help="",
    )
    pose_covariance_topic: str = setting(
        DOCK_POSE_COVARIANCE_TOPIC,
        help="the same with its covariance (PoseWithCovarianceStamped)",
        cli_help="",
    )
    frame_id: str = setting("base_link", help="the robot's base frame", cli_help="")
    config: str = setting(
        "",
        help="docking config YAML read before the parameters (docs/docking.md); empty: the defaults",
        cli_help="docking config YAML (docs/docking.md), read before parameters",
    )
    odom_timeout: float = setting(
        1.0,
        positive=True,
        help="a mission fails with odometry-lost when odometry is older than this, s",
        cli_help="odometry older than this: stop, s",
    )
    sensor_timeout: float = setting(
        1.0,
        positive=True,
        help="battery, contact and rear range readings older than this count as absent, s",
        cli_help="other sensors' age limit, s",
    )
    dock_id: str = setting(
        "home_dock",
        help="the one dock's name when no docks or dock_database are given (DockRobot's dock_id)",
        cli_help="the one dock's name without a dock database (%(default)s)",
    )
    dock_type: str = setting("monodock", help="the one dock type's name when no dock_plugins are given", flag="")
    enable_stamped_cmd_vel: bool = setting(
        True,
        help="cmd_vel as geometry_msgs/TwistStamped (Kilted's default); false: Twist",
        flag="--stamped-cmd-vel",
        cli_help="cmd_vel as TwistStamped (default, as Kilted); --no-stamped-cmd-vel: Twist",
    )
    dock_prestaging_tolerance: float = setting(
        0.5,
        positive=True,
        help="a robot this close to the staging pose (m, with the heading error in rad) is not sent there",
        flag="",
    )
    navigator_bt_xml: str = setting(
        "", help="the behaviour tree navigate_to_pose runs to the staging pose; empty: its default", flag=""
    )
    autostart_node: bool = autostart_setting(
        True,
        flag="--autostart",
        cli_help="configure and activate at start (default); --no-autostart: wait for nav2_lifecycle_manager",
    )
    bond_heartbeat_period: float = bond_heartbeat_setting(flag="")


# One per DockOptions setting, of the same name, all read once at start-up (the docking config's keys are parameters
# too, declared with the config's values as defaults: DockNode._declare_config; the dock database's names are
# declared by monodock.ros.dock_database).
PARAMETERS: dict[str, Parameter] = parameters_of(DockOptions)
