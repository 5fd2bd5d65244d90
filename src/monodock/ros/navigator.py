"""Sending the robot to a dock's staging pose through Nav2's ``navigate_to_pose`` action, as opennav_docking's
``Navigator`` does (``navigator.cpp``, Kilted): one goal (the staging pose, ``navigator_bt_xml`` as its behaviour
tree), cancelled when the docking goal is cancelled or preempted or when ``max_staging_time`` runs out, and tried once
more when navigation fails; every way it does not get there is ``FailedToStage`` (903).

The client lives on a node spun by a multi-threaded executor: ``go_to_pose`` blocks its caller (a docking goal's
thread) while the executor's other threads take the action's responses.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from monodock.core.pose2d import Pose2D
from monodock.dock.nav2 import FailedToStage
from monodock.recording.messages import split_stamp

__all__ = ["NAVIGATE_TO_POSE", "Navigator"]

NAVIGATE_TO_POSE = "navigate_to_pose"
ACCEPT_TIMEOUT = 2.0  # s for the goal's acceptance (navigator.cpp: spin_until_future_complete(..., 2s))
POLL = 0.01  # s between looks at the result (navigator.cpp: 10 ms)
STATUS_SUCCEEDED = 4  # action_msgs/msg/GoalStatus


class Navigator:
    """A ``nav2_msgs/action/NavigateToPose`` client on ``node``; ``now`` is the docking node's clock, in seconds."""

    def __init__(
        self, node: Any, now: Callable[[], float], behavior_tree: str = "", callback_group: Any = None
    ) -> None:
        from nav2_msgs.action import NavigateToPose  # type: ignore[import-not-found, unused-ignore]
        from rclpy.action import ActionClient  # type: ignore[attr-defined, import-not-found, unused-ignore]

        self._action = NavigateToPose
        self._client: Any = ActionClient(node, NavigateToPose, NAVIGATE_TO_POSE, callback_group=callback_group)
        self.now, self.behavior_tree = now, behavior_tree
        self._missing = False  # the last look found no server

    def available(self, timeout: float = 1.0) -> bool:
        """Whether a navigate_to_pose server answers (navigator.cpp waits 1 s for one). Once one was looked for in
        vain, later goals look only briefly (a server that comes up later is seen by discovery meanwhile)."""
        if self._client.server_is_ready():
            return True
        found = bool(self._client.wait_for_server(timeout_sec=0.1 if self._missing else timeout))
        self._missing = not found
        return found

    def go_to_pose(
        self, frame: str, pose: Pose2D, budget: float, preempted: Callable[[], bool], *, retried: bool = False
    ) -> None:
        """Drive to ``pose`` in ``frame`` within ``budget`` seconds (ROS time).

        Raises:
            FailedToStage: preempted or cancelled, out of time, or navigation failed twice.
        """
        if preempted():  # a cancel that came first: no navigation starts (upstream sends the goal, then looks)
            raise FailedToStage("Navigation request to staging pose preempted.")
        start = self.now()
        goal = self._action.Goal()
        goal.pose.header.frame_id = frame
        goal.pose.header.stamp.sec, goal.pose.header.stamp.nanosec = split_stamp(start)
        goal.pose.pose.position.x, goal.pose.pose.position.y = pose.x, pose.y
        goal.pose.pose.orientation.z = math.sin(0.5 * pose.theta)
        goal.pose.pose.orientation.w = math.cos(0.5 * pose.theta)
        goal.behavior_tree = self.behavior_tree
        sent: Any = self._client.send_goal_async(goal)
        if _wait(sent.done, ACCEPT_TIMEOUT) and sent.result() is not None and sent.result().accepted:
            handle = sent.result()
            result: Any = handle.get_result_async()
            while True:
                if preempted():
                    self._cancel(handle)
                    raise FailedToStage("Navigation request to staging pose preempted.")
                if self.now() - start > budget:
                    self._cancel(handle)
                    raise FailedToStage("Navigation request to staging pose timed out.")
                if result.done():
                    wrapped = result.result()
                    if wrapped.status == STATUS_SUCCEEDED and wrapped.result.error_code == 0:
                        return
                    break  # "Navigation request to staging pose failed." (a warning, then one more try)
                time.sleep(POLL)
        if not retried:
            self.go_to_pose(frame, pose, budget - (self.now() - start), preempted, retried=True)
            return
        raise FailedToStage("Navigation request to staging pose failed.")

    def _cancel(self, handle: Any) -> None:
        _wait(handle.cancel_goal_async().done, 1.0)


def _wait(done: Callable[[], bool], seconds: float) -> bool:
    end = time.monotonic() + seconds
    while not done() and time.monotonic() < end:
        time.sleep(POLL)
    return bool(done())
