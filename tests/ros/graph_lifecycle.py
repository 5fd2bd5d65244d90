"""Driver (tests/ros/test_lifecycle_graph.py, in a private network namespace): nav2_lifecycle_manager's side of
bring-up, played against monodock_dock (started as ``docking_server``, as Nav2's bringup names it) and the managed
detector.

Written from Nav2's code, not from monodock's (``nav2_lifecycle_manager/src/lifecycle_manager.cpp`` and
``nav2_util/src/lifecycle_service_client.cpp``, Kilted; bondcpp's ``bond.cpp``, bond_core ros2): for each node in
turn, wait for ``NODE/get_state``, ``change_state`` CONFIGURE then check ``get_state`` is inactive, ACTIVATE then
active, then form a bond on topic ``bond`` with the node's name as its id (publish ``bond/msg/Status`` active every
0.1 s, formed when a status of that id from another instance arrives) within ``bond_timeout``/2 with the default
``bond_timeout`` of 4 s, and watch its heartbeats (broken after 4 s without one). Deactivation ends the bond from the
manager's side (``active: false``), which the node answers the same way.

Prints JSON lines: {"kind": "step", ...} per step, {"kind": "end", ...}.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import rclpy
from bond.msg import Status
from graph_processes import DOCK, ORPHANS_END, Spinner, emit, stop_nodes, wait
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav2_msgs.action import DockRobot
from rclpy.action import ActionClient
from rclpy.qos import QoSProfile

from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig

BOND_TIMEOUT = 4.0  # nav2_lifecycle_manager's default bond_timeout, s
HEARTBEAT_PERIOD = 0.10  # the manager's side (createBondConnection)
DETECTOR = (
    ORPHANS_END + "from monodock.cli.ros_nodes import detector_main; import sys; sys.exit(detector_main(sys.argv[1:]))"
)

folder = Path(tempfile.mkdtemp())
DockLayout.default().save(folder / "layout.yaml")
RobotConfig.default().save(folder / "robot.yaml")
files = ["--method", "board", "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml")]
dock = subprocess.Popen(
    [sys.executable, "-c", DOCK, *files, "--no-autostart", "--ros-args", "-r", "__node:=docking_server"],
    stderr=subprocess.PIPE,
    text=True,
)
detector = subprocess.Popen([sys.executable, "-c", DETECTOR, *files, "--lifecycle"], stderr=subprocess.PIPE, text=True)

rclpy.init()
node = rclpy.create_node("lifecycle_manager_navigation")
spinner = Spinner(node)


class ManagerBond:
    """The manager's side of one bond, as bondcpp runs it: heartbeats out, the sister's heard."""

    def __init__(self, bond_id: str) -> None:
        self.id, self.instance = bond_id, str(uuid.uuid4())
        self.heard: list[tuple[float, bool, str]] = []  # (monotonic time, active, the sister's instance id)
        self.active = True
        self.pub = node.create_publisher(Status, "bond", QoSProfile(depth=5))
        self.sub = node.create_subscription(Status, "bond", self._on_status, QoSProfile(depth=100))
        self.timer = node.create_timer(HEARTBEAT_PERIOD, self._beat)
        self.started = time.monotonic()

    def _on_status(self, msg: Status) -> None:
        if msg.id == self.id and msg.instance_id != self.instance:
            self.heard.append((time.monotonic(), bool(msg.active), msg.instance_id))

    def _beat(self) -> None:
        msg = Status()
        msg.id, msg.instance_id, msg.active = self.id, self.instance, self.active
        msg.heartbeat_timeout, msg.heartbeat_period = BOND_TIMEOUT, HEARTBEAT_PERIOD
        self.pub.publish(msg)

    def formed_after(self) -> float | None:
        """Seconds from start to the sister's first active status (bondcpp's waitUntilFormed)."""
        alive = [t for t, active, _ in self.heard if active]
        return alive[0] - self.started if alive else None

    def broken(self, now: float) -> bool:
        """bondcpp's heartbeat time-out (or the sister said it is dead)."""
        alive = [t for t, active, _ in self.heard if active]
        died = any(not active for _, active, _ in self.heard)
        return died or (bool(alive) and now - alive[-1] > BOND_TIMEOUT)

    def largest_gap(self) -> float:
        alive = [t for t, active, _ in self.heard if active]
        return max((b - a for a, b in itertools.pairwise(alive)), default=0.0)

    def end(self) -> None:
        """The manager's bond destroyed (deactivation): ``active: false`` for a while, then silence."""
        self.active = False
        time.sleep(0.3)
        self.timer.cancel()


