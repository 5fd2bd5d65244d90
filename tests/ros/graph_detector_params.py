"""Driver (tests/ros/test_detector_params.py, inside a private network namespace): the detector's start-up and
live parameters.

First, bad settings, each in its own start (all at once): what each printed and its exit code. Then a detector
with a camera file: camera_info that agrees with the file, then one whose fx is 3 % off, then one of another size;
parameter changes through its set_parameters service (allowed, out of range, read-only), and the effect of the
allowed ones on the poses of a rendered frame. Prints what was seen as JSON lines."""

from __future__ import annotations

import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import graph_detector_common as g
import numpy as np
import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from monodock.core.pose import DockPose
from monodock.sim import Simulator

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
    "no layout": ["--robot", files["robot"]],
    "flag": ["--method", "bogus"],
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


def send(publish: Any, count: int = 3) -> None:
    for _ in range(count):
        publish()
        g.spin_for(node, 0.1)


def call(service_type: Any, name: str, request: Any) -> Any:
    client = node.create_client(service_type, f"/monodock_detector/{name}")
    assert client.wait_for_service(timeout_sec=30.0), f"no {name} service"
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=30.0)
    return future.result()


def pose_of(age: float, timeout: float = 10.0) -> dict[str, Any] | None:
    """The pose of the rendered frame stamped ``age`` seconds ago, sent again until it comes (best effort)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        stamp = int((time.time() - age) * 1e9)
        images.publish(image(stamp))
        g.spin_for(node, 0.5)
        got = [p for p in listen.poses if p["stamp"] == stamp]
        if got:
            return got[0]
    return None


end = time.monotonic() + 60
while time.monotonic() < end and not (images.get_subscription_count() and infos.get_subscription_count()):
    g.spin_for(node, 0.1)
before = pose_of(0.0)
send(lambda: infos.publish(camera_info()))
g.spin_for(node, 0.5)
agreed = time.time()
fx_off = list(sim.camera.K)
fx_off[0] *= 1.03
send(lambda: infos.publish(camera_info(k=fx_off)))
send(lambda: infos.publish(camera_info(width=320, height=240)))
g.spin_for(node, 0.5)


def parameter(name: str, value: Any) -> Parameter:
    if isinstance(value, float):
        return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))
    return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value))


changes = {"max_stamp_age": 2.5, "frame_id": "odom", "method": "pnp", "diagnostics_period": 5.0}
results = {}
for name, value in [*changes.items(), ("max_stamp_age", -1.0)]:
    result = call(SetParameters, "set_parameters", SetParameters.Request(parameters=[parameter(name, value)]))
    results[f"{name}={value}"] = {"ok": result.results[0].successful, "reason": result.results[0].reason}
got = call(GetParameters, "get_parameters", GetParameters.Request(names=list(changes))).values
double = ParameterType.PARAMETER_DOUBLE
now = {name: v.double_value if v.type == double else v.string_value for name, v in zip(changes, got, strict=True)}
after = pose_of(2.0)  # 2 s old: skipped under the 1 s default, taken under 2.5 s
detector.terminate()
_, err = detector.communicate(timeout=20)
rclpy.shutdown()
print(json.dumps({"kind": "set", "results": results, "values": now}))
truth = [rendered.x, rendered.y, rendered.yaw]
print(json.dumps({"kind": "poses", "rendered": truth, "before": before, "after": after}))
print(json.dumps({"kind": "detector", "returncode": detector.returncode, "agreed": agreed, "stderr": err}))
