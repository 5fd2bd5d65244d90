"""What makes a monodock node a Nav2 lifecycle node (``nav2_util::LifecycleNode``, Kilted): a bond to the lifecycle
manager while active, and ``autostart_node``.

``nav2_lifecycle_manager`` configures and activates the nodes it manages (``node_names``) through their
``change_state`` services, and after each activation waits ``bond_timeout``/2 (2 s by default) for a bond with it
to form (``lifecycle_manager.cpp``, ``createBondConnection``); a node that forms none fails the whole bring-up, and one
whose heartbeats stop for ``bond_timeout`` brings the other nodes down. So a managed node creates its side of the
bond in ``on_activate`` and destroys it in ``on_deactivate``, as ``nav2_util::LifecycleNode`` does: topic ``bond``,
its id the node's name, a heartbeat every ``bond_heartbeat_period`` (0.1 s; 0 makes no bond), a heartbeat time-out
of 4 s that is disabled on this side (the node never gives up on its manager).

``autostart_node`` (Nav2's parameter): configure and activate at start, for a node that runs with no manager.
"""

from __future__ import annotations

from typing import Any

from monodock.core.settings import setting
from monodock.ros.bond import Bond

__all__ = ["ManagerBond", "autostart", "autostart_setting", "bond_heartbeat_setting"]


def autostart_setting(default: bool, **meta: Any) -> Any:
    """A managed node's ``autostart_node`` setting (its default the node's; ``meta``: its flag, as ``setting``)."""
    return setting(
        default,
        **meta,
        help="configure and activate at start (a node with no lifecycle manager); false: unconfigured until a "
        "lifecycle manager (nav2_lifecycle_manager, ros2 lifecycle set) brings it up",
    )


def bond_heartbeat_setting(**meta: Any) -> Any:
    """A managed node's ``bond_heartbeat_period`` setting (``meta``: its flag, as ``setting``)."""
    return setting(
        0.1,
        **meta,
        range=(0.0, 10.0),
        help="s between heartbeats of the bond to nav2_lifecycle_manager while active; 0: no bond",
    )


# nav2_util::LifecycleNode::createBond's heartbeat time-out on the node's side (it is disabled there, as upstream).
NODE_HEARTBEAT_TIMEOUT = 4.0


class ManagerBond:
    """The node's side of its bond to the lifecycle manager: ``create`` on activation, ``destroy`` on deactivation."""

    def __init__(self, node: Any, heartbeat_period: float) -> None:
        self.node, self.heartbeat_period = node, heartbeat_period
        self.bond: Bond | None = None
        self._dying: list[Bond] = []  # broken bonds still saying so until the manager has heard it

    def create(self) -> None:
        """``createBond``; says once when the bond interfaces were not built (the manager will then fail bring-up)."""
        if self.heartbeat_period <= 0.0 or self.bond is not None:
            return
        self._reap()
        try:
            bond = Bond(
                self.node,
                "bond",
                self.node.get_name(),
                heartbeat_period=self.heartbeat_period,
                heartbeat_timeout=NODE_HEARTBEAT_TIMEOUT,
                disable_heartbeat_timeout=True,
            )
        except ImportError as exc:
            self.node.get_logger().error(
                f"no bond to the lifecycle manager: {exc} (the bond interfaces are built when monodock is installed; "
                "interfaces/README.md); nav2_lifecycle_manager will refuse this node"
            )
            return
        self.node.get_logger().info(f"Creating bond ({self.node.get_name()}) to lifecycle manager.")
        bond.start()
        self.bond = bond

    def destroy(self) -> None:
        """``destroyBond``: the manager hears ``active: false`` (it is published until the manager answers, or 2 s)."""
        bond, self.bond = self.bond, None
        if bond is None:
            return
        self.node.get_logger().info(f"Destroying bond ({self.node.get_name()}) to lifecycle manager.")
        bond.break_bond()
        self._dying.append(bond)

    def close(self) -> None:
        """Every bond released (the node is going away)."""
        self.destroy()
        for bond in self._dying:
            bond.destroy()
        self._dying.clear()

    def _reap(self) -> None:
        for bond in [b for b in self._dying if b.broken]:
            bond.destroy()
            self._dying.remove(bond)


def autostart(node: Any) -> None:
    """Configure and activate ``node`` (a rclpy LifecycleNode) as soon as its executor spins, as
    ``nav2_util::LifecycleNode::autostart`` does; a failure is logged, the node stays where it stopped."""
    from rclpy.lifecycle import TransitionCallbackReturn  # type: ignore[import-not-found, unused-ignore]

    timer: Any = None

    def start() -> None:
        timer.cancel()
        node.get_logger().info(f"Auto-starting node: {node.get_name()}")
        if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            node.get_logger().error(f"Auto-starting node {node.get_name()} failed to configure!")
            return
        if node.trigger_activate() != TransitionCallbackReturn.SUCCESS:
            node.get_logger().error(f"Auto-starting node {node.get_name()} failed to activate!")

    timer = node.create_timer(0.0, start)
