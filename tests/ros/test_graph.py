"""The ROS 2 test graphs stay on loopback: a private network namespace, LOCALHOST discovery, their own domain."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from private_graph import can_isolate, run_private_graph

HERE = Path(__file__).parent

# rclpy is never imported in the test process (tests/conftest.py keeps it out): only the graph's processes use it.
pytestmark = [
    pytest.mark.skipif(not can_isolate(), reason="no private network namespace on this machine"),
    pytest.mark.skipif(importlib.util.find_spec("rclpy") is None, reason="ROS 2 (rclpy) is not installed"),
]


def test_a_graph_sees_only_loopback_and_talks_over_it() -> None:
    run = run_private_graph(HERE / "graph_smoke.py", timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.first("interfaces")["names"] == ["lo"]
    env = run.first("env")
    assert env["range"] == "LOCALHOST"
    assert 100 < int(env["domain"]) < 233
    assert run.first("heard")["data"] == ["over loopback"]
