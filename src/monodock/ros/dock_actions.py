"""Nav2's docking interface on ``monodock_dock``: the ``dock_robot`` and ``undock_robot`` action servers
(``nav2_msgs/action/DockRobot``, ``UndockRobot``) and ``~/reload_database``, with the semantics of Nav2's own docking
server, so that a stock Nav2 stack and its behaviour trees use monodock unchanged.

The reference is ``opennav_docking``'s ``docking_server.cpp`` (and its ``navigator.cpp``, ``dock_database.cpp``) and
``nav2_util``'s ``simple_action_server.hpp`` on Nav2's ``kilted`` branch (commit 71a1d84f); the line numbers below
are ``docking_server.cpp``'s unless another file is named.

- **Goals** (``dockRobot``, 218-402). ``use_dock_id`` with any dock of the database (``DockNotInDB`` 901 otherwise;
  ``DockNotValid`` 902 when its type has no plugin), or a ``dock_pose`` with a ``dock_type`` (902 when no type fits).
  A robot already docked (charging, the contact closed, or within ``docking_threshold`` of where it docked) succeeds
  at once without moving (258-263). ``navigate_to_staging_pose`` sends the robot to the staging pose through Nav2's
  ``navigate_to_pose`` (``monodock.ros.navigator``) within ``max_staging_time``, unless it stands within
  ``dock_prestaging_tolerance`` of it (267-284); with no navigation server (the simulator alone) or a dock with no
  pose, monodock's own mission approaches from where the robot stands, and says so once in the log. Then monodock's
  mission docks: perception, the approach and the wait for the charge, its own retries (``num_retries``);
  ``max_staging_time`` bounds its far approach, which is its own way to the staging point. A failure ends with its
  Nav2 code (``FailureReason.nav2_error_code``; Nav2's time-outs are 905, never 907).
- **Cancel** is looked at before the goal starts (233-236) and at every control step of every phase, staging included
  (its ``isPreempted``, 275-278): the mission stops with zero velocity, the goal ends CANCELED.
- **Preemption**, as ``SimpleActionServer``: a new goal on a server that runs one waits in the single pending slot (a
  newer one replaces it, which ends aborted; ``simple_action_server.hpp`` 202-219). Preempted while navigating to the
  staging pose, the running goal ends ``FAILED_TO_STAGE`` (``navigator.cpp`` 76-79) and the new one runs; preempted
  later, both the running and the new goal end aborted (``terminate_all``, 335-340 and 350-355: Nav2's docking server
  does not go on to the new goal). A new goal that arrives before the running one has started replaces it
  (``getPreemptedGoalIfRequested``, 238).
- **Dock and undock exclude each other**: one lock held for a whole goal (``std::lock_guard``, 220 and 653); a goal on
  the other server waits for it, and ``reload_database`` is refused meanwhile (``dock_database.cpp``'s ``reloadDbCb``,
  85-95).
- **Undock** (``undockRobot``, 651-799): the dock type is the goal's, else the one the robot docked at, else the only
  one (902 "No dock information to undock from!" otherwise); a robot that is not docked ends the goal at once without
  a result state of its own, which the server makes ABORTED with a default result (689-693;
  ``simple_action_server.hpp`` 266-270); ``max_undocking_time`` ends it ``FAILED_TO_CONTROL`` "Undocking timed out"
  (722-726), and so does a robot that still charges at the staging pose ("Failed to control off dock", 768).
- **Feedback** (DockRobot only): the mission's state as Nav2's (``feedback_state``), ``docking_time`` on the node's
  ROS clock since the goal began, and the retries; on every change of state and at most every ``FEEDBACK_PERIOD``.

The servers live on a small node of their own (``<node>_actions``, in the docking node's namespace) spun by
a multi-threaded executor in a thread of its own: a goal's execution blocks one of its threads for the whole
mission, while its other threads take cancel requests, new goals and navigate_to_pose's answers, and the docking
node's single-threaded executor keeps serving odometry and images.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from monodock.core.pose2d import Pose2D
from monodock.dock.controller import DockingMission
from monodock.dock.database import DockInstance, DockType, load_dock_file, pose_distance, staging_pose
from monodock.dock.nav2 import (
    UNDOCK_CODES,
    DockingError,
    DockNotValid,
    FailedToControl,
    FeedbackState,
    Nav2Code,
    docking_error,
)
from monodock.dock.run import MissionResult
from monodock.dock.states import FailureReason, State, feedback_state
from monodock.errors import MonodockError
from monodock.ros.navigator import Navigator

if TYPE_CHECKING:
    from monodock.ros.dock_node import DockNode

__all__ = ["DOCK_ACTION", "FEEDBACK_PERIOD", "UNDOCK_ACTION", "DockActions"]

DOCK_ACTION = "dock_robot"
UNDOCK_ACTION = "undock_robot"
FEEDBACK_PERIOD = 0.2  # s (ROS time) between two feedback messages of the same state


def mission_error(result: MissionResult, task: str) -> DockingError:
    """The docking exception a failed mission ends its goal with (UndockRobot's codes for an undock)."""
    assert result.failure is not None
    code = result.failure.nav2_error_code
    if task == "undock" and code not in UNDOCK_CODES:
        code = Nav2Code.UNKNOWN
    return docking_error(code, f"{result.failure}: {result.reason}")


class _GoalSlots:
    """One action server's goals as Nav2's ``SimpleActionServer`` keeps them: the one executing and one pending."""

    def __init__(self, result_type: Any) -> None:
        self.result_type = result_type
        self.lock = threading.RLock()
        self.current: Any = None
        self.pending: Any = None
        self.preempt = False
        self.running = False

    def accepted(self, handle: Any) -> None:
        """``handle_accepted``: execute now, or wait in the pending slot (its earlier occupant ends aborted)."""
        with self.lock:
            if self.running:
                if self.pending is not None:
                    _end_pending(self.pending, self.result_type())
                self.pending, self.preempt = handle, True
                return
            self.current, self.running = handle, True
        handle.execute()

    def finished(self) -> None:
        """After an execution: the pending goal executes next (``work``'s loop), else the server idles."""
        with self.lock:
            nxt = self.pending if self.pending is not None and self.pending.is_active else None
            self.current, self.pending, self.preempt = nxt, None, False
            self.running = nxt is not None
        if nxt is not None:
            nxt.execute()

    def cancel_requested(self) -> bool:
        """``is_cancel_requested``: the pending goal's when there is one, else the running one's."""
        with self.lock:
            handle = self.pending if self.pending is not None else self.current
            return handle is not None and handle.is_cancel_requested

    def preempt_requested(self) -> bool:
        with self.lock:
            return self.preempt

    def stop_reason(self, action: str) -> tuple[FailureReason, str] | None:
        """Why a running mission must stop for its goal (``checkAndWarnIfCancelled``/``IfPreempted``), or None."""
        if self.cancel_requested():
            return FailureReason.CANCELLED, f"Goal was cancelled. Cancelling {action} action"
        if self.preempt_requested():
            return FailureReason.CANCELLED, f"Goal was preempted. Cancelling {action} action"
        return None

    def terminate_all(self, handle: Any, result: Any) -> None:
        """``terminate_all``: the running goal and the pending one end (CANCELED when cancel was asked, else
        ABORTED)."""
        with self.lock:
            pending, self.pending, self.preempt = self.pending, None, False
        _settle(handle)
        if pending is not None:
            _end_pending(pending, result)


def _settle(handle: Any) -> None:
    """``terminate``: a goal still active ends CANCELED when its client asked, else ABORTED."""
    if handle.is_active:
        (handle.canceled if handle.is_cancel_requested else handle.abort)()


def _end_pending(handle: Any, result: Any) -> None:
    """End a goal that never executed: rclpy sends a goal's result when its execution returns."""

    def end(h: Any) -> Any:
        _settle(h)
        return result

    handle.execute(end)


class DockActions:
    """The docking node's Nav2 action servers and ``~/reload_database``: goals in, the node's missions run, results
    out."""

    def __init__(self, node: DockNode) -> None:
        from nav2_msgs.action import DockRobot, UndockRobot  # type: ignore[import-not-found, unused-ignore]
        from rclpy.action import (  # type: ignore[attr-defined, import-not-found, unused-ignore]
            ActionServer,
            CancelResponse,
            GoalResponse,
        )
        from rclpy.callback_groups import ReentrantCallbackGroup  # type: ignore[import-not-found, unused-ignore]
        from rclpy.executors import MultiThreadedExecutor  # type: ignore[import-not-found, unused-ignore]
        from rclpy.node import Node  # type: ignore[import-not-found, unused-ignore]

        self.node = node
        self._types = {"dock": DockRobot, "undock": UndockRobot}
        self._responses = (GoalResponse, CancelResponse)
        self.slots = {"dock": _GoalSlots(DockRobot.Result), "undock": _GoalSlots(UndockRobot.Result)}
        self.mutex = threading.Lock()  # docking_server.cpp's mutex_: one goal of either kind at a time
        self._serving = threading.Event()
        self._serving.set()
        self._said: set[str] = set()
        self._feedback_at = (-math.inf, -1)  # (ROS time, state) of the last feedback
        self._goal_start = 0.0
        # Its own name beside the docking node's (no global arguments: a ``-r __node:=docking_server`` would name
        # it docking_server too), in the docking node's namespace, as the docking server's actions are.
        self.actions_node = Node(
            f"{node.get_name()}_actions",
            namespace=node.get_namespace(),
            context=node.context,
            start_parameter_services=False,
            use_global_arguments=False,
        )
        group = ReentrantCallbackGroup()
        self.servers = [
            ActionServer(
                self.actions_node,
                self._types[task],
                name,
                execute,
                goal_callback=self._on_goal,
                handle_accepted_callback=self.slots[task].accepted,
                cancel_callback=self._on_cancel,
                callback_group=group,
            )
            for task, name, execute in (
                ("dock", DOCK_ACTION, self._execute_dock),
                ("undock", UNDOCK_ACTION, self._execute_undock),
            )
        ]
        self.navigator = Navigator(self.actions_node, node.now, node.options.navigator_bt_xml, group)
        self._reload = self._reload_service()
        # Threads: a dock goal's mission, an undock goal waiting for it, navigate_to_pose's answers, cancels, goals.
        self._executor = MultiThreadedExecutor(num_threads=6, context=node.context)
        self._executor.add_node(self.actions_node)
        self._thread = threading.Thread(target=self._spin, name="monodock-actions", daemon=True)
        self._thread.start()

    def _reload_service(self) -> Any:
        try:
            from nav2_msgs.srv import ReloadDockDatabase  # type: ignore[import-not-found, unused-ignore]
        except ImportError:
            return None
        return self.node.create_service(ReloadDockDatabase, "~/reload_database", self._on_reload)

    def _spin(self) -> None:
        """Serve the actions until ``shutdown``: its own loop, so that it ends before the executor is shut down (rclpy's
        ``Executor.shutdown`` destroys the wait's guard condition at once, under a thread still waiting on it)."""
        from rclpy.executors import ExternalShutdownException  # type: ignore[import-not-found, unused-ignore]

        with contextlib.suppress(ExternalShutdownException):
            while self._serving.is_set() and self.node.context.ok():
                self._executor.spin_once(timeout_sec=0.1)

    def stop_serving(self) -> None:
        """Refuse new goals (the node is going away); a running goal ends when its mission is cancelled."""
        self._accepting = False

    def shutdown(self) -> None:
        """Stop serving: the spin loop, then the executor (its goals' threads joined), then the servers and their
        node."""
        self._serving.clear()
        self._thread.join(timeout=5.0)
        self._executor.shutdown(timeout_sec=5.0)
        for server in self.servers:
            server.destroy()
        self.actions_node.destroy_node()

    # --- requests ---------------------------------------------------------------------------

    _accepting = True

    def _on_goal(self, _goal: Any) -> Any:
        """``handle_goal``: an inactive server rejects every goal."""
        goal_response = self._responses[0]
        if not (self.node.active and self._accepting):
            self.node.get_logger().info("Action server is inactive. Rejecting the goal.")
            return goal_response.REJECT
        return goal_response.ACCEPT

    def _on_cancel(self, handle: Any) -> Any:
        """``handle_cancel``: accepted while the goal is active; its execution sees it at its next control step."""
        cancel_response = self._responses[1]
        return cancel_response.ACCEPT if handle.is_active else cancel_response.REJECT

    def _on_reload(self, request: Any, response: Any) -> Any:
        """``reloadDbCb``: new dock instances from a file, refused while a goal runs."""
        if not self.mutex.acquire(blocking=False):
            self.node.get_logger().error("Cannot reload database while docking!")
            response.success = False
            return response
        try:
            self.node.database.replace_docks(load_dock_file(request.filepath))
        except MonodockError as exc:
            self.node.get_logger().error(f"dock database not reloaded: {exc}")
            response.success = False
        else:
            self.node.get_logger().info(f"Dock database reloaded from file {request.filepath}.")
            response.success = True
        finally:
            self.mutex.release()
        return response

    # --- a goal of either action -------------------------------------------------------------

    def _execute(
        self, task: str, handle: Any, run: Callable[[Any, Any], Any], before: Callable[[], None] | None = None
    ) -> Any:
        """One goal of ``task``'s server, start to end, in one of the actions' executor threads, under the lock that
        keeps the other server's goals out: ``before()``, the server's checks (inactive, cancelled, preempted), then
        ``run(handle, result)``, which returns the result; a DockingError it raises ends the goal with its code (any
        other monodock error with UNKNOWN). Then the pending goal, if any, executes."""
        slots, Result = self.slots[task], self._types[task].Result
        try:
            result = Result()
            result.success = False
            with self.mutex:
                if before is not None:
                    before()
                if not self.node.active:
                    return result
                if slots.cancel_requested():
                    slots.terminate_all(handle, result)
                    return result
                if slots.preempt_requested():  # a newer goal came before this one started: it runs instead
                    handle.abort()
                    return Result()
                try:
                    return run(handle, result)
                except DockingError as exc:
                    result.error_code, result.error_msg = int(exc.code), str(exc)
                except MonodockError as exc:
                    result.error_code, result.error_msg = int(Nav2Code.UNKNOWN), str(exc)
                self.node.get_logger().error(result.error_msg)
                _settle(handle)  # terminate_current
                return result
        finally:
            slots.finished()

    # --- DockRobot --------------------------------------------------------------------------

    def _execute_dock(self, handle: Any) -> Any:
        return self._execute("dock", handle, self._dock, self._start_feedback)

    def _start_feedback(self) -> None:
        """A dock goal's ``docking_time`` runs from here, and its first feedback is sent whatever its state."""
        self._goal_start = self._clock_now()
        self._feedback_at = (-math.inf, -1)

    def _dock(self, handle: Any, result: Any) -> Any:
        """``dockRobot``: the goal's dock, staging, and the mission (its retries in the result as they happen)."""
        goal = handle.request
        dock, dock_type = self._find_dock(goal)
        if self.node.is_docked(dock_type):
            self.node.get_logger().info("Robot is already docked and/or charging (if applicable), no need to dock")
            result.success = True
            handle.succeed()
            return result
        self._feedback(handle, FeedbackState.NAV_TO_STAGING_POSE, 0)
        self._stage(goal, dock, dock_type)
        mission = self.node.run_mission(
            "dock",
            dock_type,
            dock.layout,
            stop_check=self._dock_stop_check(goal),
            on_tick=lambda ms: self._on_dock_tick(handle, ms, result),
        )
        result.num_retries = mission.retries
        if mission.succeeded:
            self.node.get_logger().info("Robot is charging!" if mission.charging else "Docking was successful!")
            result.success = True
            handle.succeed()
            return result
        if mission.failure is FailureReason.CANCELLED:  # cancelled, preempted, or shutting down
            self.slots["dock"].terminate_all(handle, result)
            return result
        raise mission_error(mission, "dock")

    def _find_dock(self, goal: Any) -> tuple[DockInstance, DockType]:
        """The goal's dock: by id from the database, or at the goal's pose (234-247)."""
        log = self.node.get_logger()
        if goal.use_dock_id:
            log.info(f"Attempting to dock robot at {goal.dock_id}.")
            return self.node.database.find_dock(goal.dock_id)
        p, q = goal.dock_pose.pose.position, goal.dock_pose.pose.orientation
        log.info(f"Attempting to dock robot at position ({p.x:0.2f}, {p.y:0.2f}).")
        theta = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        return self.node.database.pose_goal(goal.dock_pose.header.frame_id, Pose2D(p.x, p.y, theta), goal.dock_type)

    def _stage(self, goal: Any, dock: DockInstance, dock_type: DockType) -> None:
        """Send the robot to the dock's staging pose through navigate_to_pose, where that makes sense (258-276).

        Raises:
            FailedToStage: as ``Navigator.go_to_pose``.
            DockingError: no transform to the dock's frame (UNKNOWN, as upstream's TransformException).
        """
        log = self.node.get_logger()
        if dock.pose is None:
            if goal.navigate_to_staging_pose:
                self._say_once(
                    f"pose:{dock.name}",
                    f"dock '{dock.name}' has no pose in the dock database, so no staging pose to navigate to: "
                    "approaching it from where the robot stands",
                )
            return
        staging = staging_pose(dock.pose, dock_type)
        self.node.publish_staging_pose(dock.frame, staging)
        if not goal.navigate_to_staging_pose:
            log.info("Robot already within pre-staging pose tolerance for dock")
            return
        if not self.navigator.available(1.0):
            self._say_once(
                "navigator",
                "no navigate_to_pose action server (Nav2's navigation is not running): approaching the dock from "
                "where the robot stands, without the staging pose",
            )
            return
        here = self.node.tf.pose(dock.frame, self.node.options.frame_id)
        if here is None:
            raise DockingError(f"Transform error: no transform from {dock.frame} to {self.node.options.frame_id}")
        if pose_distance(Pose2D(*here), staging) < self.node.options.dock_prestaging_tolerance:
            log.info("Robot already within pre-staging pose tolerance for dock")
            return
        slots = self.slots["dock"]
        self.navigator.go_to_pose(
            dock.frame,
            staging,
            float(goal.max_staging_time),
            lambda: slots.cancel_requested() or slots.preempt_requested(),
        )
        log.info("Successful navigation to staging pose")

    def _dock_stop_check(self, goal: Any) -> Any:
        """Why the dock mission must stop: a cancel, a preempting goal, or its far approach over max_staging_time."""
        slots = self.slots["dock"]
        staging = [0.0, math.nan]  # seconds on the far approach so far, the last step's time
        budget = float(goal.max_staging_time)

        def check(mission: DockingMission) -> tuple[FailureReason, str] | None:
            stop = slots.stop_reason(DOCK_ACTION)
            if stop is not None:
                return stop
            now = self.node.now()
            if mission.state is State.FAR_APPROACH and not math.isnan(staging[1]):
                staging[0] += now - staging[1]
            staging[1] = now
            if staging[0] > budget:
                return FailureReason.STAGING_TIMEOUT, (
                    f"the far approach to the staging point took over max_staging_time ({budget:g} s)"
                )
            return None

        return check

    def _on_dock_tick(self, handle: Any, mission: DockingMission, result: Any) -> None:
        result.num_retries = mission.retries  # a mission that fails by raising has counted its retries so far
        if not mission.finished:  # the result says how it ended
            self._feedback(handle, feedback_state(mission.state), mission.retries)

    def _feedback(self, handle: Any, state: int, retries: int) -> None:
        """``publishDockingFeedback``, on every change of state and at most every ``FEEDBACK_PERIOD`` between."""
        now = self.node.now()
        last_at, last_state = self._feedback_at
        if state == last_state and now - last_at < FEEDBACK_PERIOD:
            return
        self._feedback_at = (now, int(state))
        msg = self._types["dock"].Feedback()
        msg.state = int(state)
        elapsed = max(0.0, now - self._goal_start)
        msg.docking_time.sec = int(elapsed)
        msg.docking_time.nanosec = int((elapsed - int(elapsed)) * 1e9)
        msg.num_retries = retries
        handle.publish_feedback(msg)

    # --- UndockRobot ------------------------------------------------------------------------

    def _execute_undock(self, handle: Any) -> Any:
        return self._execute("undock", handle, self._undock)

    def _undock(self, handle: Any, result: Any) -> Any:
        """``undockRobot``: the dock type to leave, and the undock mission within ``max_undocking_time``."""
        slots, goal, log = self.slots["undock"], handle.request, self.node.get_logger()
        docked = self.node.docked_type.name if self.node.docked_type is not None else ""
        dock_type = self.node.database.find_type(goal.dock_type or docked)
        if dock_type is None:
            raise DockNotValid("No dock information to undock from!")
        log.info(f"Attempting to undock robot of dock type {dock_type.name}.")
        if not self.node.is_docked(dock_type):
            log.info("Robot is not in the dock, no need to undock")
            return self._types["undock"].Result()  # no result state: the server ends it ABORTED with a default result
        start, budget = self._clock_now(), float(goal.max_undocking_time)

        def check(_mission: DockingMission) -> tuple[FailureReason, str] | None:
            stop = slots.stop_reason(UNDOCK_ACTION)
            if stop is None and self.node.now() - start > budget:
                return FailureReason.TIMEOUT, "Undocking timed out"
            return stop

        mission = self.node.run_mission("undock", dock_type, stop_check=check)
        if mission.failure is FailureReason.CANCELLED:
            slots.terminate_all(handle, result)
            return result
        if mission.failure is FailureReason.TIMEOUT and mission.reason == "Undocking timed out":
            raise FailedToControl("Undocking timed out")
        if not mission.succeeded:
            raise mission_error(mission, "undock")
        log.info("Robot has reached staging pose")
        if self.node.dock_for(dock_type).is_charging(self.node.robot):
            raise FailedToControl("Failed to control off dock")
        log.info("Robot has undocked!")
        result.success = True
        handle.succeed()
        return result

    def _clock_now(self, wait: float = 5.0) -> float:
        """The node's clock, once it runs: under ``use_sim_time`` it reads 0 until the first /clock message, and a
        goal timed from 0 would report the epoch as its docking_time (and an undock would time out at once)."""
        end = time.monotonic() + wait
        while self.node.now() <= 0.0 and time.monotonic() < end:
            time.sleep(0.01)
        return self.node.now()

    def _say_once(self, key: str, text: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self.node.get_logger().info(text)
