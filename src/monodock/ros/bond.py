"""A bond (ros/bond_core's heartbeat protocol) for rclpy nodes: how ``nav2_lifecycle_manager`` knows a node it manages
is alive, and the node that its manager is.

Each side publishes ``bond/msg/Status`` (``id``: the bond's name, ``instance_id``: its own UUID, ``active``) on a
shared topic every ``heartbeat_period`` and listens there for its sister's: the other instance of the same ``id``.
The state machine is bond_core's ``bond/BondSM.sm``, transition for transition, with bondcpp's timers
(``bondcpp/src/bond.cpp``, branch ros2):

================  ===============================================================================================
state             on: what follows
================  ===============================================================================================
waiting           sister alive: alive (formed); sister dead: dead; connect time-out: dead; break: dead
alive             sister alive: alive (heartbeat time-out restarted); sister dead, heartbeat time-out: dead;
                  break: awaiting sister's death (publish ``active: false`` every ``dead_publish_period``)
awaiting death    sister dead, disconnect time-out: dead; anything else: stays
dead              stays (publishing stops)
================  ===============================================================================================

A Nav2 lifecycle node's side (``nav2_util::LifecycleNode::createBond``) has ``id`` = the node's name on topic
``bond``, a heartbeat period of ``bond_heartbeat_period`` (0.1 s), a heartbeat time-out of 4 s, and
``/bond_disable_heartbeat_timeout`` set: the node never gives up on its manager; the manager's side times out after
its ``bond_timeout`` and brings the other nodes down. Needs rclpy and the ``bond`` interfaces built at install time
(interfaces/README.md).
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable
from enum import Enum
from typing import Any

__all__ = ["Bond", "BondState"]

# bond/msg/Constants.msg's defaults.
DEFAULT_CONNECT_TIMEOUT = 10.0
DEFAULT_HEARTBEAT_TIMEOUT = 4.0
DEFAULT_DISCONNECT_TIMEOUT = 2.0
DEFAULT_HEARTBEAT_PERIOD = 1.0
DEAD_PUBLISH_PERIOD = 0.05


class BondState(Enum):
    """BondSM.sm's states."""

    WAITING_FOR_SISTER = "waiting-for-sister"
    ALIVE = "alive"
    AWAIT_SISTER_DEATH = "await-sister-death"
    DEAD = "dead"


