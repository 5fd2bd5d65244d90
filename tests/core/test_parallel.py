"""core.parallel: workers where they pay, inline where they would cost more than the tasks."""

from __future__ import annotations

import os

from monodock.core.parallel import map_stream, map_with_state
from shared import worker_pid


def test_one_task_runs_inline_whatever_the_jobs() -> None:
    assert list(map_with_state(worker_pid, None, [0], jobs=2)) == [os.getpid()]
    assert list(map_stream(worker_pid, None, iter([0]), jobs=2)) == [os.getpid()]


def test_a_stream_shorter_than_inline_below_runs_inline_and_a_longer_one_in_workers() -> None:
    assert list(map_stream(worker_pid, None, iter(range(3)), jobs=2, inline_below=4)) == [os.getpid()] * 3
    pids = list(map_stream(worker_pid, None, iter(range(4)), jobs=2, inline_below=4))
    assert len(pids) == 4
    assert os.getpid() not in pids
