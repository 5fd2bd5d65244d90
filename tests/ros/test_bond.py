"""The bond's state machine against bond_core's ``bond/BondSM.sm`` (branch ros2), transition by transition, on a
stand-in node whose timers fire when the test says: no graph, no clock."""

from __future__ import annotations

import importlib.util
import sys
import types
from collections.abc import Callable
from typing import Any

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bond") is None, reason="the bond interfaces were not built")


@pytest.fixture(autouse=True)
def _rclpy_stand_ins(monkeypatch: pytest.MonkeyPatch) -> None:
    """What the bond takes of rclpy (a steady clock, a QoS), so that the test process never loads the real one."""

    class _Time:
        def to_msg(self) -> Any:
            from builtin_interfaces.msg import Time

            return Time()

    class Clock:
        def __init__(self, **_kw: Any) -> None:
            pass

        def now(self) -> _Time:
            return _Time()

    members = {
        "rclpy": {},
        "rclpy.clock": {"Clock": Clock},
        "rclpy.clock_type": {"ClockType": types.SimpleNamespace(STEADY_TIME=2)},
        "rclpy.qos": {"QoSProfile": lambda **kw: kw},
    }
    for name, values in members.items():
        module = types.ModuleType(name)
        module.__dict__.update(values)
        monkeypatch.setitem(sys.modules, name, module)


class _Timer:
    def __init__(self, period: float, callback: Callable[[], None]) -> None:
        self.period, self.callback, self.cancelled = period, callback, False

    def cancel(self) -> None:
        self.cancelled = True


class _Node:
    """What a Bond asks of its node; timers are fired by hand."""

    def __init__(self) -> None:
        self.sent: list[Any] = []
        self.timers: list[_Timer] = []
        self.on_status: Callable[[Any], None] | None = None

    def create_publisher(self, _type: Any, _topic: str, _qos: Any) -> Any:
        node = self

        class _Publisher:
            def publish(self, msg: Any) -> None:
                node.sent.append((msg.id, msg.instance_id, msg.active))

        return _Publisher()

    def create_subscription(self, _type: Any, _topic: str, callback: Callable[[Any], None], _qos: Any) -> Any:
        self.on_status = callback
        return object()

    def create_timer(self, period: float, callback: Callable[[], None], clock: Any = None) -> _Timer:
        del clock
        timer = _Timer(period, callback)
        self.timers.append(timer)
        return timer

    def destroy_timer(self, _timer: Any) -> None:
        pass

    def destroy_subscription(self, _sub: Any) -> None:
        pass

    def destroy_publisher(self, _pub: Any) -> None:
        pass

    def fire(self, period: float) -> None:
        """Every live timer of this period fires once."""
        for timer in [t for t in self.timers if t.period == period and not t.cancelled]:
            timer.callback()


def _status(bond_id: str, instance: str, active: bool) -> Any:
    from bond.msg import Status

    return Status(id=bond_id, instance_id=instance, active=active)


def _bond(**kw: Any) -> tuple[Any, _Node, list[str]]:
    from monodock.ros.bond import Bond

    node, events = _Node(), []
    bond = Bond(
        node,
        "bond",
        "docking_server",
        heartbeat_period=0.1,
        heartbeat_timeout=4.0,
        on_formed=lambda: events.append("formed"),
        on_broken=lambda: events.append("broken"),
        **kw,
    )
    bond.start()
    return bond, node, events


def test_a_sister_s_status_forms_the_bond_and_heartbeats_keep_it() -> None:
    from monodock.ros.bond import BondState

    bond, node, events = _bond()
    node.fire(0.1)
    assert node.sent == [("docking_server", bond.instance_id, True)]  # waiting: publishes alive
    assert node.on_status is not None
    node.on_status(_status("docking_server", bond.instance_id, True))  # its own status: not a sister
    node.on_status(_status("other_node", "x", True))  # another bond's
    assert bond.state is BondState.WAITING_FOR_SISTER
    node.on_status(_status("docking_server", "manager", True))
    assert (bond.state, events) == (BondState.ALIVE, ["formed"])
    assert bond.formed
    node.fire(10.0)  # the connect time-out was cancelled on forming
    assert bond.state is BondState.ALIVE
    node.on_status(_status("docking_server", "manager", True))  # Heartbeat(): the heartbeat time-out starts
    node.fire(4.0)
    assert (bond.state, events) == (BondState.DEAD, ["formed", "broken"])


def test_the_node_s_side_never_times_out_on_its_manager() -> None:
    from monodock.ros.bond import BondState

    bond, node, events = _bond(disable_heartbeat_timeout=True)
    assert node.on_status is not None
    node.on_status(_status("docking_server", "manager", True))
    node.on_status(_status("docking_server", "manager", True))
    node.fire(4.0)
    assert bond.state is BondState.ALIVE
    assert events == ["formed"]


def test_breaking_says_so_until_the_sister_answers_or_the_disconnect_time_out() -> None:
    from monodock.ros.bond import BondState

    for answer in (True, False):
        bond, node, events = _bond()
        assert node.on_status is not None
        node.on_status(_status("docking_server", "manager", True))
        bond.break_bond()
        assert bond.state is BondState.AWAIT_SISTER_DEATH
        assert node.sent[-1] == ("docking_server", bond.instance_id, False)
        node.fire(0.05)  # the dead-publishing timer
        assert node.sent[-1][2] is False
        node.on_status(_status("docking_server", "manager", True))  # ignored while dying
        assert bond.state is BondState.AWAIT_SISTER_DEATH
        if answer:
            node.on_status(_status("docking_server", "manager", False))
        else:
            node.fire(2.0)  # DisconnectTimeout
        assert bond.state is BondState.DEAD
        assert events == ["formed", "broken"]
        sent = len(node.sent)
        node.fire(0.1)  # dead: publishing stops
        node.fire(0.05)
        assert len(node.sent) == sent


def test_no_sister_within_the_connect_time_out_is_a_dead_bond_and_a_dead_sister_is_answered() -> None:
    from monodock.ros.bond import BondState

    bond, node, events = _bond()
    node.fire(10.0)
    assert (bond.state, events) == (BondState.DEAD, ["broken"])
    bond, node, events = _bond()
    assert node.on_status is not None
    node.on_status(_status("docking_server", "manager", False))  # the sister died first: Connected, Death
    assert bond.state is BondState.DEAD
    assert events == ["formed", "broken"]
    assert node.sent[-1] == ("docking_server", bond.instance_id, False)
