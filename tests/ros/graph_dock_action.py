"""Driver (tests/ros/test_dock_action_graph.py, inside a private network namespace): monodock_sim and monodock_dock
on one graph, driven only through Nav2's actions, by a client written from the upstream nav2_msgs definitions, as
Nav2's behaviour tree nodes send them.

Argument: one JSON object with
    start: [x, y, yaw] of the robot in the dock frame;
    sim_layout: optional, "lab": the sim's dock carries the lab layout (ids 11-13, written to FOLDER/lab.yaml), not
        the node's own layout (ids 1-3, FOLDER/layout.yaml);
    files: optional, {name: text} written to FOLDER/name ("{folder}" in the text is FOLDER);
    dock_params: optional, more ``-p name:=value`` for monodock_dock ("{folder}" is FOLDER);
    navigator: optional, true: this driver also serves navigate_to_pose (a plain go-to-pose controller on the sim's
        odometry, as Nav2's navigation would drive), and reports the goals it got;
    goals: in turn, each {"action": "reload", "file": name} (~/reload_database with FOLDER/name) or
           {"action": "dock" | "undock", "goal": {field: value} (DockRobot/UndockRobot goal fields;
           "dock_pose": [x, y, yaw, frame] for a PoseStamped),
           "cancel_in": optional, the feedback state (CONTROLLING = 3, ...) that makes the client cancel the goal,
           "cancel_at_once": optional, cancel as soon as the goal is accepted,
           "preempt_in", "preempt_with": optional, the feedback state at which the client sends the step
           ``preempt_with`` while this goal runs}.
Prints JSON lines: {"kind": "ready"}, per goal {"kind": "goal", accepted, status, result fields, feedback states,
the last feedback's docking time and retries, the truth before it and after it, charging, the last message of each of
Nav2's debug topics}, per reload {"kind": "reload", success}, {"kind": "navigator"}, {"kind": "end", ...}.
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
from geometry_msgs.msg import PoseStamped, TwistStamped
from graph_processes import DOCK, SIM, Spinner, emit, stop_nodes, wait
from nav2_msgs.action import DockRobot, NavigateToPose, UndockRobot
from nav2_msgs.srv import ReloadDockDatabase
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.action import ActionClient, ActionServer, CancelResponse
from sensor_msgs.msg import BatteryState

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig

spec = json.loads(sys.argv[1])
folder = Path(tempfile.mkdtemp())
own = DockLayout.default()
own.save(folder / "layout.yaml")
lab = dataclasses.replace(own, markers=tuple(dataclasses.replace(m, id=m.id + 10) for m in own.markers))
lab.save(folder / "lab.yaml")
robot_config = RobotConfig.default()
robot_config.save(folder / "robot.yaml")
for name, text in spec.get("files", {}).items():
    (folder / name).write_text(text.replace("{folder}", str(folder)))

sim_args = ["-p", f"start:={json.dumps(spec['start'])}", "-p", "seed:=1"]
if spec.get("sim_layout") == "lab":
    sim_args += ["-p", f"layout:={folder / 'lab.yaml'}"]
sim = subprocess.Popen([sys.executable, "-c", SIM, "--ros-args", *sim_args])
dock_args = ["--method", "board", "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml")]
more = [arg for p in spec.get("dock_params", []) for arg in ("-p", p.replace("{folder}", str(folder)))]
dock = subprocess.Popen([sys.executable, "-c", DOCK, *dock_args, "--ros-args", "-p", "use_sim_time:=true", *more])

rclpy.init()
node = rclpy.create_node("nav2_like_client")
truth: list[tuple[float, float, float]] = []
battery: list[int] = []
odom: list[tuple[float, float, float]] = []


def on_truth(msg: Any) -> None:
    # ground_truth is the DockPose in base_link: invert it for the robot in the dock frame.
    x, y = msg.pose.position.x, msg.pose.position.y
    yaw = 2.0 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w)
    c, s = math.cos(yaw), math.sin(yaw)
    truth.append((-(c * x + s * y), s * x - c * y, -yaw))


def on_odom(msg: Any) -> None:
    q = msg.pose.pose.orientation
    odom.append((msg.pose.pose.position.x, msg.pose.pose.position.y, 2.0 * math.atan2(q.z, q.w)))


node.create_subscription(PoseStamped, "/ground_truth", on_truth, 50)
node.create_subscription(
    BatteryState,
    "/battery_state",
    lambda msg: battery.append(msg.power_supply_status),
    50,
)
node.create_subscription(Odometry, "/odom", on_odom, 50)
debug: dict[str, Any] = {}


def on_debug(name: str, msg: Any) -> None:
    p, q = msg.pose.position, msg.pose.orientation
    debug[name] = [p.x, p.y, 2.0 * math.atan2(q.z, q.w), msg.header.frame_id]


for topic in ("dock_pose", "filtered_dock_pose", "staging_pose"):
    node.create_subscription(PoseStamped, topic, lambda m, t=topic: on_debug(t, m), 10)


def on_trajectory(msg: Any) -> None:
    debug["docking_trajectory"] = [[p.pose.position.x, p.pose.position.y, p.header.frame_id] for p in msg.poses]


node.create_subscription(PathMsg, "docking_trajectory", on_trajectory, 10)
reload_client = node.create_client(ReloadDockDatabase, "/monodock_dock/reload_database")
clients = {
    "dock": ActionClient(node, DockRobot, "dock_robot"),
    "undock": ActionClient(node, UndockRobot, "undock_robot"),
}
navigated: list[list[float | str]] = []


class Navigation:
    """navigate_to_pose as Nav2's navigation would serve it: turn, drive, turn, on odometry, in the odom frame.

    Driven by a 50 Hz timer, not inside the goal's execute callback, so that one single-threaded executor serves it
    beside everything else: a goal is accepted and held, each tick steers towards it, and it is executed (its result
    state set) once there or once its cancel comes."""

    def __init__(self) -> None:
        self.handle: Any = None
        self.goal = (0.0, 0.0, 0.0)
        self.cmd = node.create_publisher(TwistStamped, "/cmd_vel", 10)
        ActionServer(
            node,
            NavigateToPose,
            "navigate_to_pose",
            lambda _handle: NavigateToPose.Result(),  # executed only to end a goal: see tick
            handle_accepted_callback=self.accepted,
            cancel_callback=lambda _handle: CancelResponse.ACCEPT,
        )
        node.create_timer(0.02, self.tick)

    def accepted(self, handle: Any) -> None:
        p, q = handle.request.pose.pose.position, handle.request.pose.pose.orientation
        self.goal = (p.x, p.y, 2.0 * math.atan2(q.z, q.w))
        navigated.append([*self.goal, handle.request.pose.header.frame_id])
        self.handle = handle

    def send(self, v: float, w: float) -> None:
        msg = TwistStamped()
        msg.twist.linear.x, msg.twist.angular.z = v, w
        self.cmd.publish(msg)

    def end(self, how: str) -> None:
        self.send(0.0, 0.0)
        handle, self.handle = self.handle, None

        def finish(h: Any) -> Any:
            getattr(h, how)()
            return NavigateToPose.Result()

        handle.execute(finish)

    def tick(self) -> None:
        if self.handle is None or not odom:
            return
        if self.handle.is_cancel_requested:
            self.end("canceled")
            return
        x, y, th = odom[-1]
        dx, dy = self.goal[0] - x, self.goal[1] - y
        far = math.hypot(dx, dy) > 0.03
        turn = math.remainder((math.atan2(dy, dx) if far else self.goal[2]) - th, math.tau)
        if not far and abs(turn) < 0.03:
            self.end("succeed")
            return
        self.send(0.15 if far and abs(turn) < 0.2 else 0.0, max(-0.5, min(0.5, 1.5 * turn)))


if spec.get("navigator"):
    Navigation()
spinner = Spinner(node)


def make_goal(step: dict[str, Any]) -> Any:
    action = DockRobot if step["action"] == "dock" else UndockRobot
    goal = action.Goal()
    for field, value in step.get("goal", {}).items():
        if field == "dock_pose":
            x, y, yaw, frame = value
            goal.dock_pose.header.frame_id = frame
            goal.dock_pose.pose.position.x, goal.dock_pose.pose.position.y = x, y
            goal.dock_pose.pose.orientation.z, goal.dock_pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        else:
            setattr(goal, field, value)
    return goal


def send(step: dict[str, Any]) -> tuple[Any, list[Any]]:
    """The goal handle (None when not accepted) of a step's goal, and the list its feedback goes to."""
    feedback: list[Any] = []
    sent = clients[step["action"]].send_goal_async(
        make_goal(step), feedback_callback=lambda f, into=feedback: into.append(f.feedback)
    )
    wait(sent.done, 20)
    handle = sent.result()
    return (handle if handle is not None and handle.accepted else None), feedback


