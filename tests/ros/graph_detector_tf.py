"""Driver (tests/ros/test_detector_tf_graph.py, inside a private network namespace): the detector's TF and its
on-demand detection, beside monodock_sim standing still (it latches the true camera mount on /tf_static).

Three detectors (board PnP, camera from camera_info), each in its own namespace on the sim's topics:

- ``/tf_mount``: a robot file whose camera mount is 5 cm and 2° off the true one, the mount from /tf_static (the
  default), the dock frame broadcast on /tf, its debug image subscribed;
- ``/file_mount``: the same wrong robot file with ``camera_mount_source:=robot``;
- ``/on_demand``: the true robot file, started with ``active:=false``; then ``~/toggle`` (as Nav2's
  ``detector_service_name`` calls it) while nothing subscribes to its poses, then its poses subscribed, then
  ``~/toggle`` again. Each phase's poses and /diagnostics are kept.
- ``/managed``: the true robot file, a lifecycle node (``--lifecycle``), its poses subscribed throughout: configured
  and activated (``~/change_state``) with the first toggle, deactivated with the second.

Prints JSON lines: each detector's poses with the truth, the /tf dock transforms, the debug image, the phases.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import graph_detector_common as g
import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from graph_processes import end_nodes
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from monodock.core.layout import DockLayout
from monodock.core.robot import Mount, RobotConfig

start, picture = sys.argv[1], sys.argv[2]
folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
true_robot = RobotConfig.default()  # the sim's: what it renders with and latches on /tf_static
true_robot.save(folder / "true_robot.yaml")
m = true_robot.camera_mount
wrong = Mount(m.x, m.y + 0.05, m.z, m.roll, m.pitch, m.yaw + math.radians(2.0))
RobotConfig(camera_mount=wrong).save(folder / "wrong_robot.yaml")

rclpy.init()
node = rclpy.create_node("listener")
truth: dict[int, tuple[float, float, float]] = {}
poses: dict[str, list[tuple[int, tuple[float, float, float]]]] = {
    "tf_mount": [],
    "file_mount": [],
    "on_demand": [],
    "managed": [],
}
dock_tf: list[tuple[str, str, int, float, float, float]] = []
debug: list[dict[str, Any]] = []
diagnostics: list[dict[str, Any]] = []
node.create_subscription(PoseStamped, "/ground_truth", lambda msg: truth.update({g.key(msg): g.planar(msg)}), g.DEEP)
for name in ("tf_mount", "file_mount", "managed"):
    node.create_subscription(
        PoseStamped,
        f"/{name}/detected_dock_pose",
        lambda msg, name=name: poses[name].append((g.key(msg), g.planar(msg))),
        g.DEEP,
    )


def on_tf(msg: Any) -> None:
    for t in msg.transforms:
        if (t.header.frame_id, t.child_frame_id) == ("odom", "base_link"):
            continue  # the sim's odometry
        r, q = t.transform.translation, t.transform.rotation
        yaw = 2.0 * math.atan2(q.z, q.w)
        dock_tf.append((t.header.frame_id, t.child_frame_id, g.key(t), r.x, r.y, yaw))


def on_debug(msg: Any) -> None:
    if not debug:  # the first one, kept as a PNG for a person to look at
        image = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width, 3)
        cv2.imwrite(picture, image)
    green = 0
    image = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width, 3)
    green = int(np.count_nonzero(np.all(np.abs(image.astype(int) - (60, 200, 60)) < 30, axis=2)))
    debug.append({"stamp": g.key(msg), "frame": msg.header.frame_id, "encoding": msg.encoding, "green": green})


def on_diagnostics(msg: Any) -> None:
    for s in msg.status:
        values = {v.key: v.value for v in s.values}
        diagnostics.append({"t": time.time(), "name": s.name, "level": s.level[0], "message": s.message, **values})


node.create_subscription(TFMessage, "/tf", on_tf, 100)
node.create_subscription(Image, "/tf_mount/monodock_detector/debug_image", on_debug, qos_profile_sensor_data)
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402

node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 100)

files = ["--layout", str(folder / "layout.yaml")]
# use_sim_time: the images' stamps are the sim's clock, which a busy machine slows below the wall clock's pace.
topics = ["-r", "image:=/image", "-r", "camera_info:=/camera_info", "-p", "diagnostics_period:=0.5"]
topics += ["-p", "use_sim_time:=true"]
detectors = {
    "tf_mount": g.detector(
        *files, "--robot", str(folder / "wrong_robot.yaml"), "--ros-args", "-r", "__ns:=/tf_mount", *topics,
        "-p", "dock_frame:=dock",
    ),
    "file_mount": g.detector(
        *files, "--robot", str(folder / "wrong_robot.yaml"), "--ros-args", "-r", "__ns:=/file_mount", *topics,
        "-p", "camera_mount_source:=robot",
    ),
    "on_demand": g.detector(
        *files, "--robot", str(folder / "true_robot.yaml"), "--ros-args", "-r", "__ns:=/on_demand", *topics,
        "-p", "active:=false",
    ),
    "managed": g.detector(
        *files, "--robot", str(folder / "true_robot.yaml"), "--lifecycle", "--ros-args", "-r", "__ns:=/managed",
        *topics,
    ),
}  # fmt: skip
change_state = node.create_client(ChangeState, "/managed/monodock_detector/change_state")
get_state = node.create_client(GetState, "/managed/monodock_detector/get_state")
assert change_state.wait_for_service(timeout_sec=60.0), "no ~/change_state service"
toggle = node.create_client(Trigger, "/on_demand/monodock_detector/toggle")
assert toggle.wait_for_service(timeout_sec=60.0), "no ~/toggle service"
sim: subprocess.Popen[str] = g.sim(start, 40.0)
phases: list[dict[str, Any]] = []


def phase(name: str, seconds: float) -> None:
    """Spin for ``seconds``; record the on-demand detector's poses and its /diagnostics' last word."""
    begin = time.time()
    g.spin_for(node, seconds)
    said = [d for d in diagnostics if d["name"].startswith("on_demand/") and d["t"] > begin + 1.0]
    phases.append(
        {
            "name": name,
            "poses": len(poses["on_demand"]),
            "managed_poses": len(poses["managed"]),
            "managed_state": lifecycle_state(),
            # Periods with images only: under load a half-second period can pass with none (a WARN of its own).
            "messages": sorted({d["message"] for d in said if d["images_in_hz"] != "0.00"}),
            "levels": sorted({d["level"] for d in said if d["images_in_hz"] != "0.00"}),
            "reasons": sorted({d["no_estimate_reason"] for d in said if d["images_in_hz"] != "0.00"}),
        }
    )


def lifecycle_state() -> str:
    future = get_state.call_async(GetState.Request())
    rclpy.spin_until_future_complete(node, future, timeout_sec=30.0)
    return str(future.result().current_state.label)


def transition(transition_id: int) -> bool:
    future = change_state.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
    rclpy.spin_until_future_complete(node, future, timeout_sec=30.0)
    return bool(future.result().success)


def call_toggle() -> str:
    future = toggle.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, future, timeout_sec=30.0)
    result = future.result()
    return f"{result.success} {result.message}"


# Wait until the sim's images reach the always-on detectors.
end = time.monotonic() + 60
while not poses["tf_mount"] and time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
phase("stopped", 4.0)
said = [call_toggle()]
managed = [transition(Transition.TRANSITION_CONFIGURE), transition(Transition.TRANSITION_ACTIVATE)]
phase("started, nothing subscribed", 4.0)
node.create_subscription(
    PoseStamped,
    "/on_demand/detected_dock_pose",
    lambda msg: poses["on_demand"].append((g.key(msg), g.planar(msg))),
    g.DEEP,
)
phase("started, subscribed", 4.0)
said.append(call_toggle())
managed.append(transition(Transition.TRANSITION_DEACTIVATE))
g.spin_for(node, 1.0)  # a pose of an image estimated before the stop may still be on its way
stopped_with = len(poses["on_demand"])
managed_stopped_with = len(poses["managed"])
phase("stopped again", 4.0)
phases[-1]["since_stop"] = len(poses["on_demand"]) - stopped_with
phases[-1]["managed_since_stop"] = len(poses["managed"]) - managed_stopped_with
logs = end_nodes({**detectors, "sim": sim}, timeout=30)
rclpy.shutdown()

still = sorted(truth.items())
true_pose = np.median(np.array([p for _, p in still]), axis=0).tolist() if still else None
for name, got in poses.items():
    print(
        json.dumps({"kind": "poses", "name": name, "count": len(got), "poses": [p for _, p in got], "truth": true_pose})
    )
stamps = {k for k, _ in poses["tf_mount"]}
print(json.dumps({"kind": "dock_tf", "count": len(dock_tf), "transforms": dock_tf[:200], "pose_stamps": len(stamps)}))
matched = [t for t in dock_tf if t[2] in stamps]
by_stamp = dict(poses["tf_mount"])
gap = max((max(abs(t[3] - by_stamp[t[2]][0]), abs(t[4] - by_stamp[t[2]][1])) for t in matched), default=None)
print(json.dumps({"kind": "dock_tf_match", "matched": len(matched), "gap": gap}))
print(
    json.dumps(
        {
            "kind": "debug",
            "count": len(debug),
            "first": debug[:1],
            "green_min": min((d["green"] for d in debug), default=0),
        }
    )
)
print(json.dumps({"kind": "phases", "phases": phases, "toggles": said, "transitions": managed}))
for name, err in logs.items():
    code = (detectors.get(name) or sim).returncode
    print(json.dumps({"kind": "process", "name": name, "returncode": code, "stderr": err[-6000:]}))
