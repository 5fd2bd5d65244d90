"""Worker processes for CPU-bound work (rendering): fresh processes, one thread each.

Why not fork: forking a process whose BLAS or OpenMP thread pools are running can leave a lock held in
the child, which then hangs for ever (it happened in CI, in the child's first call into OpenBLAS). Spawned
workers start clean. Why one thread each: the workers already fill the cores, and BLAS or OpenCV threads
inside each only contend (measured: 2 workers with threaded BLAS were 2.3x slower than 1 process).
"""

from __future__ import annotations

import multiprocessing as mp
import multiprocessing.pool
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["SINGLE_THREAD_ENV", "worker_pool"]

# Read by OpenBLAS, OpenMP and MKL when the worker imports numpy: it must be set before that import.
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _start_worker(initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
    import cv2

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
    try:
        # The workers are started here, and take the environment as it is now.
        pool = mp.get_context("spawn").Pool(jobs, initializer=_start_worker, initargs=(initializer, initargs))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    with pool:
        yield pool
