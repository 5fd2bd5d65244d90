"""Run a ROS 2 graph where its traffic cannot leave this machine: a private network namespace with only loopback.

DDS discovers peers by multicast on every interface. Each graph runs inside ``unshare --net`` (a fresh network
namespace whose only interface is ``lo``, brought up first), with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and
a ``ROS_DOMAIN_ID`` of its own; every process the graph starts inherits the namespace. The test process itself
stays outside: it starts one driver script in the namespace and reads what the script prints (JSON lines).

The domain ID must be unique on the machine, not only in the namespace: Fast DDS's shared-memory transport names
its ports in /dev/shm by domain and participant (``fastdds_port<N>``), and /dev/shm is not namespaced. Two graphs
on one domain at once (the two pytest-xdist workers, a benchmark beside the tests) would share those ports. So
each graph holds a lock on its domain ID (``claim_domain_id``) for as long as it runs.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pytest

__all__ = [
    "GraphRun",
    "can_isolate",
    "claim_domain_id",
    "graph_environment",
    "needs_graph",
    "rerun_in_private_network",
    "run_private_graph",
]

# ROS 2's safe domain IDs on Linux (0-101, 215-232: their ports stay clear of the ephemeral range), without the
# default 0 and its neighbours a user's own graph may be on.
_DOMAIN_IDS = [*range(10, 102), *range(215, 233)]


@contextlib.contextmanager
def claim_domain_id() -> Iterator[int]:
    """A ROS_DOMAIN_ID no other graph on this machine holds (an exclusive lock on a file in the temp folder, let go
    when the block ends, or when the process dies); where to start looking is spread by the process ID."""
    folder = Path(tempfile.gettempdir()) / "monodock-ros-domains"
    folder.mkdir(exist_ok=True)
    start = os.getpid() % len(_DOMAIN_IDS)
    for i in range(len(_DOMAIN_IDS)):
        domain = _DOMAIN_IDS[(start + i) % len(_DOMAIN_IDS)]
        with open(folder / f"{domain}.lock", "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                continue
            yield domain
            return
    raise RuntimeError(f"every ROS domain ID is held by another graph ({folder})")


@functools.cache  # asked at the import of every graph test module
def can_isolate() -> bool:
    """Whether this machine can make a private network namespace (unshare and ip exist, and it is allowed)."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    done = subprocess.run([*_unshare(), "sh", "-c", "ip link set lo up"], capture_output=True, timeout=20, check=False)
    return done.returncode == 0


def needs_graph(*modules: str) -> pytest.MarkDecorator:
    """A test's (or, as ``pytestmark``, a module's) skip where no ROS graph can run here: no private network
    namespace, no rclpy, or one of ``modules`` (interface packages: nav2_msgs, bond...) not built. In CI the first
    two are failures, not skips (tests/ros/test_graph.py)."""
    import importlib.util

    import pytest

    missing = [name for name in ("rclpy", *modules) if importlib.util.find_spec(name) is None]
    if not can_isolate():
        return pytest.mark.skipif(True, reason="no private network namespace on this machine")
    if "rclpy" in missing:
        return pytest.mark.skipif(True, reason="ROS 2 (rclpy) is not installed")
    return pytest.mark.skipif(bool(missing), reason=f"{', '.join(missing)} not built here")


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
    with claim_domain_id() as domain:
        return _run(script, args, timeout, env, domain)


def graph_environment(domain: int) -> dict[str, str]:
    """This process's environment with what every graph's processes get: discovery on localhost only, the domain
    ``domain``, Fast DDS, unbuffered output, and Python's stacks on SIGABRT."""
    return dict(os.environ) | {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_DOMAIN_ID": str(domain),
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "PYTHONUNBUFFERED": "1",
        # A node that hangs is ended with SIGABRT (graph_processes.stop_nodes): its threads' stacks go to its log.
        "PYTHONFAULTHANDLER": "1",
    }


def _in_namespace(script: Path | str, args: Sequence[str]) -> list[str]:
    """``python script args...`` in a fresh network namespace whose loopback is up."""
    return [*_unshare(), "sh", "-c", 'ip link set lo up && exec "$@"', "sh", sys.executable, str(script), *args]


def rerun_in_private_network(script: Path | str, args: Sequence[str]) -> int:
    """Run ``python script --inside args...`` in a private network namespace with a domain of its own, its output
    this process's own (a benchmark that runs its graph itself); its exit code, or 2 where no such namespace can be
    made (said in one line: no ROS graph may run outside one)."""
    if not can_isolate():
        print(
            f"{Path(script).name}: error: this machine cannot make a private network namespace (unshare --net); "
            "no ROS graph may run",
            file=sys.stderr,
        )
        return 2
    with claim_domain_id() as domain:  # no other graph on this machine on it, the tests' included
        command = _in_namespace(script, ["--inside", *args])
        return subprocess.run(command, env=graph_environment(domain), check=False).returncode


def _run(
    script: Path | str, args: tuple[str, ...], timeout: float, env: dict[str, str] | None, domain: int
) -> GraphRun:
    environment = graph_environment(domain) | (env or {})
    command = _in_namespace(script, args)
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
