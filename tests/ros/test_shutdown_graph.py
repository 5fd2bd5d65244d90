"""The nodes' spin loop (monodock.ros.shutdown.spin) ends on SIGTERM and SIGINT, on a context another thread shuts
down, and on a context shut down under its wait with nothing to wake it: the way rclpy's own SIGTERM handling once
left the detector waiting forever in CI (tests/ros/graph_shutdown.py; bench/sigterm_race.py measures the race)."""

from __future__ import annotations

from pathlib import Path

from private_graph import needs_graph, run_private_graph

HERE = Path(__file__).parent

pytestmark = needs_graph()


def test_spin_ends_on_signals_and_on_a_context_shut_down_under_its_wait() -> None:
    run = run_private_graph(HERE / "graph_shutdown.py", timeout=120)
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    phases = {p["name"]: p for p in run.all("phase")}
    for name, phase in phases.items():
        assert phase["returned"], f"{name}: spin still waiting 5 s after"
        # A wait is at most 0.1 s: the flag or the context is read within that, however idle the graph.
        assert phase["after"] < 1.0, (name, phase)
        assert phase["spins"] >= 1, (name, phase)
    assert list(phases) == ["woken, then shut down", "shut down by another thread", "SIGTERM", "SIGINT"], run.stdout