def report(
    step: dict[str, Any], result_future: Any, feedback: list[Any], before: Any, cancelled: Any, **more: Any
) -> None:
    wrapped = result_future.result() if result_future.done() else None
    result = wrapped.result if wrapped is not None else None
    x, y, heading = truth[-1]
    last = feedback[-1] if feedback else None
    emit(
        "goal",
        action=step["action"],
        accepted=True,
        status=int(wrapped.status) if wrapped is not None else -1,
        succeeded=wrapped is not None and wrapped.status == GoalStatus.STATUS_SUCCEEDED,
        canceled=wrapped is not None and wrapped.status == GoalStatus.STATUS_CANCELED,
        aborted=wrapped is not None and wrapped.status == GoalStatus.STATUS_ABORTED,
        cancel_accepted=None if cancelled is None else bool(cancelled.done() and cancelled.result().goals_canceling),
        success=bool(result.success) if result is not None else None,
        error_code=int(result.error_code) if result is not None else None,
        error_msg=result.error_msg if result is not None else None,
        num_retries=int(getattr(result, "num_retries", 0)) if result is not None else None,
        feedback_states=[int(f.state) for f in feedback],
        docking_time=(last.docking_time.sec + 1e-9 * last.docking_time.nanosec) if last is not None else None,
        truth={
            "lateral_cm": 100 * y,
            "gap_cm": 100 * (-x - robot_config.front_offset),
            "heading_deg": math.degrees(heading),
        },
        moved_cm=100 * math.hypot(x - before[0], y - before[1]),
        turned_deg=math.degrees(abs(math.atan2(math.sin(heading - before[2]), math.cos(heading - before[2])))),
        charging=bool(battery) and battery[-1] == BatteryState.POWER_SUPPLY_STATUS_CHARGING,
        debug=dict(debug),
        **more,
    )


