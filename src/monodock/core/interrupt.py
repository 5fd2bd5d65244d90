"""SIGINT and SIGTERM as exceptions, so that every ``finally`` and context manager cleans up (temp folders,
worker pools), and worker processes that leave the stopping to their parent.

A Ctrl-C in a terminal goes to the whole process group: workers would each print their own KeyboardInterrupt
traceback (or die half-way through starting). Workers are therefore started with SIGINT ignored
(``sigint_blocked``: inherited across fork and exec, from the first instruction of the new interpreter), and
the parent, which gets the signal too, terminates them.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

__all__ = [
    "GRACE_S",
    "HeldSignals",
    "Terminated",
    "exit_on_signal",
    "install_signal_handlers",
    "received",
    "sigint_blocked",
]

# A second signal this soon after the first is ignored: the clean-up the first one started must finish.
GRACE_S = 5.0


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C's KeyboardInterrupt (and handled wherever that is)."""


_first_signal: float | None = None
_received: int | None = None


def _on_signal(signum: int, _frame: FrameType | None) -> None:
    global _first_signal, _received  # noqa: PLW0603 - one process, one pair of handlers
    now = time.monotonic()
    if _first_signal is not None and now - _first_signal < GRACE_S:
        return
    _first_signal = now
    _received = _received or signum
    if signum == signal.SIGTERM:
        raise Terminated
    raise KeyboardInterrupt


def install_signal_handlers() -> None:
    """SIGINT raises KeyboardInterrupt, SIGTERM raises Terminated, in the main thread (installed even where the
    shell left SIGINT ignored); a repeat within GRACE_S of the first is ignored so that the clean-up completes."""
    global _first_signal, _received  # noqa: PLW0603
    _first_signal = _received = None
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)


def received() -> KeyboardInterrupt | None:
    """The interrupt of the first SIGINT or SIGTERM since ``install_signal_handlers``, or None.

    A library that runs Python code under its own C++ may catch the KeyboardInterrupt raised there and raise its
    own error instead (ONNX Runtime's "model cannot be loaded" while ``train`` moves its bundle into place): the
    CLI asks this to tell the user the command was interrupted, not that the input was bad.
    """
    if _received is None:
        return None
    return Terminated() if _received == signal.SIGTERM else KeyboardInterrupt()


def exit_on_signal(message: str) -> None:
    """Once the command has finished (its outputs complete): SIGINT or SIGTERM print one line and exit at once,
    130 or 143, instead of raising into the interpreter's shutdown (where the exception is only printed, with a
    traceback, and the exit is slow or 0)."""

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        name = "SIGTERM" if signum == signal.SIGTERM else "SIGINT"
        print(message.format(signal=name), file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(128 + signum)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)


@contextmanager
def sigint_blocked() -> Iterator[None]:
    """SIGINT ignored while worker processes start, so that they ignore it all their life.

    An ignored signal stays ignored across fork and exec, and a Python that starts with SIGINT ignored installs no
    KeyboardInterrupt handler: a Ctrl-C, which goes to the whole process group, reaches only this process (which
    stops the workers). Meanwhile SIGINT is also blocked in this thread: one that arrives is kept pending (Linux
    never drops a blocked signal as ignored) and delivered when the block ends.
    """
    previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)


class HeldSignals:
    """Ctrl-C and SIGTERM held while worker processes start, until ``release()``: SIGINT ignored and blocked as
    ``sigint_blocked`` does (the workers inherit the ignoring), and SIGTERM only noted, then raised by ``release()``
    through the handler it had (main thread only, as ``signal.signal`` is).

    Why SIGTERM too: a spawned worker first reads what its parent sends it over a pipe; SIGTERM raised in the parent
    between the worker's start and that write left the worker to die of ``EOFError`` with a traceback on the user's
    terminal (CI caught it). Held, it is raised once every worker has what it needs and the caller's clean-up is in
    place. It is noted by a handler, not blocked: a process-directed signal goes to any thread that does not block
    it (OpenCV's and BLAS's included), and only the handler runs in the main thread whichever thread took it. The
    workers start with SIGTERM's default action (a handler is not inherited across exec), so terminate ends them.
    """

    def __init__(self) -> None:
        self._noted: list[int] = []
        self._mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        self._sigint = signal.signal(signal.SIGINT, signal.SIG_IGN)
        self._sigterm = signal.signal(signal.SIGTERM, self._note)
        self._held = True

    def _note(self, signum: int, _frame: FrameType | None) -> None:
        self._noted.append(signum)

    def release(self) -> None:
        """The handlers and the mask as they were; a SIGINT or SIGTERM held meanwhile is raised here. Once only."""
        if not self._held:
            return
        self._held = False
        signal.signal(signal.SIGINT, self._sigint)
        signal.signal(signal.SIGTERM, signal.SIG_DFL if self._sigterm is None else self._sigterm)
        signal.pthread_sigmask(signal.SIG_SETMASK, self._mask)
        if self._noted:
            signal.raise_signal(signal.SIGTERM)
