"""SIGINT and SIGTERM as a flag the node's own loop checks, so that it can still publish before it exits.

rclpy's handlers shut the context down at once (too late to command zero velocity); Python's default raises
KeyboardInterrupt wherever the main thread is, inside rclpy's C++ too, where it surfaces as a RuntimeError from
pybind11 instead. A flag set by the handler and read between callbacks does neither.

And rclpy's handlers can lose a SIGTERM: their thread wakes the executor, then shuts the context down. An executor
that wakes, finds the context still up and waits again before the shutdown lands waits on a context nobody wakes
any more: forever, if no timer or message comes (a node on /clock whose sim has stopped). Under load, 1 to 4 in
100 bare ``rclpy.spin`` processes hung so (``bench/sigterm_race.py``); a detector did in stop 46's CI. ``spin`` waits at
most ``period`` at a time and reads the flag between waits.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["ShutdownFlag", "spin"]


class ShutdownFlag:
    """Set by SIGINT or SIGTERM (installed even where the shell left SIGINT ignored, as for background jobs)."""

    def __init__(self) -> None:
        self.event = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)

    def _on_signal(self, _signum: int, _frame: Any) -> None:
        self.event.set()

    def __bool__(self) -> bool:
        return self.event.is_set()


def spin(executor: Any, stop: ShutdownFlag, period: float = 0.1, each: Callable[[], None] | None = None) -> None:
    """Serve ``executor``'s callbacks until SIGINT or SIGTERM (``stop``) or the context's shutdown, waiting at most
    ``period`` seconds at a time; ``each`` is called after every wait."""
    from rclpy.executors import ExternalShutdownException  # type: ignore[import-not-found, unused-ignore]
    from rclpy.impl.implementation_singleton import (  # type: ignore[import-not-found, unused-ignore]
        rclpy_implementation as impl,
    )

    # Another thread may shut the context down (the detector's worker, on its failure): during a wait, or while the
    # next wait set is made ("the given context is not valid"). Either way the spin is over, not failed.
    try:
        while executor.context.ok() and not stop:
            executor.spin_once(timeout_sec=period)
            if each is not None:
                each()
    except ExternalShutdownException:
        pass
    except impl.RCLError:
        if executor.context.ok():
            raise
