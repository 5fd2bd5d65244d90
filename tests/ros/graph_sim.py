"""Driver (tests/ros/test_sim_node.py, inside a private network namespace): start monodock_sim, listen to what it
publishes, drive it forward by cmd_vel for 2 s, then fall silent; print what was seen as JSON lines."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
import time
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import BatteryState, CameraInfo, Image, Range
from tf2_msgs.msg import TFMessage

NODE = "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv, duration=9.0)"
sim = subprocess.Popen(
    [sys.executable, "-c", NODE, "--ros-args", "-p", "start:=[-1.5, 0.05, 0.0]", "-p", "seed:=3"],
    stderr=subprocess.PIPE,
    text=True,
)

rclpy.init()
node = rclpy.create_node("driver")
seen: dict[str, list[float]] = {k: [] for k in ("image", "camera_info", "odom", "ground_truth", "battery", "range")}
truth: list[tuple[float, float]] = []
sizes: list[tuple[int, int, str]] = []
sent: list[float] = []
odometry: dict[float, list[float]] = {}  # stamp -> x, y, qz, qw of each odometry message
tf: list[tuple[str, str, float, list[float]]] = []  # /tf: parent, child, stamp, x, y, z, qx, qy, qz, qw
tf_static: list[tuple[str, str, list[float]]] = []


def transform(t: Any) -> list[float]:
    r, q = t.transform.translation, t.transform.rotation
    return [r.x, r.y, r.z, q.x, q.y, q.z, q.w]


def on_odometry(msg: Any) -> None:
    seen["odom"].append(stamp(msg))
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    odometry[stamp(msg)] = [p.x, p.y, q.z, q.w]


def on_tf(msg: Any) -> None:
    tf.extend((t.header.frame_id, t.child_frame_id, stamp(t), transform(t)) for t in msg.transforms)


def on_tf_static(msg: Any) -> None:
    tf_static.extend((t.header.frame_id, t.child_frame_id, transform(t)) for t in msg.transforms)


def stamp(msg: Any) -> float:
    return float(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)


def on_image(msg: Any) -> None:
    seen["image"].append(time.time())
    sizes.append((msg.width, msg.height, msg.encoding))


def on_truth(msg: Any) -> None:
    seen["ground_truth"].append(stamp(msg))
    truth.append((stamp(msg), msg.pose.position.x))


sensor = qos_profile_sensor_data
node.create_subscription(Image, "image", on_image, sensor)
node.create_subscription(CameraInfo, "camera_info", lambda m: seen["camera_info"].append(stamp(m)), sensor)
node.create_subscription(Odometry, "odom", on_odometry, 10)
node.create_subscription(TFMessage, "/tf", on_tf, 100)
node.create_subscription(
    TFMessage, "/tf_static", on_tf_static, QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
)
node.create_subscription(PoseStamped, "ground_truth", on_truth, 10)
node.create_subscription(BatteryState, "battery_state", lambda m: seen["battery"].append(stamp(m)), 10)
node.create_subscription(Range, "rear_range", lambda m: seen["range"].append(m.range), sensor)
cmd = node.create_publisher(TwistStamped, "cmd_vel", 10)  # the sim's default, as the docking node sends it
start = time.monotonic()
driving_from: float | None = None
while time.monotonic() - start < 30 and sim.poll() is None:
    rclpy.spin_once(node, timeout_sec=0.02)
    if seen["image"] and driving_from is None:
        driving_from = time.monotonic()
    if driving_from is not None and time.monotonic() - driving_from < 2.0:
        twist = TwistStamped()
        twist.twist.linear.x = 0.1
        cmd.publish(twist)
        sent.append(time.time())
rclpy.shutdown()
_, err = sim.communicate(timeout=20)
images = seen["image"]
rate = (len(images) - 1) / (images[-1] - images[0]) if len(images) > 1 else 0.0
moving = [t for (t, x0), (_, x1) in itertools.pairwise(truth) if abs(x1 - x0) > 1e-5]
xs = [x for _, x in truth[:: max(1, len(truth) // 40)]]
print(json.dumps({"kind": "counts", **{k: len(v) for k, v in seen.items()}}))
print(json.dumps({"kind": "image", "sizes": sorted(set(sizes))}))
print(json.dumps({"kind": "image_rate", "hz": rate}))
print(json.dumps({"kind": "truth", "x": xs, "last": truth[-1][1] if truth else None}))
print(json.dumps({"kind": "timeline", "sent": sent[:1] + sent[-1:], "moving": moving[:1] + moving[-1:]}))
# Each /tf odom -> base_link against the odometry of the same stamp: the largest difference in x, y, qz, qw.
paired = [(values, odometry[t]) for _, _, t, values in tf if t in odometry]
gap = max((abs(a - b) for v, o in paired for a, b in zip([v[0], v[1], v[5], v[6]], o, strict=True)), default=None)
frames = sorted({(parent, child) for parent, child, _, _ in tf})
print(json.dumps({"kind": "tf", "count": len(tf), "paired": len(paired), "gap": gap, "frames": frames}))
print(json.dumps({"kind": "tf_static", "transforms": tf_static}))
print(json.dumps({"kind": "sim", "returncode": sim.returncode, "stderr": err[-2000:]}))
