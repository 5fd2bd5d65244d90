"""Two namespaced simulated robots docking at the same time on one ROS 2 graph (Fast DDS, private network namespace;
tests/ros/graph_two_robots.py): /r1 and /r2, each a monodock_sim and a monodock_dock with frame names and a clock
topic of its own, /tf and /tf_static shared, both docked by DockRobot goals sent together.

Each robot's final pose comes from its own sim's ground truth and its charging from its own sim's battery, never from
the nodes under test. Tolerances are dock-sim's (``DockingConfig``: 2 cm lateral and gap, 3.07° heading). r1's
docking node is given a robot file whose camera mount is 5 cm and 2° off and must dock with /tf_static's.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from monodock.dock.config import DockingConfig
from private_graph import needs_graph, run_private_graph

HERE = Path(__file__).parent
TOL = DockingConfig()
ROBOTS = ("r1", "r2")
# DockRobot.Feedback's states (interfaces/upstream/nav2_msgs/action/DockRobot.action).
INITIAL_PERCEPTION, CONTROLLING, WAIT_FOR_CHARGE = 2, 3, 4
# Absolute by design, one for the whole graph (/diagnostics' statuses carry each node's namespaced name).
SHARED = {"/tf", "/tf_static", "/rosout", "/parameter_events", "/diagnostics"}

pytestmark = needs_graph("nav2_msgs", "tf2_msgs")


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.xdist_group("ros-graph")  # real-time graphs run one after another (tests/conftest.py)
def test_two_namespaced_robots_dock_side_by_side_on_one_graph() -> None:
    spec = {
        "robots": {
            "r1": {"start": [-1.2, 0.10, 0.12], "seed": 3},
            "r2": {"start": [-1.05, -0.12, -0.08], "seed": 7},
        }
    }
    run = run_private_graph(HERE / "graph_two_robots.py", json.dumps(spec), timeout=480)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr, run.stderr[-3000:]
    logs = {p["name"]: p["log"] for p in run.all("process")}
    assert run.first("ready")["ok"], (run.stderr[-3000:], logs)
    for process in run.all("process"):
        name, code, log = process["name"], process["returncode"], process["log"]
        assert code == 0, f"{name} exited {code}:\n{log[-4000:]}"
        assert "Traceback" not in process["log"], process

    robots = {r["name"]: r for r in run.all("robot")}
    assert sorted(robots) == list(ROBOTS)
    for name, robot in robots.items():  # shown with -s
        t = robot["truth"]
        print(
            f"{name}: lateral {t['lateral_cm']:.2f} cm, gap {t['gap_cm']:.2f} cm, heading {t['heading_deg']:.2f} deg "
            f"by its sim's truth; docked in {robot['seconds'] or math.nan:.1f} s"
        )
    for name, robot in robots.items():
        # Docked by its own sim's truth and charging by its own sim's battery (r1 with its file's mount, 5 cm and 2°
        # off, would end 5 cm or more to the side).
        assert robot["succeeded"], (robot, logs[f"{name}/dock"])
        assert robot["error_code"] == 0, robot
        assert robot["error_msg"] == "", robot
        truth = robot["truth"]
        assert abs(truth["lateral_cm"]) <= 100 * TOL.retry.tolerance_lateral, robot
        assert abs(truth["gap_cm"]) <= 100 * TOL.retry.tolerance_longitudinal, robot
        assert abs(truth["heading_deg"]) <= TOL.retry.tolerance_heading_deg, robot
        assert robot["charging"], robot
        # Every change of state is fed back, a short wait for the charge too.
        assert {INITIAL_PERCEPTION, CONTROLLING, WAIT_FOR_CHARGE} <= set(robot["feedback_states"]), robot
        # Every message of the robot's topics named its own frames.
        assert robot["frames"] == {
            "ground_truth": [f"{name}/base_link"],
            "odom": [f"{name}/odom -> {name}/base_link"],
            "camera_info": [f"{name}/camera_optical_frame"],
            "detected_dock_pose": [f"{name}/base_link"],
        }, robot
        assert robot["result"] == {"level": 0, "message": "docked", "hardware_id": f"{name}/base_link"}, robot
    # Side by side: each mission was still sending feedback after the other's had begun.
    spans = [robots[r]["feedback_span"] for r in ROBOTS]
    assert max(s[0] for s in spans) + 5.0 < min(s[1] for s in spans), spans

    # /tf carries each robot's odom -> base_link under its own prefixed names, equal to its own odometry at each stamp;
    # /tf_static each robot's camera chain.
    tf = run.first("tf")
    assert tf["pairs"] == [f"{r}/odom -> {r}/base_link" for r in ROBOTS], tf["pairs"]
    chains = [
        [[f"{r}/base_link", f"{r}/camera_link"], [f"{r}/camera_link", f"{r}/camera_optical_frame"]] for r in ROBOTS
    ]
    assert tf["static"] == [pair for chain in chains for pair in chain], tf["static"]
    # (The client, starved on a busy machine, may miss a few of either: the publishers keep a short history.)
    for r in ROBOTS:
        assert tf[r]["matched"] > 200, tf
        assert tf[r]["matched"] >= 0.9 * max(tf[r]["transforms"], tf[r]["odometry"]), tf
        assert tf[r]["gap"] < 1e-9, tf

    # The graph: no message of one robot reaches the other's topics. Every endpoint of a robot's topics belongs to a
    # node in that robot's namespace (or to the client); its cmd_vel has one publisher, its own docking node, and one
    # subscriber, its own sim; its clock is its own sim's, on the remapped topic, and nothing uses /clock.
    graph = run.first("graph")
    topics, client = graph["topics"], graph["client"]
    assert "/clock" not in topics, topics.get("/clock")
    outside = sorted(t for t in topics if not t.startswith(("/r1/", "/r2/")) and t not in SHARED)
    assert outside == [], outside
    # On the shared /diagnostics, each node's status is under its own namespaced name.
    for r in ROBOTS:
        assert {f"{r}/monodock_sim: real time", f"{r}/monodock_dock: docking"} <= set(graph["diagnostics"]), graph
    for r in ROBOTS:
        mine = {t: ends for t, ends in topics.items() if t.startswith(f"/{r}/")}
        assert len(mine) > 10, sorted(topics)
        for topic, ends in mine.items():
            strangers = [e for e in ends["publishers"] + ends["subscribers"] if e[0] != f"/{r}" and e != client]
            assert strangers == [], (topic, strangers)
        assert topics[f"/{r}/cmd_vel"] == {
            "publishers": [[f"/{r}", "monodock_dock"]],
            "subscribers": [[f"/{r}", "monodock_sim"]],
        }
        assert topics[f"/{r}/clock"]["publishers"] == [[f"/{r}", "monodock_sim"]]
        assert [f"/{r}", "monodock_dock"] in topics[f"/{r}/clock"]["subscribers"]
    assert topics["/tf"]["publishers"] == [[f"/{r}", "monodock_sim"] for r in ROBOTS]

    # r1's docking node took the true mount from /tf_static over its wrong robot file, and said so once; r2's agreed.
    chain = "(r1/base_link -> r1/camera_optical_frame:"
    warned = [line for line in logs["r1/dock"].splitlines() if "are 5.0 cm and 2.00° apart" in line]
    assert len(warned) == 1, logs["r1/dock"]
    assert "[WARN]" in warned[0], warned
    assert chain in warned[0], warned
    assert "apart; estimating with /tf_static's" in warned[0], warned
    assert (
        "camera mount from /tf_static (r2/base_link -> r2/camera_optical_frame), within the robot file's"
        in (logs["r2/dock"])
    )
    assert "apart" not in logs["r2/dock"], logs["r2/dock"]
