"""SIGINT and SIGTERM as a flag the node's own loop checks, so that it can still publish before it exits.

rclpy's handlers shut the context down at once (too late to command zero velocity); Python's default raises
KeyboardInterrupt wherever the main thread is, inside rclpy's C++ too, where it surfaces as a RuntimeError from
pybind11 instead. A flag set by the handler and read between callbacks does neither.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

__all__ = ["ShutdownFlag"]


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
