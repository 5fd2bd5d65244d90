"""Driver (tests/ros/test_two_robots_graph.py, inside a private network namespace): two simulated robots, /r1 and /r2,
each with its own monodock_sim and monodock_dock, docking at the same time on one graph.

Each robot runs in its namespace (``-r __ns:=/rN``) with frame names of its own (``rN/base_link``, ``rN/odom``,
``rN/camera_link``, ``rN/camera_optical_frame``) and its own clock topic (``-r /clock:=/rN/clock`` on its sim and its
docking node, which runs on ``use_sim_time``); ``/tf`` and ``/tf_static`` are shared. r1's docking node is given a
robot file whose camera mount is 5 cm and 2° off the true one and must take the true mount from /tf_static.

Argument: one JSON object ``{"robots": {"r1": {"start": [x, y, yaw], "seed": n}, "r2": {...}}, "sim": {...}}``
(``sim``: more parameters for both sims, e.g. camera_rate). A client written from the upstream nav2_msgs definitions
sends DockRobot goals to /r1/dock_robot and /r2/dock_robot together and waits for both.

Prints JSON lines: {"kind": "ready"}, per robot {"kind": "robot", ...: its goal's outcome, its truth and battery
after it, the frames its messages carried}, {"kind": "tf", ...}, {"kind": "graph", ...: every topic's publishers
and subscribers by node}, per process {"kind": "process", ...: its exit code and log}.
"""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import rclpy
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from graph_processes import DOCK, SIM, stop_nodes
from nav2_msgs.action import DockRobot
from nav_msgs.msg import Odometry
from rclpy.action import ActionClient
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import BatteryState, CameraInfo
from tf2_msgs.msg import TFMessage

from monodock.core.layout import DockLayout
from monodock.core.robot import Mount, RobotConfig

spec = json.loads(sys.argv[1])
ROBOTS: list[str] = sorted(spec["robots"])
WRONG_MOUNT = "r1"  # its docking node's robot file has the camera 5 cm and 2 degrees off
folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
true_robot = RobotConfig.default()  # what the sims render with and latch on /tf_static
true_robot.save(folder / "robot.yaml")
m = true_robot.camera_mount
wrong = Mount(m.x, m.y + 0.05, m.z, m.roll, m.pitch, m.yaw + math.radians(2.0))
dataclasses.replace(true_robot, camera_mount=wrong).save(folder / "wrong_robot.yaml")


def frames(r: str) -> dict[str, str]:
    return {
        "frame_id": f"{r}/base_link",
        "odom_frame": f"{r}/odom",
        "camera_frame": f"{r}/camera_link",
        "camera_frame_id": f"{r}/camera_optical_frame",
    }


def spawn(name: str, command: list[str]) -> tuple[subprocess.Popen[bytes], Path]:
    """A node's process, its log (stderr) in a file: a pipe nobody reads while the graph runs would fill and block."""
    log = folder / f"{name}.log"
    with log.open("wb") as out:
        return subprocess.Popen(command, stderr=out), log


processes: dict[str, tuple[subprocess.Popen[bytes], Path]] = {}
for r in ROBOTS:
    mine = ["-r", f"__ns:=/{r}", "-r", f"/clock:=/{r}/clock"]
    params = {
        "start": json.dumps(spec["robots"][r]["start"]),
        "seed": spec["robots"][r]["seed"],
        **frames(r),
        **spec.get("sim", {}),
    }
    sim_args = [a for k, v in params.items() for a in ("-p", f"{k}:={v}")]
    processes[f"{r}/sim"] = spawn(f"{r}_sim", [sys.executable, "-c", SIM, "--ros-args", *mine, *sim_args])
for r in ROBOTS:
    robot_file = folder / ("wrong_robot.yaml" if r == WRONG_MOUNT else "robot.yaml")
    dock_args = ["--method", "board", "--layout", str(folder / "layout.yaml"), "--robot", str(robot_file)]
    ros_args = ["--ros-args", "-r", f"__ns:=/{r}", "-r", f"/clock:=/{r}/clock"]
    ros_args += ["-p", "use_sim_time:=true", "-p", f"frame_id:={r}/base_link"]
    processes[f"{r}/dock"] = spawn(f"{r}_dock", [sys.executable, "-c", DOCK, *dock_args, *ros_args])

