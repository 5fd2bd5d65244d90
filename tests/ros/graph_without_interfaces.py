"""Driver (tests/packaging/test_install_fallback.py, inside a private network namespace): the nodes as an install
without the built interfaces runs them (nav2_msgs and tf2_msgs cannot be imported): the docking node, the detector
and the simulated robot start, say once what is missing, serve what they still can, and end cleanly.

Prints JSON lines: the services and topics seen on the graph, then each node's exit code and log.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from graph_processes import stop_nodes

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig

# What an install without the interfaces looks like to the nodes: importing either package fails.
HIDE = (
    "import sys, importlib.abc\n"
    "class Hidden(importlib.abc.MetaPathFinder):\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.split('.')[0] in ('nav2_msgs', 'tf2_msgs'):\n"
    "            raise ModuleNotFoundError(f\"No module named '{name}'\")\n"
    "        return None\n"
    "sys.meta_path.insert(0, Hidden())\n"
    "import ctypes, signal; ctypes.CDLL(None).prctl(1, signal.SIGTERM)\n"
)
MAINS = {
    "dock": "from monodock.cli.ros_nodes import dock_main as main",
    "detector": "from monodock.cli.ros_nodes import detector_main as main",
    "sim": "from monodock.cli.ros_sim import sim_main as main",
}
folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
RobotConfig.default().save(folder / "robot.yaml")
files = ["--method", "board", "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml")]
args = {"dock": files, "detector": files, "sim": []}
processes = {
    name: subprocess.Popen(
        [sys.executable, "-c", HIDE + MAINS[name] + "\nsys.exit(main(sys.argv[1:]))", *args[name]],
        stderr=subprocess.PIPE,
        text=True,
    )
    for name in MAINS
}
rclpy.init()
node = rclpy.create_node("observer")
end = time.monotonic() + 60
services: list[str] = []
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
    services = [name for name, _ in node.get_service_names_and_types()]
    if "/monodock_dock/dock" in services and "/monodock_detector/toggle" in services:
        break
time.sleep(2.0)  # the sim publishes, the detector estimates
topics = sorted(name for name, _ in node.get_topic_names_and_types())
print(json.dumps({"kind": "graph", "services": sorted(services), "topics": topics}), flush=True)
node.destroy_node()
rclpy.shutdown()
stop_nodes(*processes.values())
for name, process in processes.items():
    _, err = process.communicate()
    print(json.dumps({"kind": "node", "name": name, "returncode": process.returncode, "stderr": err[-4000:]}))