def call(client: Any, request: Any, timeout: float = 5.0) -> Any:
    future = client.call_async(request)
    return future.result() if wait(future.done, timeout) else None


def state_of(name: str) -> int:
    got = call(clients[name][1], GetState.Request())
    return -1 if got is None else int(got.current_state.id)


def change(name: str, transition: int) -> bool:
    request = ChangeState.Request()
    request.transition.id = transition
    got = call(clients[name][0], request, 30.0)
    return bool(got is not None and got.success)


def dock_goal_accepted() -> bool:
    sent = dock_client.send_goal_async(DockRobot.Goal(dock_id="nowhere"))
    return bool(wait(sent.done, 10) and sent.result() is not None and sent.result().accepted)


names = ["monodock_detector", "docking_server"]
clients = {
    n: (node.create_client(ChangeState, f"{n}/change_state"), node.create_client(GetState, f"{n}/get_state"))
    for n in names
}
dock_client = ActionClient(node, DockRobot, "dock_robot")
up = all(c[1].wait_for_service(timeout_sec=60) for c in clients.values()) and dock_client.wait_for_server(
    timeout_sec=30
)
emit("step", step="services", ok=up, states={n: state_of(n) for n in names})
emit("step", step="goal while unconfigured", accepted=dock_goal_accepted())
bonds: dict[str, ManagerBond] = {}
for name in names:  # startup(): configure every node, then activate every node (with its bond)
    ok = change(name, Transition.TRANSITION_CONFIGURE)
    emit("step", step="configure", node=name, ok=ok, state=state_of(name))
emit("step", step="goal while inactive", accepted=dock_goal_accepted())
for name in names:
    ok = change(name, Transition.TRANSITION_ACTIVATE)
    state = state_of(name)
    bonds[name] = ManagerBond(name)
    formed = wait(lambda b=bonds[name]: b.formed_after() is not None, BOND_TIMEOUT / 2)
    emit("step", step="activate", node=name, ok=ok, state=state, formed=formed, formed_after=bonds[name].formed_after())
emit("step", step="goal while active", accepted=dock_goal_accepted())
cmd_vel = [info.topic_type for info in node.get_publishers_info_by_topic("/cmd_vel")]
emit("step", step="cmd_vel", types=cmd_vel)
time.sleep(6.0)  # the bonds must hold: a heartbeat at least every bond_timeout
now = time.monotonic()
emit(
    "step",
    step="held",
    broken={n: b.broken(now) for n, b in bonds.items()},
    gaps={n: b.largest_gap() for n, b in bonds.items()},
)
# The docking server deactivated: the manager erases its bond; the node answers that its side is over.
ok = change("docking_server", Transition.TRANSITION_DEACTIVATE)
bonds["docking_server"].end()
ended = wait(lambda: any(not active for _, active, _ in bonds["docking_server"].heard), 3.0)
emit("step", step="deactivate", ok=ok, state=state_of("docking_server"), node_said_dead=ended)
emit("step", step="goal after deactivate", accepted=dock_goal_accepted())
ok = change("docking_server", Transition.TRANSITION_ACTIVATE)
again = ManagerBond("docking_server")
formed = wait(lambda: again.formed_after() is not None, BOND_TIMEOUT / 2)
ours = {bonds["docking_server"].instance, again.instance}
instances = ({i for _, _, i in bonds["docking_server"].heard} | {i for _, _, i in again.heard}) - ours
emit("step", step="reactivate", ok=ok, state=state_of("docking_server"), formed=formed, instances=len(instances))
# The node dies outright: the manager's bond breaks on its heartbeat time-out (checkBondConnections, every 200 ms).
dock.kill()
killed = time.monotonic()
broke = wait(lambda: again.broken(time.monotonic()), BOND_TIMEOUT + 2.0)
emit("step", step="killed", broken=broke, after=time.monotonic() - killed)
stop_nodes(detector)
_, detector_err = detector.communicate()
_, dock_err = dock.communicate()
emit("end", detector=detector.returncode, detector_stderr=detector_err[-3000:], dock_stderr=dock_err[-3000:])
spinner.stop()
rclpy.shutdown()
