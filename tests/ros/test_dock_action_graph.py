"""Nav2's docking actions over a real ROS 2 graph: monodock_dock's DockRobot and UndockRobot servers, called by an
action client written from the upstream nav2_msgs definitions that sends what Nav2's behaviour tree nodes send,
over Fast DDS (private network namespace).

The robot's true pose comes from the sim's ground truth and its charging from the sim's battery, never from the node
under test. Tolerances are the papers' (``DockingConfig``: 2 cm lateral and gap, 3.07° heading). What each outcome
should be is Nav2's docking server's (``opennav_docking/src/docking_server.cpp``, Kilted; monodock.ros.dock_actions
cites the lines).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig
from private_graph import needs_graph, run_private_graph

HERE = Path(__file__).parent
TOL = DockingConfig()
# DockRobot.Feedback's states (interfaces/upstream/nav2_msgs/action/DockRobot.action).
NAV_TO_STAGING_POSE, INITIAL_PERCEPTION, CONTROLLING, WAIT_FOR_CHARGE, RETRY = 1, 2, 3, 4, 5
BT_DEFAULT = {"action": "dock", "goal": {"dock_id": "home_dock", "navigate_to_staging_pose": True}}

pytestmark = needs_graph("nav2_msgs")


def _docked_by_truth(goal: dict[str, object]) -> None:
    truth = goal["truth"]
    assert isinstance(truth, dict)
    assert abs(truth["lateral_cm"]) <= 100 * TOL.retry.tolerance_lateral, goal
    assert abs(truth["gap_cm"]) <= 100 * TOL.retry.tolerance_longitudinal, goal
    assert abs(truth["heading_deg"]) <= TOL.retry.tolerance_heading_deg, goal
    assert goal["charging"], goal


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_nav2_s_default_goals_dock_stay_docked_and_undock() -> None:
    """The dock database from a file in Nav2's format, its dock with a layout of its own (the sim's charger carries
    markers 11-13, the node's own layout 1-3); Nav2's default goals; ~/reload_database; a cancel in RETRY."""
    start = [-1.2, 0.12, 0.15]
    front = RobotConfig.default().front_offset
    docked_pose = _in_odom(start, Pose2D(-front, 0.0, 0.0))
    database = (
        f"docks:\n  home_dock: {{type: monodock, frame: odom, pose: {docked_pose}, layout: '{{folder}}/lab.yaml'}}\n"
    )
    reloaded = database + f"  charger_7: {{type: stubborn, frame: odom, pose: {docked_pose}}}\n"
    params = [
        "dock_plugins:=[monodock, stubborn]",
        "dock_database:={folder}/docks.yaml",
        # A dock type whose charger never charges (no current reaches 100 A): the mission re-seats (RETRY).
        "stubborn.charging_threshold:=100.0",
        "stubborn.layout:={folder}/lab.yaml",
    ]
    goals = [
        BT_DEFAULT,  # exactly what Nav2's DockRobot BT node sends by default (its example's dock_id)
        BT_DEFAULT,  # again, while docked
        {"action": "undock", "goal": {}},  # UndockRobot's defaults: no dock_type, max_undocking_time 30 s
        {"action": "undock", "goal": {"dock_type": "monodock"}},  # not docked now
        {"action": "undock", "goal": {}},  # two dock types, none docked at, none named: nothing to undock from
        {"action": "dock", "goal": {"dock_id": "charger_7"}},
        {
            "action": "dock",
            "goal": {"use_dock_id": False, "dock_pose": [0.0, 0.0, 0.0, "odom"], "dock_type": "tag_dock"},
        },
        {"action": "reload", "file": "reloaded.yaml"},
        {"action": "dock", "goal": {"dock_id": "charger_7", "navigate_to_staging_pose": False}, "cancel_in": RETRY},
    ]
    spec = {
        "start": start,
        "sim_layout": "lab",
        "files": {"docks.yaml": database, "reloaded.yaml": reloaded},
        "dock_params": params,
        "goals": goals,
    }
    run = run_private_graph(HERE / "graph_dock_action.py", json.dumps(spec), timeout=540)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr, run.stderr[-3000:]
    assert run.first("ready")["ok"], run.stderr[-3000:]
    docked, again, undocked, not_docked, no_type, unknown, bad_type, retrying = run.all("goal")

    # Docked with the dock's own layout: succeeded with Nav2's result fields, on the contacts by the sim's truth.
    assert docked["succeeded"], docked
    assert (docked["success"], docked["error_code"], docked["error_msg"]) == (True, 0, "")
    _docked_by_truth(docked)
    # Feedback: staging first (no navigation here: monodock approaches from where it stands), perception, control,
    # then the wait for the charge; the elapsed time (ROS time) grows with it.
    states = docked["feedback_states"]
    assert states[0] == NAV_TO_STAGING_POSE, states
    assert INITIAL_PERCEPTION in states, states
    assert CONTROLLING in states, states
    assert states[-1] == WAIT_FOR_CHARGE, states
    assert states.index(INITIAL_PERCEPTION) < states.index(CONTROLLING)
    assert docked["docking_time"] > 2.0
    _debug_topics_agree(docked["debug"], docked_pose)

    # Already docked: succeeds at once, the robot still on its charger (upstream: no motion at all).
    assert again["succeeded"], again
    assert again["success"], again
    assert again["feedback_states"] == []
    assert again["moved_cm"] <= 1.0, again
    assert again["turned_deg"] <= 2.0, again
    _docked_by_truth(again)

    # Undocked: off the contacts, no longer charging.
    assert undocked["succeeded"], undocked
    assert undocked["success"], undocked
    assert undocked["truth"]["gap_cm"] > 10.0
    assert not undocked["charging"]

    # Undock when not docked: upstream ends it without a state of its own, which its server makes ABORTED with a
    # default result (success true, no code); the robot does not move.
    assert not_docked["aborted"], not_docked
    assert (not_docked["success"], not_docked["error_code"]) == (True, 0)
    assert not_docked["moved_cm"] < 0.5
    assert no_type["aborted"], no_type
    assert no_type["error_code"] == 902, no_type
    assert no_type["error_msg"] == "No dock information to undock from!"

    # A dock the database does not hold (yet): DOCK_NOT_IN_DB; a pose goal of a type without a plugin: DOCK_NOT_VALID.
    assert unknown["aborted"], unknown
    assert unknown["error_code"] == 901, unknown
    assert "not in database" in unknown["error_msg"]
    assert bad_type["aborted"], bad_type
    assert bad_type["error_code"] == 902, bad_type
    assert unknown["moved_cm"] < 0.5
    assert bad_type["moved_cm"] < 0.5

    # Reloaded, the database holds charger_7; its charger never charges, so the mission re-seats (RETRY), where the
    # cancel stops it.
    assert run.first("reload")["success"]
    assert retrying["canceled"], retrying
    assert retrying["cancel_accepted"] is True, retrying
    assert retrying["feedback_states"][-1] == RETRY, retrying
    assert WAIT_FOR_CHARGE in retrying["feedback_states"], retrying
    assert abs(retrying["truth"]["gap_cm"]) < 10.0, retrying
    end = run.first("end")
    assert (end["dock"], end["sim"]) == (0, 0), (end, run.stderr[-3000:])


def _debug_topics_agree(debug: dict[str, list[object]], docked_pose: list[float]) -> None:
    """Nav2's debug topics: the staging pose 0.7 m before the database's pose; dock_pose (where base_link stands
    docked, as the camera measured it) on the database's pose, which is the truth's (odometry drifts by mm); the
    trajectory ends there."""
    x, y, yaw = docked_pose
    assert debug["staging_pose"] == pytest.approx([x - 0.7 * math.cos(yaw), y - 0.7 * math.sin(yaw), yaw, "odom"])
    dock_pose = debug["dock_pose"]
    assert dock_pose[3] == debug["filtered_dock_pose"][3] == "odom"
    assert math.hypot(float(dock_pose[0]) - x, float(dock_pose[1]) - y) < 0.03, debug  # type: ignore[arg-type]
    assert debug["docking_trajectory"][-1][:2] == pytest.approx(dock_pose[:2], abs=0.02)  # type: ignore[index]


def _in_odom(start: list[float], in_dock: Pose2D) -> list[float]:
    """A pose of the dock frame in the sim's odometry frame (odometry starts at the robot's start)."""
    pose = Pose2D(*start).inverse().compose(in_dock)
    return [pose.x, pose.y, pose.theta]


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_cancel_at_every_phase_preemption_staging_and_undock_time_limit() -> None:
    start = [-1.9, 0.4, -0.1]
    front = RobotConfig.default().front_offset
    docked_pose = _in_odom(start, Pose2D(-front, 0.0, 0.0))  # where base_link stands docked (Nav2's dock pose)
    params = [
        "docks:=[home_dock]",
        "home_dock.type:=monodock",
        "home_dock.frame:=odom",
        f"home_dock.pose:={json.dumps(docked_pose)}",
    ]
    stay = {"dock_id": "home_dock", "navigate_to_staging_pose": False}
    goals = [
        {"action": "dock", "goal": {"dock_id": "home_dock"}, "cancel_at_once": True},
        {"action": "dock", "goal": {"dock_id": "home_dock"}, "cancel_in": NAV_TO_STAGING_POSE},
        {"action": "dock", "goal": {"dock_id": "home_dock"}, "cancel_in": INITIAL_PERCEPTION},
        {"action": "dock", "goal": stay, "cancel_in": CONTROLLING},
        {"action": "dock", "goal": stay, "preempt_in": CONTROLLING, "preempt_with": {"action": "dock", "goal": stay}},
        # An undock while a dock runs: not a preemption (another action), it waits for the docking to end.
        {"action": "dock", "goal": stay, "preempt_in": CONTROLLING, "preempt_with": {"action": "undock", "goal": {}}},
        {
            "action": "dock",
            "goal": {"use_dock_id": False, "dock_pose": [*docked_pose, "odom"], "navigate_to_staging_pose": False},
            "cancel_in": WAIT_FOR_CHARGE,
        },
        {"action": "undock", "goal": {}, "cancel_at_once": True},
        {"action": "undock", "goal": {"max_undocking_time": 0.5}},
    ]
    spec = {"start": start, "dock_params": params, "navigator": True, "goals": goals}
    run = run_private_graph(HERE / "graph_dock_action.py", json.dumps(spec), timeout=840)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr, run.stderr[-3000:]
    assert run.first("ready")["ok"], run.stderr[-3000:]
    goals_run = run.all("goal")
    at_once, staging, perceiving, controlling, preempted, preempting, docking, waiting = goals_run[:8]
    charging, undock_at_once, undock_late = goals_run[8:]

    # Each cancel ends the goal CANCELED. A cancel seen before the goal starts ends it with a default result (success
    # true, as upstream's terminate_all()); one seen later, unsuccessful.
    for goal in (at_once, staging, perceiving, controlling, charging, undock_at_once):
        assert goal["canceled"], goal
        assert goal["cancel_accepted"] is True, goal
    for goal in (staging, perceiving, controlling, charging):
        assert goal["success"] is False, goal
    assert at_once["moved_cm"] < 2.0, at_once
    # The staging phase went through navigate_to_pose, with Nav2's staging pose (0.7 m in front of the dock pose),
    # and the cancel reached it (upstream: FailedToStage, the goal CANCELED).
    assert staging["feedback_states"] == [NAV_TO_STAGING_POSE], staging
    assert staging["error_code"] == 903, staging
    navigated = run.first("navigator")["goals"]
    assert navigated, "navigate_to_pose was never called"
    x, y, yaw = docked_pose
    expected = [x - 0.7 * math.cos(yaw), y - 0.7 * math.sin(yaw), yaw]
    for sent in navigated:
        assert sent[3] == "odom"
        assert sent[:3] == pytest.approx(expected, abs=1e-6), sent
    # Cancelled when perception began (after navigating to the staging pose): stopped there, short of the dock; and
    # while controlling.
    assert INITIAL_PERCEPTION in perceiving["feedback_states"], perceiving
    assert perceiving["truth"]["gap_cm"] > 50.0, perceiving
    assert not perceiving["charging"], perceiving
    assert CONTROLLING in controlling["feedback_states"], controlling
    assert not controlling["charging"], controlling

    # Preempted while controlling: Nav2's docking server ends both the running goal and the new one aborted.
    assert preempted["aborted"], (preempted, preempting)
    assert preempting["aborted"], (preempted, preempting)
    assert not preempted["charging"]

    # Dock and undock exclude each other: the docking went on to its end, then the undock ran. Sent mid-approach,
    # the undock would have found the robot not docked (aborted, as above) had it not waited.
    assert docking["succeeded"], docking
    assert docking["success"], docking
    assert waiting["succeeded"], waiting
    assert waiting["truth"]["gap_cm"] > 10.0, waiting
    assert not waiting["charging"], waiting

    # A dock_pose goal (dock_type empty: the only type), cancelled at the face while it waits for the charge.
    assert charging["feedback_states"][-1] == WAIT_FOR_CHARGE, charging
    assert abs(charging["truth"]["gap_cm"]) <= 100 * TOL.retry.tolerance_longitudinal, charging

    # max_undocking_time: upstream's FAILED_TO_CONTROL "Undocking timed out", the robot stopped short of the
    # staging pose.
    assert undock_late["aborted"], undock_late
    assert undock_late["error_code"] == 905, undock_late
    assert undock_late["error_msg"] == "Undocking timed out"
    assert undock_late["truth"]["gap_cm"] < 50.0, undock_late
    end = run.first("end")
    assert (end["dock"], end["sim"]) == (0, 0), (end, run.stderr[-3000:])
