"""What the detector's graph drivers share (they run inside the private network namespace, with rclpy): how to
start the node and the simulated robot, read poses and /diagnostics, and pair poses with the ground truth."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from typing import Any

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

# Each node's process gets SIGTERM when its parent ends, however it ends (PR_SET_PDEATHSIG): none outlives its run.
_ORPHANS_END = "import ctypes, signal; ctypes.CDLL(None).prctl(1, signal.SIGTERM); "
DETECTOR = (
    _ORPHANS_END + "from monodock.cli.ros_nodes import detector_main; import sys; sys.exit(detector_main(sys.argv[1:]))"
)
SIM = _ORPHANS_END + "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv, duration={duration})"

# Every message kept (reliable, deep): a pose is never unpaired because its ground truth was lost under load.
DEEP = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)


def detector(*args: str) -> subprocess.Popen[str]:
    """``monodock-ros ARGS`` with its stderr (its log) kept for the report."""
    command = [sys.executable, "-c", DETECTOR, *args]
    return subprocess.Popen(command, stderr=subprocess.PIPE, text=True)


def sim(start: str, duration: float, *ros: str) -> subprocess.Popen[str]:
    """monodock_sim standing at ``start`` ([x, y, yaw]) for ``duration`` simulated seconds, its stderr kept; ``ros``:
    more ROS arguments (remappings)."""
    command = [sys.executable, "-c", SIM.format(duration=duration), "--ros-args", "-p", f"start:={start}", *ros]
    return subprocess.Popen(command, stderr=subprocess.PIPE, text=True)


def key(msg: Any) -> int:
    """A message's header stamp in nanoseconds."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def planar(msg: Any) -> tuple[float, float, float]:
    """(x, y, yaw) of a PoseStamped."""
    q = msg.pose.orientation
    return (msg.pose.position.x, msg.pose.position.y, 2.0 * math.atan2(q.z, q.w))


class Listener:
    """Poses (with their arrival), ground truth and the detector's /diagnostics, subscribed on ``node``; with
    ``images``, the arrival of each camera image too (by stamp); with ``namespace``, the detector's in it."""

    def __init__(self, node: Any, *, images: bool = False, namespace: str = "") -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Image

        self.detector = f"{namespace.strip('/')}/monodock_detector".lstrip("/")  # its /diagnostics status's name
        self.truth: dict[int, tuple[float, float, float]] = {}
        self.poses: list[dict[str, Any]] = []
        self.diagnostics: list[dict[str, Any]] = []
        self.image_arrival: dict[int, float] = {}
        node.create_subscription(PoseStamped, "ground_truth", self._on_truth, DEEP)
        node.create_subscription(PoseStamped, f"{namespace}/detected_dock_pose".lstrip("/"), self._on_pose, DEEP)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 100)
        if images:
            node.create_subscription(Image, "image", self._on_image, qos_profile_sensor_data)

    def _on_image(self, msg: Any) -> None:
        self.image_arrival[key(msg)] = time.time()

    def _on_truth(self, msg: Any) -> None:
        self.truth[key(msg)] = planar(msg)

    def _on_pose(self, msg: Any) -> None:
        arrival = time.time()
        self.poses.append(
            {"stamp": key(msg), "pose": planar(msg), "latency": arrival - key(msg) * 1e-9, "frame": msg.header.frame_id}
        )

    def _on_diagnostics(self, msg: Any) -> None:
        for s in msg.status:
            if s.name.startswith(self.detector):
                values = {v.key: v.value for v in s.values}
                self.diagnostics.append({"t": time.time(), "level": s.level[0], "message": s.message, **values})

    def _detector_latency(self, pose: dict[str, Any]) -> float | None:
        """From the image's arrival here to its pose's: the detector's share of the latency (transport included)."""
        seen = self.image_arrival.get(pose["stamp"])
        return None if seen is None else pose["stamp"] * 1e-9 + pose["latency"] - seen

    def pairs(self, skip: set[int] | None = None, tolerance: int = 25_000_000) -> tuple[list[dict[str, Any]], int]:
        """Each pose inside the span of the truth received (but those stamped as in ``skip``, ns), with the truth
        nearest its stamp when within ``tolerance`` (ns); and how many such poses had none that near.

        The truth goes out every 20 ms and frames are exposed in between; outside the span of the truth received
        nothing is known (the truth is not kept), so those poses are left out.
        """
        stamps = sorted(self.truth)
        pairs, unpaired = [], 0
        for p in self.poses:
            k = p["stamp"]
            if k in (skip or ()) or not stamps or not stamps[0] <= k <= stamps[-1]:
                continue
            nearest = min(stamps, key=lambda s: abs(s - k))
            if abs(nearest - k) < tolerance:
                pairs.append({**p, "truth": self.truth[nearest], "detector": self._detector_latency(p)})
            else:
                unpaired += 1
        return pairs, unpaired


def call(node: Any, service_type: Any, service: str, request: Any) -> Any:
    """The response of a service of the detector (``/monodock_detector/<service>``)."""
    import rclpy

    client = node.create_client(service_type, f"/monodock_detector/{service}")
    assert client.wait_for_service(timeout_sec=30.0), f"no {service} service"
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=30.0)
    return future.result()


def spin_for(node: Any, seconds: float) -> None:
    """Run ``node``'s callbacks for ``seconds``."""
    import rclpy

    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        rclpy.spin_once(node, timeout_sec=min(left, 0.05))
