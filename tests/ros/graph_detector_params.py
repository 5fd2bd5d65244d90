"""Driver (tests/ros/test_detector_graph.py, inside a private network namespace): the detector's start-up, its live
parameters and its covariance topic, on a frame rendered here.

First, bad settings, each in its own start (all at once): what each printed and its exit code. Then a detector
(board PnP) with a camera file: camera_info that agrees with the file, then one whose fx is 3 % off, then one of
another size; parameter changes through its set_parameters service (allowed, an integer for a real, out of range,
read-only), and their effect on the pose of the rendered frame. With a model bundle (argv[1]), a second detector,
fused, in the namespace /fused and with compressed:=true: its PoseStamped and PoseWithCovarianceStamped of the same
frame as a PNG on /fused/image/compressed. Prints what was seen as JSON lines."""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import graph_detector_common as g
import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from graph_processes import end_nodes
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from monodock.core.pose import DockPose
from monodock.sim import Simulator

bundle = sys.argv[1] if len(sys.argv) > 1 else ""
folder = Path(tempfile.mkdtemp())
sim = Simulator(seed=2)  # monodock_sim's camera, layout and robot
files = {k: str(folder / f"{k}.yaml") for k in ("camera", "layout", "robot")}
sim.camera.save(files["camera"])
sim.layout.save(files["layout"])
sim.robot.save(files["robot"])
out_of_range = folder / "out_of_range.yaml"
out_of_range.write_text("monodock_detector:\n  ros__parameters:\n    diagnostics_period: 100.0\n")

BAD = {
    "method": ["--ros-args", "-p", "method:=bogus"],
    "range": ["--ros-args", "-p", "max_stamp_age:=-1.0"],
    "type": ["--ros-args", "-p", "compressed:=maybe"],
    "range in a params file": ["--ros-args", "--params-file", str(out_of_range)],
    "missing params file": ["--ros-args", "--params-file", str(folder / "missing.yaml")],
    "missing robot file": ["--layout", files["layout"], "--robot", str(folder / "missing_robot.yaml")],
    "ROS argument": ["--ros-args", "--bogus"],
}
started = {name: g.detector(*args) for name, args in BAD.items()}
for name, process in started.items():
    _, err = process.communicate(timeout=60)
    print(json.dumps({"kind": "bad", "name": name, "returncode": process.returncode, "stderr": err}), flush=True)

rclpy.init()
node = rclpy.create_node("params")
listen = g.Listener(node)
images = node.create_publisher(Image, "image", qos_profile_sensor_data)
infos = node.create_publisher(CameraInfo, "camera_info", qos_profile_sensor_data)
detector = g.detector("--camera", files["camera"], "--layout", files["layout"], "--robot", files["robot"])
fused_args = ["--model", bundle, "--method", "fused", "--ros-args", "-r", "__ns:=/fused", "-p", "compressed:=true"]
fused = g.detector(*fused_args) if bundle else None
fused_images = node.create_publisher(CompressedImage, "/fused/image/compressed", qos_profile_sensor_data)
with_covariance: dict[str, list[Any]] = {"board": [], "fused": []}
fused_poses: list[Any] = []
node.create_subscription(
    PoseWithCovarianceStamped, "detected_dock_pose_with_covariance", with_covariance["board"].append, g.DEEP
)
node.create_subscription(
    PoseWithCovarianceStamped, "/fused/detected_dock_pose_with_covariance", with_covariance["fused"].append, g.DEEP
)
node.create_subscription(PoseStamped, "/fused/detected_dock_pose", fused_poses.append, g.DEEP)
rendered = DockPose(1.0, 0.05, math.radians(-3.0))
frame = sim.frame(rendered, 0.0, np.random.default_rng(2)).image


def camera_info(**changes: Any) -> CameraInfo:
    camera = sim.camera
    msg = CameraInfo(width=camera.width, height=camera.height, distortion_model=camera.distortion_model)
    msg.k = [float(v) for v in camera.K]
    msg.d = [float(v) for v in camera.D]
    for k, v in changes.items():
        setattr(msg, k, v)
    return msg


