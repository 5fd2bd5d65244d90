"""Sweeps on a Dask cluster: ``--cluster ADDRESS`` (a running scheduler) or ``--cluster auto`` (one on this machine).

A command runs inside ``cluster_session``; while one is open, ``compute.parallel.map_with_state`` (dock-sim, the
robustness sweep, rendering, labelling) sends its tasks to the cluster instead of a local pool, and the trainer's
model selection runs on joblib's ``dask`` backend. Without ``--cluster`` nothing here runs, and Dask (the optional
``cluster`` extra) is never imported: it is loaded inside the functions below, only when a cluster is asked for
(the robot side never loads it: .importlinter forbids it ``monodock.compute``, this subpackage).

What the cluster changes is where a task runs, never what it computes: every task carries its own seed (from the
sweep's seed and the task's index, never from a worker), so the same sweep gives identical results locally and
on the cluster (tests/compute/test_cluster.py, against a real scheduler and two workers). docs/cluster.md tells how
to start one and what it costs.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import pickle
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError
from contextlib import contextmanager
from typing import Any, TypeVar

import cv2

from monodock.core.interrupt import sigint_blocked
from monodock.errors import InputError, MonodockError

S = TypeVar("S")
T = TypeVar("T")
R = TypeVar("R")

__all__ = ["CONNECT_TIMEOUT_S", "MISSING_EXTRA", "active_client", "cluster_map", "cluster_session"]

MISSING_EXTRA = "--cluster needs the cluster extra: pip install 'monodock[cluster]'"
# How long a scheduler (and then its first worker) may take to answer before --cluster ADDRESS is refused.
CONNECT_TIMEOUT_S = 5.0
_SCHEMES = ("tcp://", "tls://", "inproc://", "ucx://", "ws://", "wss://")

_client: Any = None


def active_client() -> Any | None:
    """The Dask client of the open ``cluster_session``, or None (the local cores)."""
    return _client


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _version() -> str:
    # The package is loaded before any of its modules (this one included), on a worker as here.
    return str(sys.modules["monodock"].__version__)


def _monodock_version() -> str:
    """Runs on each worker: the monodock it imports (the function itself only unpickles where monodock does)."""
    return _version()


def _check_workers(client: Any, address: str) -> None:
    """At least one worker, each importing this monodock; a warning for workers with several threads."""
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except (TimeoutError, OSError):
        raise InputError(
            f"--cluster {address}: the scheduler has no workers (start some: dask worker {address} --nthreads 1)"
        ) from None
    try:
        versions = client.run(_monodock_version)
    except Exception as exc:  # unpickling the probe on a worker fails there when monodock is not installed
        raise InputError(
            f"--cluster {address}: the workers cannot import monodock ({type(exc).__name__}: {exc}); install it "
            "on every worker machine"
        ) from None
    other = {w: v for w, v in versions.items() if v != _version()}
    if other:
        w, v = next(iter(other.items()))
        raise InputError(
            f"--cluster {address}: worker {w} runs monodock {v}, this is {_version()}: install the same "
            "version everywhere"
        )
    threads = {w: n for w, n in client.nthreads().items() if n > 1}
    if threads:
        logging.getLogger("monodock").warning(
            "%d of the cluster's workers run several threads: the sweeps' tasks share a worker's state and are "
            "CPU-bound Python; start workers with --nthreads 1 (--nworkers per core)",
            len(threads),
        )


def _connect(address: str, workers: int | None) -> tuple[Any, Any]:
    """(client, cluster or None) for ``address``; InputError, at once or after the timeout, when it cannot be had."""
    try:
        import distributed
    except ImportError:
        raise InputError(MISSING_EXTRA) from None
    if address == "auto":
        # SIGINT ignored while the workers start, so that they ignore it all their life: a Ctrl-C reaches only this
        # process, which cancels the work and closes the cluster (core.interrupt.sigint_blocked).
        # The workers' own log (a task's error, which the command reports itself) stays off the user's terminal.
        try:
            with sigint_blocked():
                cluster = distributed.LocalCluster(
                    n_workers=workers or _cores(),
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address=None,
                    silence_logs=logging.CRITICAL,
                )
        except (OSError, TimeoutError, RuntimeError) as exc:
            why = " ".join(str(exc).split()) or type(exc).__name__
            raise MonodockError(f"--cluster auto: the local Dask cluster did not start ({why})") from None
        try:
            return distributed.Client(cluster, timeout=CONNECT_TIMEOUT_S * 2), cluster
        except BaseException:
            cluster.close()
            raise
    if workers is not None:
        raise InputError("--jobs sets the workers of --cluster auto; a running cluster has its own (drop --jobs)")
    if not address.startswith(_SCHEMES) or address.rstrip("/").endswith("://"):
        raise InputError(f"--cluster: expected tcp://HOST:PORT of a Dask scheduler, or auto; got '{address}'")
    try:
        client = distributed.Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=True)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"--cluster {address}: no Dask scheduler answered ({why})") from None
    try:
        _check_workers(client, address)
    except BaseException:
        client.close()
        raise
    return client, None


@contextmanager
def cluster_session(address: str | None, *, workers: int | None = None) -> Iterator[Any | None]:
    """Within it, the sweeps run on the Dask cluster at ``address`` ("auto": a local one of ``workers`` processes,
    default the cores); with None, on the local cores as always. Yields the client (or None)."""
    global _client  # noqa: PLW0603 - one cluster per command, set here and read by map_with_state and train
    if address is None:
        yield None
        return
    # Dask's own log lines (a worker that left, a connection closed at shutdown) are not the user's business.
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        client, cluster = _connect(address, workers)
        try:
            _client = client
            yield client
        finally:
            _client = None
            client.close(timeout=CONNECT_TIMEOUT_S)
            if cluster is not None:
                cluster.close(timeout=CONNECT_TIMEOUT_S)
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


_worker_ready = False
# glibc's mallopt parameters, and the ceiling of its own dynamic mmap threshold (64-bit); the trim threshold is
# twice that, as glibc sets it.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX = -1, -3, 32 << 20


def _prepare_worker() -> None:
    """Once per worker process: OpenCV on one thread (the workers fill the cores), as in the local pool; and glibc's
    malloc as in a plain process.

    Dask's nanny starts each worker with MALLOC_TRIM_THRESHOLD_=65536, which also freezes glibc's mmap threshold at
    128 KiB: every image buffer of the renderer is then mmapped, faulted in and unmapped again, frame after frame
    (measured: 2.8 s of system time on top of 5.2 s of user time per docking run). Larger thresholds put them back
    on the heap.
    """
    cv2.setNumThreads(1)
    if "MALLOC_TRIM_THRESHOLD_" in os.environ and sys.platform == "linux":
        with contextlib.suppress(OSError, AttributeError):  # not glibc: nothing to undo
            libc = ctypes.CDLL("libc.so.6")
            libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX)
            libc.mallopt(_M_TRIM_THRESHOLD, 2 * _MMAP_THRESHOLD_MAX)


def _call(fn: Callable[[S, T], R], state: S, task: T) -> R:
    """One task on a worker."""
    global _worker_ready  # noqa: PLW0603 - once per worker process
    if not _worker_ready:
        _prepare_worker()
        _worker_ready = True
    return fn(state, task)


def cluster_map(fn: Callable[[S, T], R], state: S, tasks: list[T]) -> Iterator[R]:
    """``fn(state, task)`` for every task on the open session's cluster; results in order, as they are ready.

    ``state`` is sent once to every worker; a window of twice the cluster's threads is in
    flight at a time, so that memory stays flat however many tasks. A worker that dies is replaced and its task
    run again by Dask (up to the scheduler's ``allowed-failures``, then a one-line error); leaving early (Ctrl-C,
    an error) cancels whatever was submitted.
    """
    from distributed import KilledWorker

    client = _client
    if client is None:
        raise RuntimeError("cluster_map needs an open cluster_session")
    name = f"monodock-{getattr(fn, '__name__', 'task')}-{time.monotonic_ns()}"
    # The state goes to the scheduler once, pickled, as a task that unpickles it: each worker gets it once (from the
    # scheduler's worker or a peer) and keeps it for all its tasks. Unlike scattered data (client.scatter), a task
    # can be run again, so a worker that dies holding the state loses nothing.
    blob = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
    shared = client.submit(pickle.loads, blob, key=f"{name}-state", pure=False)
    window = max(4, 2 * sum(client.nthreads().values()))
    todo = iter(enumerate(tasks))
    pending: deque[Any] = deque()

    def submit() -> None:
        for i, task in todo:
            pending.append(client.submit(_call, fn, shared, task, key=f"{name}-{i}", priority=-i, pure=False))
            return

    try:
        for _ in range(window):
            submit()
        while pending:
            future = pending[0]
            try:
                result = future.result()
            except KilledWorker:
                raise MonodockError(
                    f"a Dask worker died running task {future.key.rsplit('-', 1)[-1]} of {len(tasks)}, each time it "
                    "was tried; see the workers' logs (out of memory?)"
                ) from None
            except CancelledError:
                raise MonodockError("lost the Dask scheduler mid-sweep (it stopped, or the network did)") from None
            pending.popleft()
            submit()
            yield result
    finally:
        if pending:
            client.cancel(list(pending), force=True)
        pending.clear()
        client.cancel([shared], force=True)
