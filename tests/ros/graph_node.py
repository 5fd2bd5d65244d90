"""Driver: run one monodock ROS 2 node's command line (inside a private network namespace) with the given arguments.

``graph_node.py dock ARGS...`` runs monodock-dock-ros, ``detector`` monodock-ros, ``sim`` monodock-sim-ros; its
exit code is this script's.
"""

from __future__ import annotations

import sys

from monodock.cli.ros_nodes import detector_main, dock_main
from monodock.cli.ros_sim import sim_main

main = {"dock": dock_main, "detector": detector_main, "sim": sim_main}[sys.argv[1]]
sys.exit(main(sys.argv[2:]))