def image(stamp: int) -> Image:
    msg = Image(height=frame.shape[0], width=frame.shape[1], encoding="mono8", step=frame.shape[1])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.data = frame.tobytes()
    return msg


def png(stamp: int) -> CompressedImage:
    msg = CompressedImage(format="mono8; png compressed mono8")
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.data = cv2.imencode(".png", frame)[1].tobytes()
    return msg


def send(publish: Any, count: int = 3) -> None:
    for _ in range(count):
        publish()
        g.spin_for(node, 0.1)


def answer(age: float, publisher: Any, answers: list[Any], timeout: float = 10.0, encode: Any = image) -> Any:
    """The answer (from ``answers``) to the rendered frame stamped ``age`` s ago, sent again until it comes."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        stamp = int((time.time() - age) * 1e9)
        publisher.publish(encode(stamp))
        g.spin_for(node, 0.5)
        got = [a for a in answers if (a["stamp"] if isinstance(a, dict) else g.key(a)) == stamp]
        if got:
            return got[0]
    return None


end = time.monotonic() + 60
while time.monotonic() < end and not (images.get_subscription_count() and infos.get_subscription_count()):
    g.spin_for(node, 0.1)
before = answer(0.0, images, listen.poses)
send(lambda: infos.publish(camera_info()))
g.spin_for(node, 0.5)
agreed = time.time()
fx_off = list(sim.camera.K)
fx_off[0] *= 1.03
send(lambda: infos.publish(camera_info(k=fx_off)))
# A camera of half the size (K scaled with it: one with the full-size K would be implausible, and refused as such).
half = [v * 0.5 for v in sim.camera.K[:6]] + list(sim.camera.K[6:])
send(lambda: infos.publish(camera_info(width=320, height=240, k=half)))
g.spin_for(node, 0.5)


def parameter(name: str, value: Any) -> Parameter:
    if isinstance(value, int):
        return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value))
    if isinstance(value, float):
        return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))
    return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value))


changes = {"max_stamp_age": 2.5, "frame_id": "odom", "method": "pnp", "diagnostics_period": 5.0}
results = {}
for name, value in [("max_stamp_age", 2), *changes.items(), ("max_stamp_age", -1.0)]:
    request = SetParameters.Request(parameters=[parameter(name, value)])
    result = g.call(node, SetParameters, "set_parameters", request).results[0]
    results[f"{name}={value}"] = {"ok": result.successful, "reason": result.reason}
got = g.call(node, GetParameters, "get_parameters", GetParameters.Request(names=list(changes))).values
double = ParameterType.PARAMETER_DOUBLE
now = {name: v.double_value if v.type == double else v.string_value for name, v in zip(changes, got, strict=True)}
after = answer(2.0, images, listen.poses)  # 2 s old: skipped under the 1 s default, taken under 2.5 s
covariance = answer(0.0, fused_images, with_covariance["fused"], 60.0, png) if fused else None  # after its warm-up
g.spin_for(node, 0.5)
plain = [m for m in fused_poses if covariance is not None and g.key(m) == g.key(covariance)]
logs = end_nodes({"detector": detector, **({"fused": fused} if fused else {})}, timeout=20)
err, fused_err = logs["detector"], logs.get("fused", "")
rclpy.shutdown()
truth = [rendered.x, rendered.y, rendered.yaw]
print(json.dumps({"kind": "set", "results": results, "values": now}))
print(json.dumps({"kind": "poses", "rendered": truth, "before": before, "after": after}))
print(json.dumps({"kind": "detector", "returncode": detector.returncode, "agreed": agreed, "stderr": err}))
fused_out = {
    "returncode": fused.returncode if fused else None,
    "stderr": fused_err,
    "board": len(with_covariance["board"]),
}
if covariance is not None:
    fused_out |= {
        "stamps": [g.key(covariance), *[g.key(m) for m in plain]],
        "frames": [covariance.header.frame_id, *[m.header.frame_id for m in plain]],
        "pose": g.planar(covariance.pose),
        "plain": [g.planar(m) for m in plain],
        "covariance": list(covariance.pose.covariance),
    }
print(json.dumps({"kind": "fused", **fused_out}))
