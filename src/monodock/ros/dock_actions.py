"""Nav2's docking interface on ``monodock_dock``: ``nav2_msgs/action/DockRobot`` and ``UndockRobot`` servers.

Named ``dock_robot`` and ``undock_robot`` relative to the node's namespace, as Nav2's docking server names them, so a
Nav2 behaviour tree's DockRobot/UndockRobot nodes (or any action client written from the upstream definitions)
find them. The types come from the interfaces monodock builds at install time (interfaces/README.md); without
them the servers are off and the node says so once (the Trigger services stay: the no-Nav2 way in).

A goal runs the same mission as ``~/dock``/``~/undock``:

- **Goal fields.** monodock docks at the dock its camera sees, from where the robot stands. So ``use_dock_id``
  must be true with an empty ``dock_id`` or the node's own ``dock_id`` (else ``DOCK_NOT_IN_DB``, 901);
  ``dock_type`` must be empty or the node's ``dock_type`` (else ``DOCK_NOT_VALID``, 902); and
  ``navigate_to_staging_pose`` must be false, since there is no navigation stack to call (else ``FAILED_TO_STAGE``,
  903). ``max_staging_time`` is then unused, as in Nav2 without staging. Each refusal ends the goal aborted, with the
  code and the reason in words in ``error_msg``.
- **Feedback.** About 5 Hz while it runs: the mission's state as Nav2's (``INITIAL_PERCEPTION`` while looking for the
  dock and measuring it, ``NAV_TO_STAGING_POSE`` on the far approach to the staging point on the dock's axis,
  ``CONTROLLING`` on the way in, ``WAIT_FOR_CHARGE`` on the contacts, ``RETRY`` while
  backing off for another try), the time since the goal began, and the retries.
- **Cancel.** Stops the mission (zero velocity at once, as every exit does); the goal ends canceled. A new goal while
  one runs cancels the running one first (as a new ``~/dock`` does), then runs.
- **Result.** ``success``, the failure's Nav2 error code (``FailureReason.nav2_error_code``; an undock's reasons map
  to UndockRobot's own codes), the retries and the failure in words.

The servers live on a small node of their own (``monodock_dock_actions``, in the docking node's namespace) spun by
a multi-threaded executor in a thread of its own: a goal's execution waits for the mission there, and a cancel
request is served beside it, while the docking node's single-threaded executor keeps serving odometry and images
(an rclpy coroutine awaiting the mission would be polled on every spin of that executor instead).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from monodock.dock.controller import DockingMission, FailureReason, MissionResult, State
from monodock.errors import MonodockError

__all__ = ["DOCK_ACTION", "UNDOCK_ACTION", "DockActions", "FeedbackState", "feedback_state", "undock_error_code"]

DOCK_ACTION = "dock_robot"
UNDOCK_ACTION = "undock_robot"
FEEDBACK_PERIOD = 0.2  # s between two feedback messages

# DockRobot.Result and UndockRobot.Result's codes (interfaces/upstream/nav2_msgs/action/*.action).
NONE, DOCK_NOT_IN_DB, DOCK_NOT_VALID, FAILED_TO_STAGE = 0, 901, 902, 903
FAILED_TO_CONTROL, TIMEOUT, UNKNOWN = 905, 907, 999


class FeedbackState:
    """DockRobot.Feedback's states (the .action's constants)."""

    NONE = 0
    NAV_TO_STAGING_POSE = 1
    INITIAL_PERCEPTION = 2
    CONTROLLING = 3
    WAIT_FOR_CHARGE = 4
    RETRY = 5


_PERCEIVING = {State.ACQUIRE, State.CENTER, State.CALCULATE}
_RETRYING = {State.RECOVER, State.RESEAT, State.BACK_OFF}
_CHARGING = {State.SETTLE, State.CHARGE_WAIT, State.DOCKED}


def feedback_state(state: State) -> int:
    """The Nav2 feedback state of a mission state."""
    if state in _PERCEIVING:
        return FeedbackState.INITIAL_PERCEPTION
    if state is State.FAR_APPROACH:  # legs to the staging point on the dock's axis: Nav2's staging, on our own pose
        return FeedbackState.NAV_TO_STAGING_POSE
    if state in _RETRYING:
        return FeedbackState.RETRY
    if state in _CHARGING:
        return FeedbackState.WAIT_FOR_CHARGE
    return FeedbackState.CONTROLLING


def undock_error_code(failure: FailureReason | None) -> int:
    """UndockRobot.Result's code for an undock's failure (it has no codes for perception or charging)."""
    if failure is None or failure is FailureReason.CANCELLED:
        return NONE
    if failure is FailureReason.TIMEOUT:
        return TIMEOUT
    code = failure.nav2_error_code
    return FAILED_TO_CONTROL if code == FAILED_TO_CONTROL else UNKNOWN


@dataclass
class _Goal:
    """The goal being executed: its handle, its task, when it began, and how its mission ended."""

    handle: Any
    task: str
    started: float
    done: threading.Event
    outcome: tuple[MissionResult | None, str] = (None, "")
    last_feedback: float = -math.inf
    last_state: int | None = None

    def end(self, result: MissionResult | None, error: str) -> None:
        """Called by the mission thread when the mission is over."""
        self.outcome = (result, error)
        self.done.set()


class DockActions:
    """The two action servers of a docking node (``DockNode``): goals in, missions run by the node, results out.

    The node provides ``start_mission(task, on_done) -> None`` (raises ``MonodockError`` with the reason it cannot),
    ``cancel_mission(why) -> bool`` and its parameters ``dock_id`` and ``dock_type``.
    """

    def __init__(self, node: Any, start: Callable[..., None], cancel: Callable[[str], bool]) -> None:
        from nav2_msgs.action import DockRobot, UndockRobot  # type: ignore[import-not-found, unused-ignore]
        from rclpy.action import ActionServer, CancelResponse  # type: ignore[attr-defined, import-not-found, unused-ignore]
        from rclpy.callback_groups import ReentrantCallbackGroup  # type: ignore[import-not-found, unused-ignore]
        from rclpy.executors import MultiThreadedExecutor  # type: ignore[import-not-found, unused-ignore]
        from rclpy.node import Node  # type: ignore[import-not-found, unused-ignore]

        self.node, self._start, self._cancel = node, start, cancel
        self._types = {"dock": DockRobot, "undock": UndockRobot}
        self._cancel_accept = CancelResponse.ACCEPT
        self._lock = threading.Lock()
        self._goal: _Goal | None = None
        self.actions_node = Node(
            "monodock_dock_actions",
            namespace=node.get_namespace(),
            context=node.context,
            start_parameter_services=False,
        )
        group = ReentrantCallbackGroup()
        self.servers = [
            ActionServer(
                self.actions_node, action, name, execute, cancel_callback=self._on_cancel, callback_group=group
            )
            for action, name, execute in (
                (DockRobot, DOCK_ACTION, self._execute_dock),
                (UndockRobot, UNDOCK_ACTION, self._execute_undock),
            )
        ]
        self._executor = MultiThreadedExecutor(num_threads=3, context=node.context)
        self._executor.add_node(self.actions_node)
        self._serving = threading.Event()
        self._serving.set()
        self._thread = threading.Thread(target=self._spin, name="monodock-actions", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        """Serve the actions until ``shutdown``: its own loop, so that it ends before the executor is shut down (rclpy's
        ``Executor.shutdown`` destroys the wait's guard condition at once, under a thread still waiting on it)."""
        from rclpy.executors import ExternalShutdownException  # type: ignore[import-not-found, unused-ignore]

        with contextlib.suppress(ExternalShutdownException):
            while self._serving.is_set() and self.node.context.ok():
                self._executor.spin_once(timeout_sec=0.1)

    def shutdown(self) -> None:
        """Stop serving (the node is going away): the spin loop, then the executor (its goals' threads joined), then
        the servers and their node."""
        self._serving.clear()
        self._thread.join(timeout=5.0)
        self._executor.shutdown(timeout_sec=5.0)
        for server in self.servers:
            server.destroy()
        self.actions_node.destroy_node()

    # --- goals ------------------------------------------------------------------------------

    def refusal(self, goal: Any) -> tuple[int, str] | None:
        """Why a DockRobot goal cannot be served, as (code, words), or None."""
        dock_id = str(self.node.get_parameter("dock_id").value)
        dock_type = str(self.node.get_parameter("dock_type").value)
        if not goal.use_dock_id:
            return DOCK_NOT_IN_DB, (
                "monodock docks at the dock its camera sees, not at a pose: send use_dock_id: true "
                f"(dock_id empty or '{dock_id}')"
            )
        if goal.dock_id and goal.dock_id != dock_id:
            return DOCK_NOT_IN_DB, f"dock '{goal.dock_id}' is not this node's: its dock is '{dock_id}' (or empty)"
        if goal.dock_type and goal.dock_type != dock_type:
            return DOCK_NOT_VALID, f"dock_type '{goal.dock_type}' is not this node's ('{dock_type}', or empty)"
        if goal.navigate_to_staging_pose:
            return FAILED_TO_STAGE, (
                "navigate_to_staging_pose: true needs a navigation stack, which monodock_dock does not call: send "
                "false with the dock in the camera's view (the mission finds and approaches it from there)"
            )
        return None

    def _execute_dock(self, handle: Any) -> Any:
        return self._execute(handle, "dock")

    def _execute_undock(self, handle: Any) -> Any:
        return self._execute(handle, "undock")

    def _execute(self, handle: Any, task: str) -> Any:
        """One goal, start to end, in one of the actions' executor threads."""
        refused = self._refusal(handle.request, task)
        if refused is not None:
            handle.abort()
            return self._result(task, False, *refused)
        with self._lock:
            previous = self._goal
        if previous is not None and self._cancel(f"cancelled by a new {task} goal"):
            previous.done.wait(10.0)  # the running mission ends (zero velocity) before this one starts
        goal = _Goal(handle, task, time.monotonic(), threading.Event())
        with self._lock:
            self._goal = goal
        try:
            self._start(task, goal.end)
        except MonodockError as exc:
            with self._lock:
                self._goal = None
            handle.abort()
            return self._result(task, False, DOCK_NOT_VALID if task == "undock" else UNKNOWN, str(exc))
        goal.done.wait()
        with self._lock:
            if self._goal is goal:
                self._goal = None
        return self._finish(handle, task, *goal.outcome)

    def _refusal(self, request: Any, task: str) -> tuple[int, str] | None:
        if task == "dock":
            return self.refusal(request)
        dock_type = str(self.node.get_parameter("dock_type").value)
        if request.dock_type and request.dock_type != dock_type:
            return DOCK_NOT_VALID, f"dock_type '{request.dock_type}' is not this node's ('{dock_type}', or empty)"
        return None

    def _finish(self, handle: Any, task: str, result: MissionResult | None, error: str) -> Any:
        if result is not None and result.succeeded:
            handle.succeed()
            return self._result(task, True, NONE, "", result.retries)
        failure = result.failure if result is not None else None
        if failure is FailureReason.CANCELLED and handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
        if result is None:
            return self._result(task, False, UNKNOWN, error)
        code = failure.nav2_error_code if (failure and task == "dock") else undock_error_code(failure)
        words = f"{failure}: {result.reason}" if failure else result.state.value
        return self._result(task, False, code, words, result.retries)

    def _result(self, task: str, success: bool, code: int, words: str, retries: int = 0) -> Any:
        out = self._types[task].Result()
        out.success, out.error_code, out.error_msg = success, code, words
        if task == "dock":
            out.num_retries = retries
        return out

    def _on_cancel(self, handle: Any) -> Any:
        with self._lock:
            goal = self._goal
        if goal is not None and goal.handle is handle:
            self._cancel("cancelled by the action client")
        return self._cancel_accept

    # --- feedback, from the mission thread --------------------------------------------------

    def feedback(self, mission: DockingMission) -> None:
        """Publish the running dock goal's feedback on every change of state, and at most every ``FEEDBACK_PERIOD``
        between (UndockRobot has none): a short state (a charge that comes at once) is still reported."""
        with self._lock:
            goal = self._goal
        if goal is None or goal.task != "dock":
            return
        now, state = time.monotonic(), feedback_state(mission.state)
        if now - goal.last_feedback < FEEDBACK_PERIOD and state == goal.last_state:
            return
        goal.last_feedback, goal.last_state = now, state
        msg = self._types["dock"].Feedback()
        msg.state = state
        elapsed = now - goal.started
        msg.docking_time.sec = int(elapsed)
        msg.docking_time.nanosec = int((elapsed - int(elapsed)) * 1e9)
        msg.num_retries = mission.retries
        goal.handle.publish_feedback(msg)
