"""nav2_lifecycle_manager brings monodock's nodes up: its side of the lifecycle transitions and of the bond, played from
Nav2's own code (tests/ros/graph_lifecycle.py says which), against monodock_dock started as ``docking_server`` and the
managed detector, over Fast DDS in a private network namespace."""

from __future__ import annotations

from pathlib import Path

import pytest

from private_graph import needs_graph, run_private_graph

HERE = Path(__file__).parent
UNCONFIGURED, INACTIVE, ACTIVE = 1, 2, 3  # lifecycle_msgs/msg/State
BOND_TIMEOUT = 4.0

pytestmark = needs_graph("bond")


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_lifecycle_manager_configures_activates_and_bonds_with_both_nodes() -> None:
    run = run_private_graph(HERE / "graph_lifecycle.py", timeout=240)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr, run.stderr[-3000:]
    steps = {}
    for record in run.all("step"):
        steps.setdefault(record["step"], []).append(record)

    # Both wait unconfigured for the manager; the docking server refuses goals until it is active.
    services = steps["services"][0]
    assert services["ok"], run.stderr[-3000:]
    assert services["states"] == {"monodock_detector": UNCONFIGURED, "docking_server": UNCONFIGURED}
    assert steps["goal while unconfigured"][0]["accepted"] is False
    for configured in steps["configure"]:
        assert configured["ok"], configured
        assert configured["state"] == INACTIVE, configured
    assert steps["goal while inactive"][0]["accepted"] is False

    # Each activation forms a bond within bond_timeout / 2 (the manager fails bring-up otherwise).
    for activated in steps["activate"]:
        assert activated["ok"], activated
        assert activated["state"] == ACTIVE, activated
        assert activated["formed"], activated
        assert activated["formed_after"] < BOND_TIMEOUT / 2, activated
    assert steps["goal while active"][0]["accepted"] is True
    # Kilted's default: TwistStamped on cmd_vel.
    assert steps["cmd_vel"][0]["types"] == ["geometry_msgs/msg/TwistStamped"]

    # The bonds hold: heartbeats far more often than the manager's heartbeat time-out.
    held = steps["held"][0]
    assert held["broken"] == {"monodock_detector": False, "docking_server": False}, held
    assert max(held["gaps"].values()) < 1.0, held

    # Deactivated: the node ends its side of the bond and refuses goals; activated again, a new bond forms.
    deactivated = steps["deactivate"][0]
    assert deactivated["ok"], deactivated
    assert deactivated["state"] == INACTIVE, deactivated
    assert deactivated["node_said_dead"], deactivated
    assert steps["goal after deactivate"][0]["accepted"] is False
    reactivated = steps["reactivate"][0]
    assert reactivated["ok"], reactivated
    assert reactivated["formed"], reactivated
    assert reactivated["instances"] == 2, reactivated  # the node's bond of each activation

    # Killed outright: the manager's bond breaks on its heartbeat time-out.
    killed = steps["killed"][0]
    assert killed["broken"], killed
    assert killed["after"] <= BOND_TIMEOUT + 0.5, killed
    assert run.first("end")["detector"] == 0, run.first("end")
