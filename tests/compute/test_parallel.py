"""compute.parallel: workers where they pay, inline where they would cost more than the tasks."""

from __future__ import annotations

import os
import subprocess
import sys

from monodock.compute.parallel import map_stream, map_with_state
from shared import worker_pid


def test_one_task_runs_inline_whatever_the_jobs() -> None:
    assert list(map_with_state(worker_pid, None, [0], jobs=2)) == [os.getpid()]
    assert list(map_stream(worker_pid, None, iter([0]), jobs=2)) == [os.getpid()]


def test_a_stream_shorter_than_inline_below_runs_inline_and_a_longer_one_in_workers() -> None:
    assert list(map_stream(worker_pid, None, iter(range(3)), jobs=2, inline_below=4)) == [os.getpid()] * 3
    pids = list(map_stream(worker_pid, None, iter(range(4)), jobs=2, inline_below=4))
    assert len(pids) == 4
    assert os.getpid() not in pids


# SIGTERM raised in the parent just after a spawned worker has started and before the parent has sent it what it
# starts from (the CI's "SIGTERM during simulate" case, made certain by raising it there).
_TERM_WHILE_A_WORKER_STARTS = """
import gc, os, signal, time
import multiprocessing.util as util
from monodock.core.interrupt import install_signal_handlers
from monodock.compute.parallel import worker_pool

install_signal_handlers()
spawn = util.spawnv_passfds

def spawn_then_terminated(path, args, passfds):
    pid = spawn(path, args, passfds)
    if "--multiprocessing-fork" in args:  # a worker (not the resource tracker), started and waiting on its pipe
        os.kill(os.getpid(), signal.SIGTERM)
    return pid

util.spawnv_passfds = spawn_then_terminated
stopped = "nothing"
try:
    with worker_pool(2) as pool:
        print("the pool ran", flush=True)
except KeyboardInterrupt as exc:
    stopped = type(exc).__name__
# The command goes on to clean up (temp folders) with the exception gone: a worker still waiting on its pipe
# then reads the end of it.
gc.collect()
print("stopped by", stopped, flush=True)
time.sleep(2.0)
"""


def test_sigterm_while_the_workers_start_stops_the_pool_with_no_worker_traceback() -> None:
    """The signal waits until every worker has what it starts from, then stops the pool: no worker dies of
    EOFError with a traceback on the terminal, and none is left behind (the pipe closes when the last one ends)."""
    done = subprocess.run(
        [sys.executable, "-c", _TERM_WHILE_A_WORKER_STARTS], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.stdout.strip() == "stopped by Terminated", (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr
    assert "EOFError" not in done.stderr, done.stderr
