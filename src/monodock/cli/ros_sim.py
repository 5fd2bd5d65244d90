"""The command line of ``monodock-sim-ros`` (node ``monodock_sim``): the simulator as a robot on a ROS 2 graph.

Apart from ``cli.ros_nodes`` because it loads the simulator, which the robot side's entry points must not.
Its settings are ROS parameters (``--ros-args -p start:=[x,y,yaw] -p seed:=3``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from monodock.ros.sim_node import run_sim

__all__ = ["sim_main"]


USAGE = """usage: monodock-sim-ros [-h] [--ros-args -p NAME:=VALUE ... [--params-file FILE]]

node monodock_sim: the simulator as a robot on a ROS 2 graph. It publishes image, camera_info, odom, /tf,
/tf_static, battery_state, contact, rear_range, ground_truth and /clock, and drives by cmd_vel. Its settings are
ROS parameters: start:=[x,y,yaw] (m, rad; the robot in the dock frame), seed, layout, robot, camera, camera_rate,
cmd_vel_timeout, enable_stamped_cmd_vel (TwistStamped, default true), nuisances (default|clean), frame_id,
odom_frame, camera_frame, camera_frame_id, rear_range_frame (docs/ros2.md, "The simulated robot").
"""


def sim_main(argv: Sequence[str] | None = None) -> int:
    """``monodock-sim-ros``: the simulated robot on the graph until shut down (``-h``: its usage, and nothing
    starts)."""
    args = list(sys.argv if argv is None else ["monodock-sim-ros", *argv])
    own = args[1 : args.index("--ros-args")] if "--ros-args" in args else args[1:]
    if "-h" in own or "--help" in own:
        print(USAGE, end="")
        return 0
    if own:
        print(f"monodock-sim-ros: error: unrecognised arguments: {' '.join(own)} (see monodock-sim-ros --help)",
              file=sys.stderr)  # fmt: skip
        return 2
    return run_sim(args)
