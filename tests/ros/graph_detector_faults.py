"""Driver (tests/ros/test_detector_faults.py, inside a private network namespace): the detector (board PnP, camera
from camera_info) is fed each kind of bad message in turn, then the frames of monodock_sim standing still.

Phases, each a burst of its kind: images before any camera_info; camera_info with K all zero, then with NaN;
a valid camera_info; images of an unknown encoding; images whose data is shorter than step x height; images
with stale stamps; an image, then images older than it; a flood of good images as fast as they go; then the sim.
Prints the phases' times, the detector's log (stderr), its /diagnostics, the poses of the driver's own frames
with the pose they were rendered at, and the sim's poses paired with its ground truth."""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import graph_detector_common as g
import numpy as np
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from monodock.core.pose import DockPose
from monodock.sim import Simulator

start = sys.argv[1]
folder = Path(tempfile.mkdtemp())
sim_model = Simulator(seed=4)  # the defaults of monodock_sim: its camera, layout and robot
sim_model.layout.save(folder / "layout.yaml")
sim_model.robot.save(folder / "robot.yaml")
rendered = DockPose(1.2, -0.05, math.radians(4.0))
frame = sim_model.frame(rendered, 0.0, np.random.default_rng(4)).image

rclpy.init()
node = rclpy.create_node("faults")
listen = g.Listener(node)
images = node.create_publisher(Image, "image", qos_profile_sensor_data)
infos = node.create_publisher(CameraInfo, "camera_info", qos_profile_sensor_data)
# max_stamp_age 1 s (the default); diagnostics every 0.5 s so that each phase has its own.
detector = g.detector(
    "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml"), "--diagnostics-period", "0.5"
)
phases: list[dict[str, Any]] = []


def stamped(msg: Any, seconds: float) -> Any:
    msg.header.stamp.sec = int(math.floor(seconds))
    msg.header.stamp.nanosec = int((seconds - math.floor(seconds)) * 1e9)
    return msg


def image(seconds: float, *, encoding: str = "mono8", short: int = 0) -> Image:
    """The rendered frame (mono8), or bytes of its size under another encoding (yuv422_yuy2: 2 a pixel)."""
    per_pixel = 2 if encoding == "yuv422_yuy2" else 1
    data = np.repeat(frame, per_pixel, axis=1).tobytes()
    msg = stamped(Image(), seconds)
    msg.header.frame_id = "camera_optical_frame"
    msg.height, msg.width = frame.shape
    msg.encoding, msg.is_bigendian, msg.step = encoding, 0, frame.shape[1] * per_pixel
    msg.data = data[: len(data) - short]
    return msg


def camera_info(k: list[float] | None = None) -> CameraInfo:
    camera = sim_model.camera
    msg = stamped(CameraInfo(), time.time())
    msg.width, msg.height, msg.distortion_model = camera.width, camera.height, camera.distortion_model
    msg.k = [float(v) for v in (camera.K if k is None else k)]
    msg.d = [float(v) for v in camera.D]
    return msg


def phase(name: str, burst: Any, count: int, gap: float = 0.1, settle: float = 0.6) -> None:
    began = time.time()
    for i in range(count):
        burst(i)
        g.spin_for(node, gap)
    g.spin_for(node, settle)
    phases.append({"name": name, "start": began, "end": time.time()})


# The detector is up when its subscriptions match and it reports.
end = time.monotonic() + 60
while time.monotonic() < end and not (images.get_subscription_count() and infos.get_subscription_count()):
    g.spin_for(node, 0.1)
while time.monotonic() < end and not listen.diagnostics:
    g.spin_for(node, 0.1)

phase("no calibration", lambda _: images.publish(image(time.time())), 20, settle=0.8)
phase("K all zero", lambda _: infos.publish(camera_info([0.0] * 9)), 3)
nan_k = list(sim_model.camera.K)
nan_k[2] = math.nan
phase("NaN in K", lambda _: infos.publish(camera_info(nan_k)), 3)
phase("calibrated", lambda _: infos.publish(camera_info()), 3)
phase("unknown encoding", lambda _: images.publish(image(time.time(), encoding="yuv422_yuy2")), 3)
phase("short data", lambda _: images.publish(image(time.time(), short=640)), 3)
phase("stale", lambda _: images.publish(image(time.time() - 5.0)), 3)
last = time.time()
images.publish(image(last))  # a good one: it gives a pose
phase("out of order", lambda i: images.publish(image(last - 0.2 + 0.01 * i)), 3)
phase("flood", lambda _: images.publish(image(time.time())), 300, gap=0.0, settle=1.5)
driver_end = time.time()

sim = g.sim(start, 7.0)
deadline = time.monotonic() + 90
while sim.poll() is None and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.05)
g.spin_for(node, 1.0)
detector.terminate()
_, err = detector.communicate(timeout=20)
rclpy.shutdown()
driver_poses = [p for p in listen.poses if p["stamp"] * 1e-9 <= driver_end]
pairs, unpaired = listen.pairs(after=int(driver_end * 1e9))
print(json.dumps({"kind": "phases", "phases": phases}))
print(json.dumps({"kind": "driver_poses", "rendered": [rendered.x, rendered.y, rendered.yaw], "poses": driver_poses}))
print(json.dumps({"kind": "sim_poses", "pairs": pairs, "unpaired": unpaired}))
print(json.dumps({"kind": "diagnostics", "statuses": listen.diagnostics}))
print(json.dumps({"kind": "processes", "sim": sim.returncode, "detector": detector.returncode, "stderr": err}))
