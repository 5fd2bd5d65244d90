"""The graph drivers' node processes (tests/ros/graph_dock*.py): how they start and how they end.

Each node gets SIGTERM when its driver ends, however the driver ends (PR_SET_PDEATHSIG): none outlives its run.
"""

from __future__ import annotations

import signal
import subprocess

ORPHANS_END = "import ctypes, signal; ctypes.CDLL(None).prctl(1, signal.SIGTERM); "
SIM = ORPHANS_END + "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv)"
DOCK = ORPHANS_END + "from monodock.cli.ros_nodes import dock_main; import sys; sys.exit(dock_main(sys.argv[1:]))"


def stop_nodes(*processes: subprocess.Popen[bytes]) -> None:
    """SIGINT to each node still running, then wait for all. A node that will not end gets SIGABRT (exit code -6),
    which with PYTHONFAULTHANDLER (tests/private_graph.py) writes every thread's stack to its log, where it hung;
    then, if even that does not end it, SIGKILL (-9)."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            # Generous: on a starved CI host a node's DDS teardown after SIGINT took over 20 s once (stop 33's CI).
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGABRT)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
