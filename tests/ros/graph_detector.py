"""Driver (tests/ros/test_detector_graph.py, inside a private network namespace): monodock_sim standing still in
front of the dock, the detector (board PnP, camera from camera_info) on its images, configured by the shipped
params file config/monodock_detector.yaml with a second file for the paths and a -p on top, and flags below
both. Prints the detected poses paired with the ground truth nearest their stamps, each with its latency from the
image's stamp to its arrival here, the detector's /diagnostics, and its parameters as its parameter services give
them."""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import graph_detector_common as g
import rclpy
from graph_processes import end_nodes
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig

start, shipped = sys.argv[1], sys.argv[2]
folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
RobotConfig.default().save(folder / "robot.yaml")
overlay = folder / "paths.yaml"
paths = f"    layout: {folder / 'layout.yaml'}\n    robot: {folder / 'robot.yaml'}\n"
overlay.write_text(f"monodock_detector:\n  ros__parameters:\n{paths}")

# Subscribed before the nodes start, so that no early pose or ground truth is missed while discovery runs.
rclpy.init()
node = rclpy.create_node("listener")
listen = g.Listener(node, images=True)
# The flags say pnp, another frame and another period: the params files must win over them, and the -p over the
# files (no stamp limit: a sim slowed down by a busy machine sends late frames, and they are to be measured).
flags = ["--method", "pnp", "--frame-id", "flag_frame", "--diagnostics-period", "2.0"]
ros = ["--ros-args", "--params-file", shipped, "--params-file", str(overlay)]
ros += ["-p", "diagnostics_period:=0.5", "-p", "max_stamp_age:=0.0"]
detector = g.detector(*flags, *ros)


def call(service_type: Any, name: str, request: Any) -> Any:
    return g.call(node, service_type, name, request)


names = call(ListParameters, "list_parameters", ListParameters.Request()).result.names
got = call(GetParameters, "get_parameters", GetParameters.Request(names=names)).values
described = call(DescribeParameters, "describe_parameters", DescribeParameters.Request(names=names)).descriptors
fields = {1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value"}
parameters = {
    name: {
        "value": getattr(value, fields[value.type]) if value.type in fields else None,
        "type": fields.get(d.type, "").removesuffix("_value"),
        "read_only": d.read_only,
        "description": d.description,
        "bounds": [[r.from_value, r.to_value] for r in d.floating_point_range],
    }
    for name, value, d in zip(names, got, described, strict=True)
}
print(json.dumps({"kind": "parameters", "parameters": parameters}), flush=True)
sim = g.sim(start, 9.0)  # once the detector answers: all its frames are for the detector

end = time.monotonic() + 90
while sim.poll() is None and time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
sim_end = time.time()
_, sim_err = sim.communicate(timeout=20)
g.spin_for(node, 2.0)  # the poses of the last frames, then /diagnostics without images
err = end_nodes({"detector": detector}, timeout=20)["detector"]
rclpy.shutdown()
pairs, unpaired = listen.pairs(tolerance=100_000_000)  # standing still: the truth of the last 0.1 s
stamps = sorted(listen.truth)
span = (stamps[-1] - stamps[0]) * 1e-9 if stamps else 0.0
print(json.dumps({"kind": "poses", "count": len(listen.poses), "pairs": pairs, "unpaired": unpaired, "span": span}))
print(json.dumps({"kind": "diagnostics", "sim_end": sim_end, "statuses": listen.diagnostics}))
processes = {"sim": sim.returncode, "sim_stderr": sim_err[-4000:], "detector": detector.returncode, "stderr": err}
print(json.dumps({"kind": "processes", **processes}))
