"""Driver (tests/ros/test_detector_graph.py, inside a private network namespace): monodock_sim standing still in
front of the dock, the detector (board PnP, camera from camera_info) on its images; print each detected pose with
the ground truth of the same stamp, and each pose's latency from the image's stamp to its arrival here."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig

folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
RobotConfig.default().save(folder / "robot.yaml")
start = sys.argv[1] if len(sys.argv) > 1 else "[-1.6, 0.1, 0.05]"
SIM = "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv, duration=8.0)"
sim = subprocess.Popen([sys.executable, "-c", SIM, "--ros-args", "-p", f"start:={start}"])
DET = "from monodock.cli.ros_nodes import detector_main; import sys; sys.exit(detector_main(sys.argv[1:]))"
detector = subprocess.Popen(
    [
        sys.executable,
        "-c",
        DET,
        "--method",
        "board",
        "--layout",
        str(folder / "layout.yaml"),
        "--robot",
        str(folder / "robot.yaml"),
        "--image-topic",
        "/image",
        "--camera-info-topic",
        "/camera_info",
    ],
)

rclpy.init()
node = rclpy.create_node("listener")
truth: dict[int, tuple[float, float, float]] = {}
poses: list[tuple[int, tuple[float, float, float], float]] = []


def key(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def pose(msg: Any) -> tuple[float, float, float]:
    import math

    q = msg.pose.orientation
    yaw = 2.0 * math.atan2(q.z, q.w)
    return (msg.pose.position.x, msg.pose.position.y, yaw)


def on_truth(msg: Any) -> None:
    truth[key(msg)] = pose(msg)


def on_pose(msg: Any) -> None:
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    poses.append((key(msg), pose(msg), time.time() - stamp))


node.create_subscription(PoseStamped, "ground_truth", on_truth, 100)
node.create_subscription(PoseStamped, "detected_dock_pose", on_pose, 100)
end = time.monotonic() + 60
while sim.poll() is None and time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
detector.terminate()
detector.wait(timeout=20)
rclpy.shutdown()
# The truth is published every 20 ms, frames are exposed between: pair each pose with the nearest truth stamp.
stamps = sorted(truth)
pairs = []
for k, p, latency in poses:
    nearest = min(stamps, key=lambda s: abs(s - k)) if stamps else None
    if nearest is not None and abs(nearest - k) < 100_000_000:  # standing still: the truth of the last 0.1 s
        pairs.append({"pose": p, "truth": truth[nearest], "latency": latency})
print(json.dumps({"kind": "poses", "count": len(poses), "pairs": pairs}))
print(json.dumps({"kind": "sim", "returncode": sim.returncode}))
