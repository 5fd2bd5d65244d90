"""monodock_sim on a real ROS 2 graph (Fast DDS, private network namespace): it publishes the camera at its rate,
odometry, ground truth, battery and the rear range, drives by cmd_vel and stops when cmd_vel falls silent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from monodock.core.robot import RobotConfig
from private_graph import needs_graph, run_private_graph

HERE = Path(__file__).parent

pytestmark = needs_graph()


def test_the_simulated_robot_publishes_and_drives() -> None:
    run = run_private_graph(HERE / "graph_sim.py", timeout=180)
    assert run.returncode == 0, run.stderr
    sim = run.first("sim")
    assert sim["returncode"] == 0, sim["stderr"]
    counts = run.first("counts")
    # 9 s of simulated time at 15 fps and 50 Hz, less the driver's start-up.
    assert counts["image"] > 60
    assert counts["odom"] > 250
    assert counts["ground_truth"] > 250
    assert counts["battery"] > 250
    assert run.first("image")["sizes"] == [[640, 480, "mono8"]]
    assert 12.0 < run.first("image_rate")["hz"] < 18.0
    x = run.first("truth")["x"]
    moved = max(x) - run.first("truth")["last"]  # the dock's distance ahead (DockPose x) shrinks as it drives
    # 2 s at 0.1 m/s, then stopped by the cmd_vel time-out: about 0.2 m, and it does not keep going. The commands
    # span 2 s of wall clock; a busy machine runs the simulation slower, so fewer simulated seconds of them.
    assert 0.12 < moved < 0.3
    # /tf: odom -> base_link with every odometry message, the same pose at the same stamp.
    tf = run.first("tf")
    assert tf["frames"] == [["odom", "base_link"]]
    assert tf["count"] > 250
    assert tf["paired"] > 250
    assert tf["gap"] < 1e-9
    # /tf_static (latched, heard after the fact): base_link -> camera_link -> camera_optical_frame, which composed is
    # the optical frame the simulator renders from (the default robot file's mount and REP 103's optical rotation).
    static = {(parent, child): values for parent, child, values in run.first("tf_static")["transforms"]}
    assert set(static) == {("base_link", "camera_link"), ("camera_link", "camera_optical_frame")}
    base_T_optical = _matrix(static["base_link", "camera_link"]) @ _matrix(
        static["camera_link", "camera_optical_frame"]
    )
    np.testing.assert_allclose(base_T_optical, RobotConfig.default().base_T_optical(), atol=1e-9)


def _matrix(values: list[float]) -> np.ndarray:
    """A 4x4 transform from translation x, y, z and quaternion x, y, z, w."""
    x, y, z, qx, qy, qz, qw = values
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    T[:3, 3] = [x, y, z]
    return T


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["-p", "nuisances:=foggy"], "parameter nuisances: 'foggy' is not one of default, clean"),
        (["-p", "camera_rate:=0.0"], "parameter camera_rate must be a finite number above 0, got 0"),
        (["-p", "layout:=/nonexistent/layout.yaml"], "/nonexistent/layout.yaml"),
        (["-p", "seed:=abc"], "parameter seed is an integer, got 'abc'"),
        (["-p", "start:=[1.0, 2.0]"], "parameter start is a list of 3 finite numbers, got [1.0, 2.0]"),
        (["-p", "start:=hello"], "parameter start is a list of 3 finite numbers, got 'hello'"),
    ],
)
def test_bad_parameters_are_one_line_and_exit_2(args: list[str], message: str) -> None:
    run = run_private_graph(HERE / "graph_node.py", "sim", "--ros-args", *args, timeout=60)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    assert lines[0].startswith("monodock-sim-ros: error: ")
    assert message in lines[0]


def test_help_prints_the_usage_and_starts_nothing() -> None:
    run = run_private_graph(HERE / "graph_node.py", "sim", "--help", timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("usage: monodock-sim-ros"), run.stdout[:200]
    assert "start:=[x,y,yaw]" in run.stdout
    assert run.stderr == ""  # no node came up to log anything
    refused = run_private_graph(HERE / "graph_node.py", "sim", "--bogus", timeout=60)
    assert refused.returncode == 2
    assert refused.stderr.strip() == (
        "monodock-sim-ros: error: unrecognised arguments: --bogus (see monodock-sim-ros --help)"
    )
