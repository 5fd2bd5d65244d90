"""Driver (tests/ros/test_detector_faults.py, inside a private network namespace): the detector (board PnP, camera
from camera_info) is fed each kind of bad message in turn on its topics, then the frames of monodock_sim standing
still.

Phases, each a burst of its kind: images before any camera_info; camera_info with K all zero, then with NaN; a
valid camera_info; images of an unknown encoding; images whose data is shorter than step x height; images with
stale stamps; a good image, then images older than it; a flood of good images as fast as they go; then the sim's
frames. The sim starts with the detector (its start-up takes seconds) on topics of its own, and this driver relays
its image and camera_info, unchanged, to the detector's topics once the bad messages are done.

Prints the phases' times, the stamps of the images that must give no pose, the detector's log (stderr), its
/diagnostics, the poses of this driver's rendered frame and the pose it was rendered at, and the poses of the sim's
frames paired with its ground truth."""

from __future__ import annotations

import json
import math
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import graph_detector_common as g
import numpy as np
import rclpy
from graph_processes import end_nodes
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from monodock.core.pose import DockPose
from monodock.sim import Simulator

start = sys.argv[1]
folder = Path(tempfile.mkdtemp())
model = Simulator(seed=4)  # monodock_sim's camera, layout and robot
model.layout.save(folder / "layout.yaml")
model.robot.save(folder / "robot.yaml")
rendered = DockPose(1.2, -0.05, math.radians(4.0))
frame = model.frame(rendered, 0.0, np.random.default_rng(4)).image

rclpy.init()
node = rclpy.create_node("faults")
listen = g.Listener(node)
images = node.create_publisher(Image, "image", qos_profile_sensor_data)
infos = node.create_publisher(CameraInfo, "camera_info", qos_profile_sensor_data)
# Stale beyond 5 s here (1 s by default); diagnostics every 0.5 s.
layout, robot = str(folder / "layout.yaml"), str(folder / "robot.yaml")
detector = g.detector("--layout", layout, "--robot", robot, "--max-stamp-age", "5", "--diagnostics-period", "0.5")
sim = g.sim(start, 120.0, "-r", "image:=sim/image", "-r", "camera_info:=sim/camera_info")
phases: list[dict[str, Any]] = []
refused: list[int] = []  # stamps of the images that must give no pose
good: list[int] = []  # stamps of the rendered frames sent as they are


def now_ns() -> int:
    return time.time_ns()


def image(stamp: int, *, encoding: str = "mono8", short: int = 0) -> Image:
    """The rendered frame (mono8), or a corner of it under another encoding (yuv422_yuy2: 2 bytes a pixel; small,
    as a best-effort message of more than Fast DDS's 0.5 MB shared-memory segment may well be lost)."""
    per_pixel = 2 if encoding == "yuv422_yuy2" else 1
    pixels = frame if per_pixel == 1 else frame[:48, :64]
    data = np.repeat(pixels, per_pixel, axis=1).tobytes()
    msg = Image(height=pixels.shape[0], width=pixels.shape[1], encoding=encoding, step=pixels.shape[1] * per_pixel)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.header.frame_id = "camera_optical_frame"
    msg.data = data[: len(data) - short]
    return msg


def bad(stamp: int, **kind: Any) -> None:
    refused.append(stamp)
    images.publish(image(stamp, **kind))


def send_good(stamp: int) -> None:
    good.append(stamp)
    images.publish(image(stamp))


def camera_info(k: list[float] | None = None) -> CameraInfo:
    camera = model.camera
    msg = CameraInfo(width=camera.width, height=camera.height, distortion_model=camera.distortion_model)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now_ns(), 1_000_000_000)
    msg.k = [float(v) for v in (camera.K if k is None else k)]
    msg.d = [float(v) for v in camera.D]
    return msg


def phase(name: str, send: Any, count: int, gap: float = 0.1, settle: float = 0.6) -> None:
    began = time.time()
    for i in range(count):
        send(i)
        g.spin_for(node, gap)
    g.spin_for(node, settle)
    phases.append({"name": name, "start": began, "end": time.time()})


def good_pose(timeout: float = 10.0) -> int:
    """The stamp of a fresh rendered frame whose pose came back (sent again until one does: best effort)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        stamp = now_ns()
        send_good(stamp)
        g.spin_for(node, 0.3)
        if any(p["stamp"] == stamp for p in listen.poses):
            return stamp
    raise SystemExit("no pose for a good frame")


# The detector is up when its subscriptions match and it reports.
end = time.monotonic() + 60
while time.monotonic() < end and not (images.get_subscription_count() and infos.get_subscription_count()):
    g.spin_for(node, 0.1)
while time.monotonic() < end and not listen.diagnostics:
    g.spin_for(node, 0.1)

phase("no calibration", lambda _: bad(now_ns()), 20, settle=0.8)
phase("K all zero", lambda _: infos.publish(camera_info([0.0] * 9)), 3)
nan_k = list(model.camera.K)
nan_k[2] = math.nan
phase("NaN in K", lambda _: infos.publish(camera_info(nan_k)), 3)
phase("calibrated", lambda _: infos.publish(camera_info()), 3)
phase("unknown encoding", lambda _: bad(now_ns(), encoding="yuv422_yuy2"), 3)
phase("short data", lambda _: bad(now_ns(), short=640), 3)
phase("stale", lambda _: bad(now_ns() - 60 * 10**9), 3)
last = good_pose()
phase("out of order", lambda i: bad(last - 200_000_000 + 10_000_000 * i), 3)
phase("flood", lambda _: send_good(now_ns()), 300, gap=0.0, settle=1.5)

# Then the sim's frames, relayed as they are, for 7 s or until 40 have given poses (a busy machine slows the sim
# down). No stamp limit for them: the sim may be seconds late then, but its frames are still to be estimated.
limit = Parameter(name="max_stamp_age", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.0))
assert g.call(node, SetParameters, "set_parameters", SetParameters.Request(parameters=[limit])).results[0].successful
relay_start = time.time()
node.create_subscription(Image, "sim/image", images.publish, qos_profile_sensor_data)
node.create_subscription(CameraInfo, "sim/camera_info", infos.publish, qos_profile_sensor_data)
g.spin_for(node, 7.0)
deadline = time.monotonic() + 20.0
while time.monotonic() < deadline and sum(p["stamp"] not in set(good) for p in listen.poses) < 40:
    g.spin_for(node, 0.5)
relay_end = time.time()
sim.send_signal(signal.SIGINT)  # stopped here: its exit code is not the detector's business
_, sim_err = sim.communicate(timeout=20)
g.spin_for(node, 1.0)
err = end_nodes({"detector": detector}, timeout=20)["detector"]
rclpy.shutdown()
driver_poses = [p for p in listen.poses if p["stamp"] in set(good)]
pairs, unpaired = listen.pairs(skip=set(good), tolerance=100_000_000)  # standing still
print(json.dumps({"kind": "phases", "phases": phases, "relay": [relay_start, relay_end], "refused": refused}))
print(json.dumps({"kind": "driver_poses", "rendered": [rendered.x, rendered.y, rendered.yaw], "poses": driver_poses}))
print(json.dumps({"kind": "sim_poses", "pairs": pairs, "unpaired": unpaired}))
print(json.dumps({"kind": "diagnostics", "statuses": listen.diagnostics}))
processes = {"sim": sim.returncode, "sim_stderr": sim_err[-4000:], "detector": detector.returncode, "stderr": err}
print(json.dumps({"kind": "processes", **processes}))