rclpy.init()
node = rclpy.create_node("two_robots_client")
DEEP = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
truth: dict[str, list[tuple[float, float, float]]] = {r: [] for r in ROBOTS}
battery: dict[str, list[int]] = {r: [] for r in ROBOTS}
seen_frames: dict[str, dict[str, set[str]]] = {r: {} for r in ROBOTS}  # robot -> what -> frame names
odom_at: dict[str, dict[int, tuple[float, float]]] = {r: {} for r in ROBOTS}  # robot -> stamp -> odometry (x, y)
tf_at: dict[tuple[str, str], dict[int, tuple[float, float]]] = {}  # (parent, child) -> stamp -> (x, y)
tf_static: list[tuple[str, str]] = []
results: dict[str, dict[str, Any]] = {}


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def saw(r: str, what: str, *names: str) -> None:
    seen_frames[r].setdefault(what, set()).update(names)


def on_truth(r: str, msg: Any) -> None:
    # ground_truth is the DockPose in base_link: invert it for the robot in the dock frame.
    saw(r, "ground_truth", msg.header.frame_id)
    x, y = msg.pose.position.x, msg.pose.position.y
    yaw = 2.0 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w)
    c, s = math.cos(yaw), math.sin(yaw)
    truth[r].append((-(c * x + s * y), s * x - c * y, -yaw))


def on_battery(r: str, msg: Any) -> None:
    battery[r].append(msg.power_supply_status)


def on_odom(r: str, msg: Any) -> None:
    saw(r, "odom", f"{msg.header.frame_id} -> {msg.child_frame_id}")
    odom_at[r][stamp_ns(msg.header)] = (msg.pose.pose.position.x, msg.pose.pose.position.y)


def on_tf(msg: Any) -> None:
    for t in msg.transforms:
        move = t.transform.translation
        tf_at.setdefault((t.header.frame_id, t.child_frame_id), {})[stamp_ns(t.header)] = (move.x, move.y)


def on_tf_static(msg: Any) -> None:
    tf_static.extend((t.header.frame_id, t.child_frame_id) for t in msg.transforms)


def on_result(r: str, msg: Any) -> None:
    results[r] = {"level": int(msg.level[0]), "message": msg.message, "hardware_id": msg.hardware_id}


latched = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
for r in ROBOTS:
    node.create_subscription(PoseStamped, f"/{r}/ground_truth", lambda msg, r=r: on_truth(r, msg), DEEP)
    node.create_subscription(BatteryState, f"/{r}/battery_state", lambda msg, r=r: on_battery(r, msg), DEEP)
    node.create_subscription(Odometry, f"/{r}/odom", lambda msg, r=r: on_odom(r, msg), DEEP)
    node.create_subscription(
        CameraInfo,
        f"/{r}/camera_info",
        lambda msg, r=r: saw(r, "camera_info", msg.header.frame_id),
        qos_profile_sensor_data,
    )
    node.create_subscription(
        PoseStamped, f"/{r}/detected_dock_pose", lambda msg, r=r: saw(r, "detected_dock_pose", msg.header.frame_id), 50
    )
    node.create_subscription(
        DiagnosticStatus,
        f"/{r}/monodock_dock/result",
        lambda msg, r=r: on_result(r, msg),
        QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL),
    )
diagnostics: set[str] = set()
node.create_subscription(
    DiagnosticArray, "/diagnostics", lambda msg: diagnostics.update(s.name for s in msg.status), DEEP
)
node.create_subscription(TFMessage, "/tf", on_tf, DEEP)
node.create_subscription(TFMessage, "/tf_static", on_tf_static, latched)
clients = {r: ActionClient(node, DockRobot, f"/{r}/dock_robot") for r in ROBOTS}


def emit(kind: str, /, **values: Any) -> None:
    print(json.dumps({"kind": kind, **values}), flush=True)


def spin_until(done: Any, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while not done() and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.02)
    return bool(done())


began = time.monotonic()
ready = spin_until(lambda: all(c.server_is_ready() for c in clients.values()) and all(truth.values()), 120)
emit("ready", ok=ready, seconds=time.monotonic() - began)
handles: dict[str, Any] = {}
feedback: dict[str, list[Any]] = {r: [] for r in ROBOTS}
feedback_at: dict[str, list[float]] = {r: [] for r in ROBOTS}  # when each feedback arrived, s after the goals


