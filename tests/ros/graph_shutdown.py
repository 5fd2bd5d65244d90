"""Driver (tests/ros/test_shutdown_graph.py, inside a private network namespace): ``monodock.ros.shutdown.spin``
on an idle node (nothing to wake it: no timer, no message), ended as rclpy's SIGTERM handling can end a process.

rclpy's signal thread wakes the executor and then shuts the context down, without waking it again. Phase
``woken, then shut down``: a thread wakes the executor, waits 0.3 s (the executor is waiting again by then) and shuts
the context down as rclpy's signal thread does (``rcl_shutdown``, no Python callbacks). Phase ``shut down by another
thread``: ``rclpy.try_shutdown()`` from a thread, as the detector's worker does on a failure. Phase ``SIGTERM``: this
process sends itself SIGTERM. Phase ``SIGINT``: the same with SIGINT. Each prints how long ``spin`` took to return
after the last event (or that it had not returned after 5 s).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from monodock.ros.shutdown import ShutdownFlag, spin

stop = ShutdownFlag()


def woken_then_shut_down(executor: SingleThreadedExecutor) -> None:
    executor.wake()
    time.sleep(0.3)
    rclpy.get_default_context().handle.shutdown()  # rcl_shutdown, as rclpy's signal thread: no Python callbacks


def phase(name: str, end: object) -> None:
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("idle")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spins = [0]
    last: list[float] = []

    def act() -> None:
        time.sleep(0.55)  # the executor is halfway through a wait (they are 0.1 s)
        if callable(end):
            end(executor)
        else:
            os.kill(os.getpid(), end)
        last.append(time.monotonic())

    threading.Thread(target=act, daemon=True).start()

    def watchdog() -> None:
        print(json.dumps({"kind": "phase", "name": name, "returned": False}), flush=True)
        os._exit(0)

    guard = threading.Timer(5.5, watchdog)  # 5 s after the event
    guard.daemon = True
    guard.start()
    spin(executor, stop, each=lambda: spins.__setitem__(0, spins[0] + 1))
    guard.cancel()
    after = time.monotonic() - last[-1] if last else None
    print(json.dumps({"kind": "phase", "name": name, "returned": True, "after": after, "spins": spins[0]}), flush=True)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    stop.event.clear()


phase("woken, then shut down", woken_then_shut_down)
phase("shut down by another thread", lambda _executor: rclpy.try_shutdown())  # the detector's worker on a failure
phase("SIGTERM", signal.SIGTERM)
phase("SIGINT", signal.SIGINT)
sys.exit(0)
