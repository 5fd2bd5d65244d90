"""Worker processes for CPU-bound work (rendering): fresh processes, one thread each.

Why not fork: forking a process whose BLAS or OpenMP thread pools are running can leave a lock held in
the child, which then hangs for ever (it happened in CI, in the child's first call into OpenBLAS). Spawned
workers start clean. Why one thread each: the workers already fill the cores, and BLAS or OpenCV threads
inside each only contend (measured: 2 workers with threaded BLAS were 2.3x slower than 1 process).
"""

from __future__ import annotations

import itertools
import multiprocessing as mp
import multiprocessing.pool
import os
import signal
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import cv2

from monodock.compute.cluster import active_client, cluster_map
from monodock.core.interrupt import HeldSignals

S = TypeVar("S")
T = TypeVar("T")
R = TypeVar("R")

__all__ = ["SINGLE_THREAD_ENV", "map_stream", "map_with_state", "worker_pool"]

# Read by OpenBLAS, OpenMP and MKL when the worker imports numpy: it must be set before that import.
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _start_worker(initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
    # The parent stops the workers (Pool.terminate) on Ctrl-C; a worker's own KeyboardInterrupt would only print
    # a traceback. SIGINT is ignored from the worker's start already (HeldSignals); this keeps it so.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    cv2.setNumThreads(1)
    if initializer is not None:
        initializer(*initargs)


@contextmanager
def worker_pool(
    jobs: int,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
) -> Iterator[multiprocessing.pool.Pool]:
    """A pool of ``jobs`` spawned, single-threaded worker processes; ``initializer(*initargs)`` runs in each."""
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    # The workers are started here, and take the environment (and the ignored SIGINT) as it is now; a Ctrl-C or
    # SIGTERM meanwhile waits until every worker has been sent what it starts from (HeldSignals says why).
    held = HeldSignals()
    try:
        try:
            pool = mp.get_context("spawn").Pool(jobs, initializer=_start_worker, initargs=(initializer, initargs))
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        # Leaving the block, by an exception (Ctrl-C, SIGTERM, an error) or not, terminates the workers at once.
        with pool:
            held.release()  # a signal held while they started is raised here, and the pool terminates
            yield pool
    finally:
        held.release()


_STATE: Any = None


def _set_state(state: Any) -> None:
    global _STATE  # noqa: PLW0603 - one copy of the shared state per worker process, sent once
    _STATE = state


def _call_with_state(args: tuple[Callable[[Any, Any], Any], Any]) -> Any:
    fn, task = args
    return fn(_STATE, task)


def map_with_state(fn: Callable[[S, T], R], state: S, tasks: list[T], *, jobs: int, chunksize: int = 2) -> Iterator[R]:
    """``fn(state, task)`` for every task, in order, in ``jobs`` workers (inline when jobs <= 1 or there is one task
    only), or on the Dask cluster of an open ``compute.cluster.cluster_session`` (``--cluster``), whatever ``jobs``.

    ``state`` (e.g. a Simulator with its world) goes to each worker once, not with every task; ``fn`` must be
    a module-level function so that it pickles. Results come back as they are ready and in order, so memory
    stays flat however many tasks.
    """
    if active_client() is not None:
        yield from cluster_map(fn, state, tasks)
        return
    if jobs <= 1 or len(tasks) <= 1:
        yield from (fn(state, t) for t in tasks)
        return
    with worker_pool(jobs, _set_state, (state,)) as pool:
        yield from pool.imap(_call_with_state, [(fn, t) for t in tasks], chunksize=chunksize)


def map_stream(
    fn: Callable[[S, T], R], state: S, tasks: Iterable[T], *, jobs: int, window: int = 0, inline_below: int = 2
) -> Iterator[R]:
    """``map_with_state`` over a stream of big tasks (e.g. images read from a recording): in order, and only
    ``window`` tasks (default 4 per worker) read ahead and in flight, so memory does not grow with the stream.

    A stream of fewer than ``inline_below`` tasks runs inline: starting the workers (~0.7 s of a core each, for
    their imports) would cost more than the tasks. (``Pool.imap`` would read the whole stream ahead.)
    """
    stream = iter(tasks)
    head = list(itertools.islice(stream, max(inline_below, 1)))
    tasks = itertools.chain(head, stream)
    if jobs <= 1 or len(head) < inline_below:
        yield from (fn(state, t) for t in tasks)
        return
    window = window or 4 * jobs
    with worker_pool(jobs, _set_state, (state,)) as pool:
        pending: deque[multiprocessing.pool.AsyncResult[R]] = deque()
        for t in tasks:
            pending.append(pool.apply_async(_call_with_state, ((fn, t),)))
            if len(pending) >= window:
                yield pending.popleft().get()
        while pending:
            yield pending.popleft().get()
