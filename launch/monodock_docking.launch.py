"""Launch monodock's docking node in place of Nav2's docking server.

The node is ``monodock-dock-ros``, named ``docking_server`` (as Nav2's ``navigation_launch.py`` names its docking
server, and its lifecycle manager's ``node_names`` list it), a lifecycle node with a bond. Its actions are
``dock_robot`` and ``undock_robot`` in ``namespace``, where Nav2's behaviour trees call them.

Arguments, as Nav2's launch files have them:
    namespace: the robot's namespace ("").
    use_sim_time: the simulator's /clock (false).
    params_file: the node's parameters (monodock's config/monodock_docking.yaml).
    autostart: the lifecycle manager brings the node up at once (true).
    use_lifecycle_manager: start a lifecycle manager of its own, ``lifecycle_manager_docking`` (true); false where
        Nav2's ``lifecycle_manager_navigation`` already lists ``docking_server``.
    layout, robot: the dock layout and robot files (the package's config/layout.yaml and config/robot.yaml, the
        simulator's); a params file that sets ``layout`` or ``robot`` wins.
    log_level: info.

    ros2 launch monodock monodock_docking.launch.py params_file:=/path/to/params.yaml use_sim_time:=true
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

NODE_NAME = "docking_server"


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("monodock")
    namespace = LaunchConfiguration("namespace")
    use_sim_time = LaunchConfiguration("use_sim_time")
    params_file = LaunchConfiguration("params_file")
    autostart = LaunchConfiguration("autostart")
    log_level = LaunchConfiguration("log_level")
    # Absolute /tf and /tf_static into the namespace, as Nav2's bringup does for a namespaced robot.
    remappings = [("/tf", "tf"), ("/tf_static", "tf_static")]
    arguments = [
        DeclareLaunchArgument("namespace", default_value="", description="Top-level namespace"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="Use the simulator's /clock if true"),
        DeclareLaunchArgument(
            "params_file",
            default_value=os.path.join(share, "config", "monodock_docking.yaml"),
            description="Full path to the docking node's ROS 2 parameters file",
        ),
        DeclareLaunchArgument("autostart", default_value="true", description="Automatically start up the docking node"),
        DeclareLaunchArgument(
            "use_lifecycle_manager",
            default_value="true",
            description="Start lifecycle_manager_docking (false: Nav2's lifecycle manager lists docking_server)",
        ),
        DeclareLaunchArgument(
            "layout", default_value=os.path.join(share, "config", "layout.yaml"), description="Dock layout YAML"
        ),
        DeclareLaunchArgument(
            "robot", default_value=os.path.join(share, "config", "robot.yaml"), description="Robot YAML"
        ),
        DeclareLaunchArgument("log_level", default_value="info", description="log level"),
    ]
    docking = Node(
        package="monodock",
        executable="monodock-dock-ros",
        name=NODE_NAME,
        namespace=namespace,
        output="screen",
        # Later entries win: the layout and robot arguments, then the params file, then what the launch fixes.
        parameters=[
            {"layout": LaunchConfiguration("layout"), "robot": LaunchConfiguration("robot")},
            params_file,
            {"use_sim_time": use_sim_time, "autostart_node": False},
        ],
        arguments=["--ros-args", "--log-level", log_level],
        remappings=remappings,
    )
    manager = Node(
        package="nav2_lifecycle_manager",
        executable="lifecycle_manager",
        name="lifecycle_manager_docking",
        namespace=namespace,
        output="screen",
        condition=IfCondition(LaunchConfiguration("use_lifecycle_manager")),
        arguments=["--ros-args", "--log-level", log_level],
        parameters=[{"use_sim_time": use_sim_time, "autostart": autostart, "node_names": [NODE_NAME]}],
    )
    return LaunchDescription([*arguments, docking, manager])