class Bond:
    """One side of a bond on ``node``: ``start`` it, ``break_bond`` to end it; ``on_formed``/``on_broken`` are called
    from the node's executor when it forms or breaks."""

    def __init__(
        self,
        node: Any,
        topic: str,
        bond_id: str,
        *,
        heartbeat_period: float = DEFAULT_HEARTBEAT_PERIOD,
        heartbeat_timeout: float = DEFAULT_HEARTBEAT_TIMEOUT,
        connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
        disconnect_timeout: float = DEFAULT_DISCONNECT_TIMEOUT,
        dead_publish_period: float = DEAD_PUBLISH_PERIOD,
        disable_heartbeat_timeout: bool = False,
        on_formed: Callable[[], None] | None = None,
        on_broken: Callable[[], None] | None = None,
    ) -> None:
        from bond.msg import Status  # type: ignore[import-not-found, unused-ignore]
        from rclpy.clock import Clock  # type: ignore[import-not-found, unused-ignore]
        from rclpy.clock_type import ClockType  # type: ignore[import-not-found, unused-ignore]
        from rclpy.qos import QoSProfile  # type: ignore[import-not-found, unused-ignore]

        self.node, self.id, self.instance_id = node, bond_id, str(uuid.uuid4())
        self.heartbeat_period, self.heartbeat_timeout = heartbeat_period, heartbeat_timeout
        self.connect_timeout, self.disconnect_timeout = connect_timeout, disconnect_timeout
        self.dead_publish_period = dead_publish_period
        self.disable_heartbeat_timeout = disable_heartbeat_timeout
        self.on_formed, self.on_broken = on_formed, on_broken
        self.state = BondState.WAITING_FOR_SISTER
        self.sister_instance_id = ""
        self.sister_died_first = False
        self._status = Status
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._lock = threading.RLock()
        self._started = False
        self._timers: dict[str, Any] = {}
        self._spent: list[Any] = []  # cancelled timers, destroyed with the bond (not inside their own callback)
        # bondcpp's QoS: the publisher keeps the last 5, the subscription 100; both reliable.
        self._pub = node.create_publisher(Status, topic, QoSProfile(depth=5))
        self._sub = node.create_subscription(Status, topic, self._on_status, QoSProfile(depth=100))

    # --- life -------------------------------------------------------------------------------

    def start(self) -> None:
        """Start publishing and listening; the connect time-out runs from here (``Bond::start``)."""
        with self._lock:
            self._started = True
            self._timeout("connect", self.connect_timeout)
            self._timer("publishing", self.heartbeat_period, self._do_publishing)

    def break_bond(self) -> None:
        """End the bond from this side (``Bond::breakBond``): the sister hears ``active: false``."""
        with self._lock:
            if self.state is BondState.DEAD:
                return
            self._event("die")
        self._publish(False)

    def destroy(self) -> None:
        """Break the bond and release its timers, publisher and subscription (the node lives on)."""
        self.break_bond()
        with self._lock:
            for name in list(self._timers):
                self._cancel(name)
            self._started = False
            spent, self._spent = self._spent, []
        for timer in spent:
            self.node.destroy_timer(timer)
        self.node.destroy_subscription(self._sub)
        self.node.destroy_publisher(self._pub)

    @property
    def formed(self) -> bool:
        """Whether the sister has been heard (``!isStateWaitingForSister``)."""
        return self.state is not BondState.WAITING_FOR_SISTER

    @property
    def broken(self) -> bool:
        return self.state is BondState.DEAD

    # --- events -----------------------------------------------------------------------------

    def _on_status(self, msg: Any) -> None:
        """``Bond::bondStatusCB``: a status of this bond's id from another instance is the sister's."""
        if not self._started or msg.id != self.id or msg.instance_id == self.instance_id:
            return
        with self._lock:
            if not self.sister_instance_id:
                self.sister_instance_id = msg.instance_id
            self._event("sister_alive" if msg.active else "sister_dead")
            answer_death = not msg.active and self.sister_died_first
        if answer_death:
            self._publish(False)

    def _on_timeout(self, name: str) -> None:
        """The ``name`` time-out (connect, heartbeat, disconnect) expired: BondSM's ``<name>_timeout`` event. Each
        fires once: its event ends the wait it times (a heartbeat restarts the heartbeat time-out afresh)."""
        if name == "heartbeat" and self.disable_heartbeat_timeout:
            return
        with self._lock:
            self._cancel(name)
            self._event(f"{name}_timeout")

    def _do_publishing(self) -> None:
        """``Bond::doPublishing``: alive (or waiting) says so, a dying side says it is not, a dead one stops."""
        with self._lock:
            state = self.state
        if state in (BondState.WAITING_FOR_SISTER, BondState.ALIVE):
            self._publish(True)
        elif state is BondState.AWAIT_SISTER_DEATH:
            self._publish(False)
        else:
            self._cancel("publishing")
            self._cancel("dead_publishing")

    def _event(self, event: str) -> None:
        """One event of BondSM.sm: the transition and its actions (the lock is held)."""
        state = self.state
        waiting, alive = BondState.WAITING_FOR_SISTER, BondState.ALIVE
        if state is waiting:
            if event == "sister_alive":
                self._connected(alive)
            elif event == "sister_dead":
                self._connected(BondState.DEAD)
                self.sister_died_first = True
                self._death()
            elif event in ("connect_timeout", "die"):
                self.state = BondState.DEAD
                self._death()
        elif state is alive:
            if event == "sister_alive":
                self._timeout("heartbeat", self.heartbeat_timeout)  # Heartbeat()
            elif event in ("sister_dead", "heartbeat_timeout"):
                self.state = BondState.DEAD
                self.sister_died_first = self.sister_died_first or event == "sister_dead"
                self._death()
            elif event == "die":
                self.state = BondState.AWAIT_SISTER_DEATH  # StartDying()
                self._cancel("heartbeat")
                self._timeout("disconnect", self.disconnect_timeout)
                self._timer("dead_publishing", self.dead_publish_period, self._do_publishing)
        elif state is BondState.AWAIT_SISTER_DEATH and event in ("sister_dead", "disconnect_timeout"):
            self.state = BondState.DEAD
            self._death()

    def _connected(self, state: BondState) -> None:
        self.state = state
        self._cancel("connect")
        if self.on_formed is not None:
            self.on_formed()

    def _death(self) -> None:
        self._cancel("heartbeat")
        self._cancel("disconnect")
        if self.on_broken is not None:
            self.on_broken()

    # --- plumbing ---------------------------------------------------------------------------

    def _publish(self, active: bool) -> None:
        msg = self._status()
        msg.header.stamp = self._steady.now().to_msg()
        msg.id, msg.instance_id, msg.active = self.id, self.instance_id, active
        msg.heartbeat_timeout, msg.heartbeat_period = float(self.heartbeat_timeout), float(self.heartbeat_period)
        self._pub.publish(msg)

    def _timer(self, name: str, period: float, callback: Callable[[], None]) -> None:
        """(Re)start a steady-clock timer, as bondcpp's wall timers."""
        self._cancel(name)
        self._timers[name] = self.node.create_timer(period, callback, clock=self._steady)

    def _timeout(self, name: str, period: float) -> None:
        """(Re)start the ``name`` time-out: ``_on_timeout(name)`` after ``period``."""
        self._timer(name, period, lambda: self._on_timeout(name))

    def _cancel(self, name: str) -> None:
        timer = self._timers.pop(name, None)
        if timer is not None:
            timer.cancel()
            self._spent.append(timer)