def on_feedback(r: str, message: Any) -> None:
    feedback[r].append(message.feedback)
    feedback_at[r].append(time.monotonic() - sent_at)


sent_at = time.monotonic()
if ready:
    goal = DockRobot.Goal(use_dock_id=True, dock_id="home_dock", navigate_to_staging_pose=False)
    sent_at = time.monotonic()
    sent = {
        r: c.send_goal_async(goal, feedback_callback=lambda f, r=r: on_feedback(r, f)) for r, c in clients.items()
    }  # both before either is answered: the two missions run side by side
    spin_until(lambda: all(s.done() for s in sent.values()), 30)
    handles = {r: s.result() for r, s in sent.items() if s.done()}
    futures = {r: h.get_result_async() for r, h in handles.items() if h is not None and h.accepted}
    finished: dict[str, float] = {}

    def both_done() -> bool:
        for r, f in futures.items():
            if f.done() and r not in finished:
                finished[r] = time.monotonic() - sent_at
        return len(finished) == len(ROBOTS)

    spin_until(both_done, 240)
    spin_until(lambda: False, 1.5)  # the robots settle, the batteries report
    for r in ROBOTS:
        wrapped = futures[r].result() if r in futures and futures[r].done() else None
        result = wrapped.result if wrapped is not None else None
        x, y, heading = truth[r][-1]
        states = [int(f.state) for f in feedback[r]]
        emit(
            "robot",
            name=r,
            accepted=r in futures,
            succeeded=wrapped is not None and wrapped.status == GoalStatus.STATUS_SUCCEEDED,
            error_code=int(result.error_code) if result is not None else None,
            error_msg=result.error_msg if result is not None else None,
            seconds=finished.get(r),
            feedback=len(states),
            feedback_states=sorted(set(states)),
            feedback_span=[feedback_at[r][0], feedback_at[r][-1]] if feedback_at[r] else None,
            docking_time=(feedback[r][-1].docking_time.sec + 1e-9 * feedback[r][-1].docking_time.nanosec)
            if feedback[r]
            else None,
            truth={
                "x": x,
                "y": y,
                "lateral_cm": 100 * y,
                "gap_cm": 100 * (-x - true_robot.front_offset),
                "heading_deg": math.degrees(heading),
            },
            start=spec["robots"][r]["start"],
            charging=bool(battery[r]) and battery[r][-1] == BatteryState.POWER_SUPPLY_STATUS_CHARGING,
            frames={what: sorted(names) for what, names in seen_frames[r].items()},
            result=results.get(r),
        )

# /tf against each robot's own odometry, stamp by stamp: r1's odom -> base_link is r1's odometry, not r2's.
tf_report: dict[str, Any] = {"pairs": sorted(f"{p} -> {c}" for p, c in tf_at), "static": sorted(set(tf_static))}
for r in ROBOTS:
    transforms = tf_at.get((f"{r}/odom", f"{r}/base_link"), {})
    common = sorted(set(transforms) & set(odom_at[r]))
    gap = max((math.dist(transforms[k], odom_at[r][k]) for k in common), default=None)
    tf_report[r] = {"transforms": len(transforms), "odometry": len(odom_at[r]), "matched": len(common), "gap": gap}
emit("tf", **tf_report)

# The graph while every node still runs: each topic's publishers and subscribers, by node (namespace, name).
graph: dict[str, dict[str, list[list[str]]]] = {}
for topic, _types in node.get_topic_names_and_types():
    graph[topic] = {
        "publishers": sorted([i.node_namespace, i.node_name] for i in node.get_publishers_info_by_topic(topic)),
        "subscribers": sorted([i.node_namespace, i.node_name] for i in node.get_subscriptions_info_by_topic(topic)),
    }
emit("graph", topics=graph, client=[node.get_namespace(), node.get_name()], diagnostics=sorted(diagnostics))

stop_nodes(*(p for p, _ in processes.values()))
for name, (process, log) in processes.items():
    emit("process", name=name, returncode=process.returncode, log=log.read_text(errors="replace")[-8000:])
emit("end", seconds=time.monotonic() - began)
node.destroy_node()
rclpy.shutdown()
