"""Driver (tests/ros/test_launch.py, in a private network namespace): the docking node built in this process with the
arguments launch/monodock_docking.launch.py gives it, and what it then holds.

Arguments: PARAMS_FILE LAYOUT ROBOT. Prints {"kind": "params", name, values (every parameter), docks, state}.
"""

from __future__ import annotations

import json
import sys

import rclpy

from monodock.ros.dock_node import DockNode
from monodock.ros.dock_options import DockOptions

params, layout, robot = sys.argv[1:4]
rclpy.init(
    args=[
        "monodock-dock-ros",
        "--ros-args",
        "-r",
        "__node:=docking_server",
        "-p",
        f"layout:={layout}",
        "-p",
        f"robot:={robot}",
        "--params-file",
        params,
        "-p",
        "autostart_node:=false",
        "-p",
        "use_sim_time:=false",
    ]
)
node = DockNode(DockOptions())  # refuses (one line, an InputError) any key of the file it does not declare
values = {name: node.get_parameter(name).value for name in node._parameters}
docks = {n: [d.type, d.frame, list(d.pose) if d.pose else None] for n, d in node.database.docks.items()}
state = node._state_machine.current_state[1]
print(json.dumps({"kind": "params", "name": node.get_name(), "values": values, "docks": docks, "state": state}))
node.stop("done")
node.destroy_node()
rclpy.shutdown()
