"""Tasks that tests/compute/test_cluster.py sends to a real Dask cluster: module-level, so that the workers (whose
PYTHONPATH holds src/ and tests/) import them by name, as they do monodock's own."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np


def seeded_draw(state: tuple[int, str], task: int) -> tuple[int, float, int]:
    """(task, a draw seeded by the sweep's seed and the task alone, the shared state's length)."""
    seed, blob = state
    return task, float(np.random.default_rng([seed, task]).normal()), len(blob)


def die_once(marker: str, task: int) -> int:
    """Task 3 kills its worker process the first time it runs (the marker file remembers); the rest square."""
    if task == 3 and not Path(marker).exists():
        Path(marker).write_text("died")
        os._exit(1)
    return task * task


def always_die(_state: None, _task: int) -> int:
    os._exit(1)


def slow(_state: None, task: int) -> int:
    time.sleep(0.5)
    return task


def scheduler_tasks(dask_scheduler: object) -> int:
    """Runs on the scheduler: how many tasks it still holds."""
    return len(dask_scheduler.tasks)  # type: ignore[attr-defined]
