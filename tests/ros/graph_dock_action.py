"""Driver (tests/ros/test_dock_action_graph.py, inside a private network namespace): monodock_sim and monodock_dock
on one graph, driven only through Nav2's actions, by a client written from the upstream nav2_msgs definitions.

Argument: one JSON object with
    start: [x, y, yaw] of the robot in the dock frame;
    goals: in turn, each {"action": "dock" | "undock", "goal": {field: value} (DockRobot/UndockRobot goal fields),
           "cancel_in": optional, the feedback state (CONTROLLING = 3, ...) that makes the client cancel the goal,
           "preempt_in", "preempt_with": optional, the feedback state at which the client sends the step
           ``preempt_with`` while this goal runs}.
Prints JSON lines: {"kind": "ready"}, per goal {"kind": "goal", accepted, status, result fields, feedback states,
the last feedback's docking time and retries, the truth after it, charging}, {"kind": "end", ...}.
"""

from __future__ import annotations

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
from geometry_msgs.msg import PoseStamped
from graph_processes import DOCK, SIM, stop_nodes
from nav2_msgs.action import DockRobot, UndockRobot
from rclpy.action import ActionClient
from sensor_msgs.msg import BatteryState

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig

spec = json.loads(sys.argv[1])
folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
robot_config = RobotConfig.default()
robot_config.save(folder / "robot.yaml")

sim = subprocess.Popen(
    [sys.executable, "-c", SIM, "--ros-args", "-p", f"start:={json.dumps(spec['start'])}", "-p", "seed:=1"]
)
dock_args = ["--method", "board", "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml")]
dock = subprocess.Popen([sys.executable, "-c", DOCK, *dock_args, "--ros-args", "-p", "use_sim_time:=true"])

rclpy.init()
node = rclpy.create_node("nav2_like_client")
truth: list[tuple[float, float, float]] = []
battery: list[int] = []


def on_truth(msg: Any) -> None:
    # ground_truth is the DockPose in base_link: invert it for the robot in the dock frame.
    x, y = msg.pose.position.x, msg.pose.position.y
    yaw = 2.0 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w)
    c, s = math.cos(yaw), math.sin(yaw)
    truth.append((-(c * x + s * y), s * x - c * y, -yaw))


node.create_subscription(PoseStamped, "/ground_truth", on_truth, 50)
node.create_subscription(BatteryState, "/battery_state", lambda msg: battery.append(msg.power_supply_status), 50)
clients = {
    "dock": ActionClient(node, DockRobot, "dock_robot"),
    "undock": ActionClient(node, UndockRobot, "undock_robot"),
}


def emit(kind: str, /, **values: Any) -> None:
    print(json.dumps({"kind": kind, **values}), flush=True)


def spin_until(done: Any, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while not done() and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.02)
    return bool(done())


def send(step: dict[str, Any]) -> tuple[Any, list[Any]]:
    """The goal handle (None when not accepted) of a step's goal, and the list its feedback goes to."""
    action = DockRobot if step["action"] == "dock" else UndockRobot
    goal = action.Goal()
    for field, value in step.get("goal", {}).items():
        setattr(goal, field, value)
    feedback: list[Any] = []
    sent = clients[step["action"]].send_goal_async(
        goal, feedback_callback=lambda f, into=feedback: into.append(f.feedback)
    )
    spin_until(sent.done, 20)
    handle = sent.result()
    return (handle if handle is not None and handle.accepted else None), feedback


def report(step: dict[str, Any], result_future: Any, feedback: list[Any], cancelled: Any, **more: Any) -> None:
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
        charging=bool(battery) and battery[-1] == BatteryState.POWER_SUPPLY_STATUS_CHARGING,
        **more,
    )


ready = spin_until(lambda: all(c.server_is_ready() for c in clients.values()) and truth, 90)
emit("ready", ok=ready)
for step in spec["goals"] if ready else []:
    handle, feedback = send(step)
    if handle is None:
        emit("goal", action=step["action"], accepted=False)
        continue
    result_future = handle.get_result_async()
    cancel_in, preempt_in = step.get("cancel_in"), step.get("preempt_in")
    cancelled = None
    preempting: tuple[Any, list[Any]] | None = None
    end = time.monotonic() + 150
    while not result_future.done() and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.02)
        reached = feedback[-1].state if feedback else None
        if cancel_in is not None and cancelled is None and reached == cancel_in:
            cancelled = handle.cancel_goal_async()
        if preempt_in is not None and preempting is None and reached == preempt_in:
            preempting = send(step["preempt_with"])  # a new goal while this one runs, as a behaviour tree may send
    if preempting is None:
        spin_until(lambda: False, 1.0)  # the robot settles, the battery reports
        report(step, result_future, feedback, cancelled)
        continue
    # The preempted goal's result (as it was when the new goal took over), then the new goal's to its end.
    report(step, result_future, feedback, cancelled, preempted=True)
    second, second_feedback = preempting
    if second is None:
        emit("goal", action=step["preempt_with"]["action"], accepted=False)
        continue
    second_future = second.get_result_async()
    spin_until(second_future.done, 150)
    spin_until(lambda: False, 1.0)
    report(step["preempt_with"], second_future, second_feedback, None, preempting=True)

stop_nodes(dock, sim)
emit("end", dock=dock.returncode, sim=sim.returncode)
node.destroy_node()
rclpy.shutdown()
