"""The graph drivers' node processes (tests/ros/graph_dock*.py): how they start and how they end; and what the
drivers that are clients themselves share: a spinning executor, waiting, printing a record.

Each node gets SIGTERM when its driver ends, however the driver ends (PR_SET_PDEATHSIG): none outlives its run.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

ORPHANS_END = "import ctypes, signal; ctypes.CDLL(None).prctl(1, signal.SIGTERM); "
SIM = ORPHANS_END + "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv)"
DOCK = ORPHANS_END + "from monodock.cli.ros_nodes import dock_main; import sys; sys.exit(dock_main(sys.argv[1:]))"


def stop_nodes(*processes: subprocess.Popen[bytes]) -> None:
    """SIGINT to each node still running, then wait for all. A node that will not end has its native stacks written
    to this driver's stderr (``native_stacks``), then gets SIGABRT (exit code -6), which with PYTHONFAULTHANDLER
    (tests/private_graph.py) writes every thread's Python stack to its log, where it hung; then, if even that does
    not end it, SIGKILL (-9)."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            # Generous: on a starved CI host a node's DDS teardown after SIGINT took over 20 s once (stop 33's CI).
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            print(native_stacks(process.pid), file=sys.stderr, flush=True)
            abort(process)


def end_nodes(processes: Mapping[str, subprocess.Popen[str]], timeout: float) -> dict[str, str]:
    """SIGTERM to every node at once, each one's piped stderr read to its end meanwhile (one reader per node: a
    node blocked on a full pipe while another is waited for would look hung), and their logs by name. A node still
    running ``timeout`` seconds after the signal is a failure the test reports with where it hung: its native stacks
    (gdb) and, after SIGABRT, its Python stacks (PYTHONFAULTHANDLER) are added to its log, then it is ended."""
    logs: dict[str, str] = {}

    def read(name: str, process: subprocess.Popen[str]) -> None:
        logs[name] = process.stderr.read() if process.stderr is not None else ""

    readers = [threading.Thread(target=read, args=item) for item in processes.items()]
    for process in processes.values():
        if process.poll() is None:
            process.terminate()
    for reader in readers:
        reader.start()
    end = time.monotonic() + timeout
    hung: dict[str, str] = {}
    for name, process in processes.items():
        try:
            process.wait(timeout=max(end - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            hung[name] = native_stacks(process.pid)
            abort(process)
    for reader in readers:
        reader.join(timeout=10)
    logs = {name: logs.get(name, "(its log was still being read 10 s after it ended)") for name in processes}
    for name, stacks in hung.items():
        # The log last: its end is the Python stacks SIGABRT wrote, which a driver's trimmed copy must keep.
        said = f"still running {timeout:g} s after SIGTERM; its native stacks:\n{stacks}\n"
        logs[name] = f"{said}its log, ending with its Python stacks:\n{logs.get(name, '')}"
    return logs


def abort(process: subprocess.Popen[Any]) -> None:
    """SIGABRT (its Python stacks to its log, with PYTHONFAULTHANDLER), then SIGKILL if even that does not end it."""
    process.send_signal(signal.SIGABRT)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def native_stacks(pid: int) -> str:
    """Every thread's C/C++ stack of a live process (gdb, where installed): where a node hangs below Python."""
    gdb = shutil.which("gdb")
    if gdb is None:
        return "(no gdb on this machine: no native stacks)"
    try:
        command = [gdb, "-p", str(pid), "-batch", "-ex", "thread apply all bt"]
        done = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
    except subprocess.TimeoutExpired:
        return "(gdb took over 60 s: no native stacks)"
    # A thread's innermost frames say where it waits; its outer ones (Python's eval loop) would crowd out the rest.
    lines = [line for line in done.stdout.splitlines() if line.startswith(("Thread", "#"))]
    return "\n".join(line for line in lines if not line.startswith("#") or int(line[1:].split()[0]) < 12)


def emit(kind: str, /, **values: Any) -> None:
    """One JSON record on stdout, for the test (tests/private_graph.py's GraphRun)."""
    print(json.dumps({"kind": kind, **values}), flush=True)


def wait(done: Callable[[], Any], seconds: float) -> bool:
    """Whether ``done()`` came true within ``seconds`` (something else spins meanwhile)."""
    end = time.monotonic() + seconds
    while not done() and time.monotonic() < end:
        time.sleep(0.01)
    return bool(done())


class Spinner:
    """A driver's node served by a single-threaded executor in a thread and a loop of its own, which ``stop`` ends
    before the executor is shut down (a thread still inside ``spin()`` when the process exits aborts it). The
    driver's main thread waits on what the callbacks gather (``wait``); no callback may block. Single-threaded on
    purpose: rclpy's multi-threaded executor costs several times the CPU per message, which a 50 Hz robot's topics
    turn into most of a core taken from the nodes under test."""

    def __init__(self, node: Any) -> None:
        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self._running = threading.Event()
        self._running.set()
        self._thread = threading.Thread(target=self._spin)
        self._thread.start()

    def _spin(self) -> None:
        while self._running.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def stop(self) -> None:
        self._running.clear()
        self._thread.join(timeout=10)
        self.executor.shutdown()