ready = wait(lambda: all(c.server_is_ready() for c in clients.values()) and truth and odom, 90)
emit("ready", ok=ready)
for step in spec["goals"] if ready else []:
    if step["action"] == "reload":
        request = ReloadDockDatabase.Request(filepath=str(folder / step["file"]))
        answered = reload_client.call_async(request)
        wait(answered.done, 20)
        emit("reload", success=bool(answered.done() and answered.result().success))
        continue
    debug.clear()
    before = truth[-1]
    handle, feedback = send(step)
    if handle is None:
        emit("goal", action=step["action"], accepted=False)
        continue
    result_future = handle.get_result_async()
    cancel_in, preempt_in = step.get("cancel_in"), step.get("preempt_in")
    cancelled = handle.cancel_goal_async() if step.get("cancel_at_once") else None
    preempting: tuple[Any, list[Any]] | None = None
    end = time.monotonic() + 150
    while not result_future.done() and time.monotonic() < end:
        time.sleep(0.01)
        reached = feedback[-1].state if feedback else None
        if cancel_in is not None and cancelled is None and reached == cancel_in:
            cancelled = handle.cancel_goal_async()
        if preempt_in is not None and preempting is None and reached == preempt_in:
            preempting = send(step["preempt_with"])  # a new goal while this one runs, as a behaviour tree may send
    wait(lambda: False, 0.5)  # the robot settles (the base stops within 0.1 s), the battery reports
    if preempting is None:
        report(step, result_future, feedback, before, cancelled)
        continue
    report(step, result_future, feedback, before, cancelled, preempted=True)
    second, second_feedback = preempting
    if second is None:
        emit("goal", action=step["preempt_with"]["action"], accepted=False)
        continue
    second_future = second.get_result_async()
    wait(second_future.done, 150)
    wait(lambda: False, 0.5)
    report(step["preempt_with"], second_future, second_feedback, before, None, preempting=True)

emit("navigator", goals=navigated)
stop_nodes(dock, sim)
emit("end", dock=dock.returncode, sim=sim.returncode)
spinner.stop()
node.destroy_node()
rclpy.shutdown()
