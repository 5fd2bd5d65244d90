"""Run a ROS 2 graph where its traffic cannot leave this machine: a private network namespace with only loopback.

DDS discovers peers by multicast on every interface. Each graph runs inside ``unshare --net`` (a fresh network
namespace whose only interface is ``lo``, brought up first), with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and
a ``ROS_DOMAIN_ID`` of its own; every process the graph starts inherits the namespace. The test process itself
stays outside: it starts one driver script in the namespace and reads what the script prints (JSON lines).
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["GraphRun", "can_isolate", "run_private_graph"]

_DOMAIN_IDS = itertools.count(101 + os.getpid() % 60)  # 101-232: clear of the default 0 and of other runs


def can_isolate() -> bool:
    """Whether this machine can make a private network namespace (unshare and ip exist, and it is allowed)."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    done = subprocess.run([*_unshare(), "sh", "-c", "ip link set lo up"], capture_output=True, timeout=20, check=False)
    return done.returncode == 0


def _unshare() -> list[str]:
    return ["unshare", "--net"] if os.geteuid() == 0 else ["unshare", "--net", "--map-root-user"]


class GraphRun:
    """What a driver script printed: one JSON object per line, and its exit code and stderr."""

    def __init__(self, returncode: int, stdout: str, stderr: str) -> None:
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr
        self.records: list[dict[str, Any]] = []
        for line in stdout.splitlines():
            if line.startswith("{"):
                self.records.append(json.loads(line))

    def first(self, kind: str) -> dict[str, Any]:
        return next(r for r in self.records if r.get("kind") == kind)

    def all(self, kind: str) -> list[dict[str, Any]]:
        return [r for r in self.records if r.get("kind") == kind]


def run_private_graph(
    script: Path | str, *args: str, timeout: float = 240.0, env: dict[str, str] | None = None
) -> GraphRun:
    """Run ``python script args...`` in a private network namespace with loopback only; its own ROS_DOMAIN_ID."""
    environment = dict(os.environ)
    environment.update(
        {
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            "ROS_DOMAIN_ID": str(next(_DOMAIN_IDS)),
            "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
            "PYTHONUNBUFFERED": "1",
            # A node that hangs is ended with SIGABRT (graph_processes.stop_nodes): its threads' stacks go to its log.
            "PYTHONFAULTHANDLER": "1",
        }
    )
    environment.update(env or {})
    inner = 'ip link set lo up && exec "$@"'
    command = [*_unshare(), "sh", "-c", inner, "sh", sys.executable, str(script), *args]
    # A session of its own: on a time-out the whole graph (driver and the nodes it started) is killed, not only
    # the driver, and what it printed so far is kept for the failure message.
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment, start_new_session=True
    )
    try:
        stdout, stderr = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        return GraphRun(-9, stdout, f"timed out after {timeout:.0f} s\n{stderr}")
    except BaseException:  # pytest-timeout, Ctrl-C: the graph goes with the test
        os.killpg(process.pid, signal.SIGKILL)
        raise
    return GraphRun(process.returncode, stdout, stderr)
