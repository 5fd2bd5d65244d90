"""The detector's TF and on-demand detection on a real ROS 2 graph (Fast DDS, private network namespace), against
monodock_sim's ground truth: the camera mount from /tf_static over a wrong robot file, the dock frame on /tf, the
debug image, and ~/toggle as Nav2's ``detector_service_name`` calls it (tests/ros/graph_detector_tf.py)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from private_graph import GraphRun, needs_graph, run_private_graph

HERE = Path(__file__).parent

pytestmark = needs_graph()


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> GraphRun:
    picture = tmp_path_factory.mktemp("debug") / "debug_image.png"
    done = run_private_graph(HERE / "graph_detector_tf.py", "[-1.2, 0.08, 0.1]", str(picture), timeout=240)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    for process in done.all("process"):
        assert process["returncode"] == 0, process["stderr"]
        assert "Traceback" not in process["stderr"]
    return done


def _median_error(run: GraphRun, name: str) -> np.ndarray:
    """|median pose - truth| of a detector's poses: x (m), y (m), yaw (degrees)."""
    record = next(r for r in run.all("poses") if r["name"] == name)
    assert record["count"] > 20, record["count"]
    error = np.abs(np.median(np.array(record["poses"]), axis=0) - np.array(record["truth"]))
    return np.array([error[0], error[1], math.degrees(error[2])])


def _log(run: GraphRun, name: str) -> str:
    return str(next(r for r in run.all("process") if r["name"] == name)["stderr"])


def test_the_camera_mount_comes_from_tf_static_over_a_wrong_robot_file(run: GraphRun) -> None:
    # The robot file puts the camera 5 cm left and 2 degrees turned; the sim renders with, and latches, the truth.
    error = _median_error(run, "tf_mount")
    assert np.all(error < (0.01, 0.005, 0.5)), error
    warned = [line for line in _log(run, "tf_mount").splitlines() if "are 5.0 cm and 2.00° apart" in line]
    assert len(warned) == 1, _log(run, "tf_mount")
    assert "estimating with /tf_static's" in warned[0]


def test_camera_mount_source_robot_keeps_the_file_s_mount_and_still_warns(run: GraphRun) -> None:
    # The same wrong file, kept: the pose moves by about the mount's error (5 cm, and 2 degrees at 1.2 m).
    error = _median_error(run, "file_mount")
    assert np.all(error[1:] > (0.05, 1.5)), error
    log = _log(run, "file_mount")
    assert log.count("apart; estimating with the robot file's") == 1, log


def test_a_mount_within_tolerance_is_used_with_one_line_of_information(run: GraphRun) -> None:
    log = _log(run, "on_demand")
    assert "camera mount from /tf_static (base_link -> camera_optical_frame), within the robot file's" in log
    assert "apart" not in log


def test_the_dock_frame_is_broadcast_with_each_pose(run: GraphRun) -> None:
    transforms: list[Any] = run.first("dock_tf")["transforms"]
    assert {(parent, child) for parent, child, *_ in transforms} == {("base_link", "dock")}
    match = run.first("dock_tf_match")
    assert match["matched"] == run.first("dock_tf")["pose_stamps"] > 20  # one per pose, at the pose's stamp
    assert match["gap"] < 1e-9


def test_the_debug_image_draws_the_markers_on_the_camera_s_frame(run: GraphRun) -> None:
    debug = run.first("debug")
    assert debug["count"] > 20
    first = debug["first"][0]
    assert (first["frame"], first["encoding"]) == ("camera_optical_frame", "bgr8")
    # Three marker outlines and their corner dots, green, in every picture (the sim's image is grey).
    assert debug["green_min"] > 300


def test_detection_runs_only_when_started_and_watched(run: GraphRun) -> None:
    phases = {p["name"]: p for p in run.first("phases")["phases"]}
    assert run.first("phases")["toggles"] == ["True detection started", "True detection stopped"]
    stopped, unwatched = phases["stopped"], phases["started, nothing subscribed"]
    watched, again = phases["started, subscribed"], phases["stopped again"]
    assert (stopped["poses"], stopped["levels"]) == (0, [0])
    assert stopped["reasons"] == ["stopped (~/start or ~/toggle starts detection)"]
    assert (unwatched["poses"], unwatched["levels"]) == (0, [0])
    assert unwatched["reasons"] == ["idle: nothing subscribes to the poses, the dock frame or the debug image"]
    assert watched["poses"] > 20  # 4 s at 15 fps
    assert again["since_stop"] == 0
    assert again["reasons"] == ["stopped (~/start or ~/toggle starts detection)"]


def test_the_lifecycle_node_estimates_only_while_active(run: GraphRun) -> None:
    phases = {p["name"]: p for p in run.first("phases")["phases"]}
    assert run.first("phases")["transitions"] == [True, True, True]  # configure, activate, deactivate
    # Subscribed throughout: nothing while unconfigured, poses while active, none after deactivate.
    assert phases["stopped"]["managed_state"] == "unconfigured"
    assert phases["stopped"]["managed_poses"] == 0
    assert phases["started, subscribed"]["managed_state"] == "active"
    assert phases["started, subscribed"]["managed_poses"] > 20
    assert phases["stopped again"]["managed_state"] == "inactive"
    assert phases["stopped again"]["managed_since_stop"] == 0
    error = _median_error(run, "managed")
    assert np.all(error < (0.01, 0.005, 0.5)), error
