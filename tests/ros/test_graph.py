"""The ROS 2 test graphs stay on loopback: a private network namespace, LOCALHOST discovery, their own domain."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from private_graph import can_isolate, claim_domain_id, needs_graph, run_private_graph

HERE = Path(__file__).parent


# rclpy is never imported in the test process (tests/conftest.py keeps it out): only the graph's processes use it.
@needs_graph()
def test_a_graph_sees_only_loopback_and_talks_over_it() -> None:
    run = run_private_graph(HERE / "graph_smoke.py", timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.first("interfaces")["names"] == ["lo"]
    env = run.first("env")
    assert env["range"] == "LOCALHOST"
    assert 10 <= int(env["domain"]) <= 101 or 215 <= int(env["domain"]) <= 232  # ROS 2's safe IDs on Linux
    assert run.first("heard")["data"] == ["over loopback"]


@pytest.mark.skipif(not os.environ.get("MONODOCK_REQUIRE_ROS_GRAPH"), reason="only where ROS graphs must run (CI)")
def test_ci_runs_the_graphs_instead_of_skipping_them() -> None:
    """.ci/run sets MONODOCK_REQUIRE_ROS_GRAPH: there, a missing ROS 2 install or namespace is a failure, not a skip."""
    assert importlib.util.find_spec("rclpy") is not None, "rclpy is not installed: the ros extra is missing"
    assert can_isolate(), "unshare --net does not work here: the ROS graph tests would all be skipped"


def test_graphs_running_at_once_never_share_a_domain_id() -> None:
    """Fast DDS's shared-memory ports (/dev/shm, which no network namespace separates) are named by the domain: two
    graphs at once, here or in another process (the other xdist worker, a benchmark), each get their own."""
    claim = "import sys; sys.path.insert(0, sys.argv[1]); from private_graph import claim_domain_id as c\n"
    claim += "with c() as d: print(d)"
    tests = str(Path(__file__).parents[1])
    with claim_domain_id() as first, claim_domain_id() as second:
        other = subprocess.run([sys.executable, "-c", claim, tests], capture_output=True, text=True, check=True)
        held = {first, second}
        assert len(held) == 2
        assert int(other.stdout) not in held
