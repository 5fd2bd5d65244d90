"""The command line of ``monodock-sim-ros`` (node ``monodock_sim``): the simulator as a robot on a ROS 2 graph.

Apart from ``cli.ros_nodes`` because it loads the simulator, which the robot side's entry points must not.
Its settings are ROS parameters (``--ros-args -p start:=[x,y,yaw] -p seed:=3``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from monodock.ros.sim_node import run_sim

__all__ = ["sim_main"]


def sim_main(argv: Sequence[str] | None = None) -> int:
    """``monodock-sim-ros``: the simulated robot on the graph until shut down."""
    return run_sim(list(sys.argv if argv is None else ["monodock-sim-ros", *argv]))
