"""SIGTERM to a ROS 2 node that is waiting for work: how many are still running 5 s later, by how the node spins.

A node on /clock whose sim has stopped has nothing to wake it but the signal. rclpy's own SIGTERM handling wakes
the executor from another thread and then shuts the context down; an executor that wakes in between waits again,
on a context nobody wakes any more. The detector hung so in stop 46's CI (``monodock.ros.shutdown`` says more).

Kinds, each started ``--runs`` times in a private network namespace (only loopback, as the ROS tests), ``--at-once``
at a time; once all of a batch are on the graph (and a random 0-0.4 s more), all of it gets SIGTERM at once, as a
test's driver ends its graph:

- ``rclpy.spin``: a bare node, rclpy's handlers, ``rclpy.spin`` (the upstream pattern the detector used);
- ``monodock spin``: a bare node, ``ShutdownFlag`` and ``monodock.ros.shutdown.spin`` (what the nodes use now);
- ``monodock-ros``: the detector itself, on sim time with no sim (``use_sim_time:=true``, no /clock).

``--hogs`` adds one CPU-bound process per core, as a busy CI machine.

    python bench/sigterm_race.py [--runs 100] [--at-once 4] [--hogs] [--kinds rclpy.spin,monodock spin,monodock-ros]
        [--out FILE.md]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import _positive, emit, environment, markdown_table

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from private_graph import rerun_in_private_network

GRACE = 5.0  # s after SIGTERM before a node counts as hung
BARE_RCLPY = """
import rclpy
from rclpy.executors import ExternalShutdownException
rclpy.init()
node = rclpy.create_node("{name}")
try:
    rclpy.spin(node)
except (ExternalShutdownException, KeyboardInterrupt):
    pass
"""
BARE_MONODOCK = """
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from monodock.ros.shutdown import ShutdownFlag, spin
stop = ShutdownFlag()
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node("{name}")
executor = SingleThreadedExecutor()
executor.add_node(node)
spin(executor, stop)
node.destroy_node()
rclpy.try_shutdown()
"""
DETECTOR = "from monodock.cli.ros_nodes import detector_main; import sys; sys.exit(detector_main(sys.argv[1:]))"
KINDS = ("rclpy.spin", "monodock spin", "monodock-ros")


def command(kind: str, name: str, folder: Path) -> list[str]:
    if kind == "rclpy.spin":
        return [sys.executable, "-c", BARE_RCLPY.format(name=name)]
    if kind == "monodock spin":
        return [sys.executable, "-c", BARE_MONODOCK.format(name=name)]
    files = ["--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml")]
    ros = ["--ros-args", "-r", f"__node:={name}", "-p", "use_sim_time:=true"]
    return [sys.executable, "-c", DETECTOR, *files, *ros]


class Listener:
    """The graph's node names, kept fresh by a node of this process spinning in a thread."""

    def __init__(self) -> None:
        import threading

        import rclpy

        rclpy.init()
        self.node = rclpy.create_node("sigterm_race")
        self._names: set[str] = set()
        self._running = True
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()

    def _poll(self) -> None:
        while self._running:
            self._names = set(self.node.get_node_names())
            time.sleep(0.05)

    def names(self) -> set[str]:
        return self._names

    def close(self) -> None:
        import rclpy

        self._running = False
        self._thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.try_shutdown()


def batch(kind: str, first: int, count: int, folder: Path, listener: Listener) -> list[dict[str, Any]]:
    """Start ``count`` nodes, wait until all are on the graph, SIGTERM them all at once (as a test's driver ends its
    graph); for each, whether it ended within GRACE, and how."""
    names = [f"{kind.replace(' ', '_').replace('.', '_').replace('-', '_')}_{first + i}" for i in range(count)]
    processes = [
        subprocess.Popen(command(kind, name, folder), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        for name in names
    ]
    end = time.monotonic() + 120.0
    while not set(names) <= listener.names() and time.monotonic() < end:
        time.sleep(0.05)
    time.sleep(random.uniform(0.0, 0.4))
    started = [process.poll() is None for process in processes]
    for process in processes:
        process.terminate()
    deadline = time.monotonic() + GRACE
    results = []
    for process, up in zip(processes, started, strict=True):
        try:
            process.wait(timeout=max(deadline - time.monotonic(), 0.01))
            hung = False
        except subprocess.TimeoutExpired:
            hung = True
            process.kill()
            process.wait()
        err = process.stderr.read().decode(errors="replace") if process.stderr else ""
        results.append({"kind": kind, "started": up, "hung": hung, "returncode": process.returncode, "stderr": err})
    return results


def inside(args: argparse.Namespace) -> None:
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig

    folder = Path(tempfile.mkdtemp())
    DockLayout.default().save(folder / "layout.yaml")
    RobotConfig.default().save(folder / "robot.yaml")
    hogs = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(mp.cpu_count() if args.hogs else 0)
    ]
    listener = Listener()
    started = time.monotonic()
    try:
        results = []
        for first in range(0, args.runs, args.at_once):
            for kind in args.kinds:
                results += batch(kind, first, min(args.at_once, args.runs - first), folder, listener)
    finally:
        listener.close()
        for hog in hogs:
            hog.kill()
    rows = []
    for kind in args.kinds:
        mine = [r for r in results if r["kind"] == kind]
        hung = sum(r["hung"] for r in mine)
        codes = sorted({r["returncode"] for r in mine if not r["hung"]})
        rows.append([kind, str(len(mine)), f"{hung} ({hung / len(mine):.1%})", ", ".join(map(str, codes))])
    env = environment()
    report = "\n".join(
        [
            f"## SIGTERM to an idle node: hung {GRACE:g} s later ({env['date_utc']} UTC, {env['machine']}, "
            f"{'one busy process per core beside' if args.hogs else 'no load added'}, {args.at_once} at a time, "
            f"{time.monotonic() - started:.0f} s)",
            "",
            markdown_table(["kind", "runs", "hung", "exit codes of the others"], rows),
        ]
    )
    hung_logs = [r["stderr"] for r in results if r["hung"] and r["stderr"]]
    emit(report, {"environment": env, "results": results, "hung_logs": hung_logs}, args.out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=_positive, default=100, help="SIGTERMs per kind (default 100)")
    parser.add_argument("--at-once", type=_positive, default=4, help="nodes started and stopped at once (default 4)")
    parser.add_argument("--hogs", action="store_true", help="one CPU-bound process per core beside")
    parser.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated, of: {', '.join(KINDS)}")
    parser.add_argument("--out", help="also write the report here (markdown) and the raw results beside it (.json)")
    parser.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    args.kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = [k for k in args.kinds if k not in KINDS]
    if unknown or not args.kinds:
        parser.error(f"--kinds: {', '.join(unknown) or 'none given'} (one or more of: {', '.join(KINDS)})")
    if not args.inside:
        return rerun_in_private_network(__file__, sys.argv[1:])
    inside(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
