"""Driver (tests/ros/test_dock_graph.py, inside a private network namespace): monodock_sim and monodock_dock on one
graph; call the dock node's services in turn and print, after each mission, its result and the sim's truth.

Argument: one JSON object with
    start: [x, y, yaw] of the robot in the dock frame;
    steps: the services to call in turn ("dock", "undock");
    fault: optional, {"kind": "camera" | "odometry" | "kill" | "sigint" | "cancel" | "again" | "garbage",
           "state": the mission state that springs it (kill, sigint: once the robot has moved 2 cm in it;
           again: a second call of the same service, which cancels;
           garbage: malformed images published on the camera topic from then on),
           "for": seconds a silenced sensor stays silent (camera)};
    sim: optional, monodock_sim's parameters (e.g. cmd_vel_timeout);
    setup: optional, a folder with layout.yaml, robot.yaml and camera.yaml (default: the built-in set-up);
    params: optional, the dock node's parameters, given as a params file (nested mappings);
    record: optional, a folder for an MCAP recording of the run (monodock-record-ros).
Prints JSON lines: {"kind": "step", ...} per mission, {"kind": "fault", ...}, {"kind": "end", ...}.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from graph_processes import DOCK, SIM, stop_nodes
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import BatteryState, Image
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.ros.recorder import RecorderOptions, RecorderProcess

spec = json.loads(sys.argv[1])
folder = Path(tempfile.mkdtemp())
if spec.get("setup"):  # another set-up: its layout, robot (mounts) and camera, for the sim and the node alike
    setup = Path(spec["setup"])
    DockLayout.load(setup / "layout.yaml").save(folder / "layout.yaml")
    robot_config = RobotConfig.load(setup / "robot.yaml")
    spec.setdefault("sim", {}).update(
        layout=str(setup / "layout.yaml"), robot=str(setup / "robot.yaml"), camera=str(setup / "camera.yaml")
    )
else:
    DockLayout.default().save(folder / "layout.yaml")
    robot_config = RobotConfig.default()
robot_config.save(folder / "robot.yaml")
start = json.dumps(spec["start"])

sim_params = [f"{k}:={v}" for k, v in {"start": start, "seed": 1, **spec.get("sim", {})}.items()]
sim = subprocess.Popen([sys.executable, "-c", SIM, "--ros-args", *[a for kv in sim_params for a in ("-p", kv)]])
dock_args = ["--method", "board", "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml")]
# The sim's clock (/clock): under load the simulation may fall behind the wall clock, and the mission must time
# its frames and odometry on the clock that stamped them, as with any simulator.
dock_args += ["--ros-args", "-p", "use_sim_time:=true"]
if spec.get("params"):  # a ROS 2 params file: the docking config's keys, nested as in docs/docking.yaml
    (folder / "params.yaml").write_text(json.dumps({"monodock_dock": {"ros__parameters": spec["params"]}}))
    dock_args += ["--ros-args", "--params-file", str(folder / "params.yaml")]
dock = subprocess.Popen([sys.executable, "-c", DOCK, *dock_args])
recorder = None
if spec.get("record"):  # a rosbag2 (MCAP) of the run: images, poses, odometry, cmd_vel, state, result
    recorder = RecorderProcess(RecorderOptions(spec["record"])).start()

rclpy.init()
node = rclpy.create_node("driver")
latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
states: list[tuple[float, str]] = []
results: list[DiagnosticStatus] = []
# (wall time, robot x, y, heading in the dock frame, the sim's stamp)
truth: list[tuple[float, float, float, float, float]] = []
battery: list[int] = []


def on_truth(msg: Any) -> None:
    # ground_truth is the DockPose in base_link: invert it for the robot in the dock frame.
    x, y = msg.pose.position.x, msg.pose.position.y
    yaw = 2.0 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w)
    c, s = math.cos(yaw), math.sin(yaw)
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    truth.append((time.monotonic(), -(c * x + s * y), s * x - c * y, -yaw, stamp))


node.create_subscription(String, "/monodock_dock/state", lambda msg: states.append((time.monotonic(), msg.data)), 50)
node.create_subscription(DiagnosticStatus, "/monodock_dock/result", results.append, latched)
node.create_subscription(PoseStamped, "/ground_truth", on_truth, 50)
node.create_subscription(BatteryState, "/battery_state", lambda msg: battery.append(msg.power_supply_status), 50)
clients = {name: node.create_client(Trigger, f"/monodock_dock/{name}") for name in ("dock", "undock", "cancel")}
silence = {name: node.create_client(SetBool, f"/monodock_sim/silence_{name}") for name in ("camera", "odometry")}


def malformed_images() -> Any:
    """Images a camera driver should never send: wrong sizes, unknown encodings, no data, absurd dimensions."""
    kinds = [("mono8", 640, 480, 100), ("bayer_xyz9", 640, 480, 640 * 480), ("mono8", 0, 0, 0), ("rgb8", 640, 480, 7),
             ("mono8", 60000, 60000, 16), ("mono16", 640, 480, 640 * 480)]  # fmt: skip
    while True:
        for encoding, width, height, size in kinds:
            msg = Image(encoding=encoding, width=width, height=height, step=width, data=bytes(size))
            msg.header.stamp = node.get_clock().now().to_msg()
            yield msg


bad_images = malformed_images()


def spin_for(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.02)


def call(client: Any, request: Any) -> Any:
    future = client.call_async(request)
    end = time.monotonic() + 20
    while not future.done() and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    return future.result()


def emit(kind: str, /, **values: Any) -> None:
    print(json.dumps({"kind": kind, **values}), flush=True)


def final_truth() -> dict[str, float]:
    _, x, y, heading, _ = truth[-1]
    return {
        "lateral_cm": 100 * y,
        "gap_cm": 100 * (-x - robot_config.front_offset),  # front edge's centre to the face
        "heading_deg": math.degrees(heading),
    }


ready = time.monotonic() + 90
while not (clients["dock"].service_is_ready() and truth) and time.monotonic() < ready:
    rclpy.spin_once(node, timeout_sec=0.1)
if recorder is not None and not recorder.wait_for(["/image", "/odom", "/cmd_vel", "/monodock_dock/state"], 30):
    emit("recorder", ok=False, log=recorder.log)
emit("ready", ok=clients["dock"].service_is_ready())
fault = spec.get("fault")
for step in spec["steps"]:
    before = len(results)
    t0 = time.monotonic()
    reply = call(clients[step], Trigger.Request())
    emit("reply", step=step, success=bool(reply and reply.success), message=reply.message if reply else "")
    if not (reply and reply.success):
        emit(
            "step",
            step=step,
            level=-1,
            message="refused",
            values={},
            seconds=0.0,
            truth=final_truth(),
            charging=False,
            states=[],
        )
        continue
    sprung = False
    deadline = t0 + 150
    while len(results) == before and time.monotonic() < deadline and dock.poll() is None:
        rclpy.spin_once(node, timeout_sec=0.02)
        if fault and not sprung and states and states[-1][1] == fault["state"]:
            sprung = True
            at = time.monotonic()
            if fault["kind"] in ("kill", "sigint"):
                # Spring once the robot is under way in that state, not at the instant it is entered (it may still
                # be at rest after Moving₂'s turn): 2 cm travelled, or 5 s, whichever is first.
                start = truth[-1][1:3]
                under_way = time.monotonic() + 5.0
                while math.dist(truth[-1][1:3], start) < 0.02 and time.monotonic() < under_way:
                    rclpy.spin_once(node, timeout_sec=0.01)
                at = truth[-1][4]  # the sim's time of the last state seen before the signal
                dock.send_signal(signal.SIGKILL if fault["kind"] == "kill" else signal.SIGINT)
                dock.wait()
                # Watch 4 s of the sim's time, not of the wall clock: under load the sim falls behind the wall
                # clock and catches up in bursts, so a wall-clock window may hold too little of its motion.
                watch = time.monotonic() + 20.0
                while truth[-1][4] < at + 4.0 and time.monotonic() < watch:
                    rclpy.spin_once(node, timeout_sec=0.02)
                track = [(stamp - at, x, y) for _, x, y, _, stamp in truth if stamp >= at - 0.2]
                emit("fault", what=fault["kind"], track=track, returncode=dock.returncode)
                break
            if fault["kind"] == "garbage":  # malformed images on the camera topic, among the good ones, from now on
                garbage = node.create_publisher(Image, "/image", qos_profile_sensor_data)
                node.create_timer(0.03, lambda pub=garbage: pub.publish(next(bad_images)))
                emit("fault", what="garbage")
                continue
            if fault["kind"] in ("cancel", "again"):
                service = "cancel" if fault["kind"] == "cancel" else step
                reply = call(clients[service], Trigger.Request())
                emit("fault", what=fault["kind"], success=bool(reply and reply.success), message=reply.message)
                continue
            request = SetBool.Request(data=True)
            call(silence[fault["kind"]], request)
            emit("fault", what=fault["kind"], state=fault["state"])
            if "for" in fault:
                spin_for(float(fault["for"]))
                call(silence[fault["kind"]], SetBool.Request(data=False))
    if dock.poll() is not None:
        break
    spin_for(1.0)  # let the robot settle and the battery report
    status = results[-1] if len(results) > before else None
    values = {kv.key: kv.value for kv in status.values} if status else {}
    emit(
        "step",
        step=step,
        level=int.from_bytes(status.level, "little")
        if isinstance(status.level, bytes)
        else int(status.level)
        if status
        else -1,
        message=status.message if status else "no result",
        values=values,
        seconds=time.monotonic() - t0,
        truth=final_truth(),
        charging=bool(battery) and battery[-1] == BatteryState.POWER_SUPPLY_STATUS_CHARGING,
        states=[s for t, s in states if t >= t0],
    )
    if fault and fault["kind"] == "odometry":
        call(silence["odometry"], SetBool.Request(data=False))
        fault = None
        # Let odometry flow again before the next call: on a loaded machine the sim's first messages can come
        # later than the node's 2 s odometry time-out (a flake seen once in CI).
        spin_for(3.0)

recorded = None if recorder is None else recorder.stop()  # first: the bag holds the run to its end
stop_nodes(dock, sim)
emit("end", dock=dock.returncode, sim=sim.returncode, recorder=recorded)
node.destroy_node()
rclpy.shutdown()
