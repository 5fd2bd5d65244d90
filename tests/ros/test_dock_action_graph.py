"""Nav2's docking actions over a real ROS 2 graph: monodock_dock's DockRobot and UndockRobot servers, called by an
action client written from the upstream nav2_msgs definitions, over Fast DDS (private network namespace).

The robot's true final pose comes from the sim's ground truth and its charging from the sim's battery, never from
the node under test. Tolerances are dock-sim's (``DockingConfig``: 2 cm lateral and gap, 3.07° heading).
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from monodock.dock.controller import DockingConfig
from private_graph import can_isolate, run_private_graph

HERE = Path(__file__).parent
TOL = DockingConfig()
# DockRobot.Feedback's states (interfaces/upstream/nav2_msgs/action/DockRobot.action).
INITIAL_PERCEPTION, CONTROLLING, WAIT_FOR_CHARGE = 2, 3, 4

pytestmark = [
    pytest.mark.skipif(not can_isolate(), reason="no private network namespace on this machine"),
    pytest.mark.skipif(importlib.util.find_spec("rclpy") is None, reason="ROS 2 (rclpy) is not installed"),
    pytest.mark.skipif(importlib.util.find_spec("nav2_msgs") is None, reason="nav2_msgs was not built here"),
]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_nav2_client_docks_is_refused_in_words_undocks_and_cancels() -> None:
    goals = [
        {"action": "dock", "goal": {"use_dock_id": True, "dock_id": "", "navigate_to_staging_pose": False}},
        {"action": "dock", "goal": {"use_dock_id": True, "navigate_to_staging_pose": True}},  # Nav2's default
        {"action": "undock", "goal": {"dock_type": "monodock"}},
        {"action": "dock", "goal": {"navigate_to_staging_pose": False, "dock_id": "dock"}, "cancel_in": CONTROLLING},
        {
            "action": "dock",
            "goal": {"navigate_to_staging_pose": False},
            "preempt_in": CONTROLLING,
            "preempt_with": {"action": "dock", "goal": {"navigate_to_staging_pose": False}},
        },
    ]
    run = run_private_graph(
        HERE / "graph_dock_action.py", json.dumps({"start": [-1.2, 0.12, 0.15], "goals": goals}), timeout=540
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr, run.stderr[-3000:]
    assert run.first("ready")["ok"], run.stderr[-3000:]
    docked, staged, undocked, cancelled, preempted, preempting = [r for r in run.records if r["kind"] == "goal"]

    # Docked: succeeded, with Nav2's result fields, on the contacts by the sim's truth and charging.
    assert docked["succeeded"], docked
    assert docked["success"] is True
    assert docked["error_code"] == 0
    assert docked["error_msg"] == ""
    assert abs(docked["truth"]["lateral_cm"]) <= 100 * TOL.tolerance_lateral
    assert abs(docked["truth"]["gap_cm"]) <= 100 * TOL.tolerance_longitudinal
    assert abs(docked["truth"]["heading_deg"]) <= TOL.tolerance_heading_deg
    assert docked["charging"]
    # Feedback: perception first, then control, then waiting for the charge; the elapsed time grows with it.
    states = docked["feedback_states"]
    assert states[0] == INITIAL_PERCEPTION, states
    assert CONTROLLING in states, states
    assert states[-1] == WAIT_FOR_CHARGE, states
    assert docked["docking_time"] > 2.0

    # navigate_to_staging_pose: true (Nav2's default) needs a navigation stack: refused, in words, as FAILED_TO_STAGE.
    assert not staged["succeeded"], staged
    assert staged["error_code"] == 903, staged
    assert "navigation stack" in staged["error_msg"]
    assert staged["feedback_states"] == []

    # Undocked: off the contacts, no longer charging.
    assert undocked["succeeded"], undocked
    assert undocked["success"] is True
    assert undocked["truth"]["gap_cm"] > 10.0
    assert not undocked["charging"]

    # Cancelled while controlling: the goal ends CANCELED, short of the dock, not charging.
    assert cancelled["cancel_accepted"] is True, cancelled
    assert cancelled["canceled"], cancelled
    assert cancelled["success"] is False
    assert cancelled["truth"]["gap_cm"] > 2.0
    assert not cancelled["charging"]

    # A new goal while one runs (a behaviour tree's retry): the running goal ends aborted, saying why, once its
    # mission has stopped; the new one docks from where the robot was, on the contacts by the truth, charging.
    assert preempted["aborted"], preempted
    assert preempted["success"] is False
    assert "cancelled by a new dock goal" in preempted["error_msg"], preempted
    assert preempting["succeeded"], preempting
    assert abs(preempting["truth"]["lateral_cm"]) <= 100 * TOL.tolerance_lateral
    assert abs(preempting["truth"]["gap_cm"]) <= 100 * TOL.tolerance_longitudinal
    assert abs(preempting["truth"]["heading_deg"]) <= TOL.tolerance_heading_deg
    assert preempting["charging"]
    assert preempting["feedback_states"][0] == INITIAL_PERCEPTION
    end = run.first("end")
    assert end["dock"] == 0, (end, run.stderr[-3000:])
    assert end["sim"] == 0, (end, run.stderr[-3000:])
