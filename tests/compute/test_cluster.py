"""``--cluster``: the sweeps on a real Dask cluster give what the local cores give, and a cluster that cannot be
had, or a worker that dies, is one line.

The fixture starts a real cluster on loopback: a ``dask scheduler`` process and two ``dask worker`` processes (one
thread each, with nannies that restart a worker that dies), whose PYTHONPATH holds this checkout's src/ and tests/
(for tests/cluster_tasks.py); the scheduler gives up on a task after one worker died running it
(allowed-failures 1, so that the test of a task that always kills its worker is short).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import cluster_tasks
import monodock
from monodock.cli.main import main
from monodock.compute.cluster import MISSING_EXTRA, active_client, cluster_session
from monodock.compute.parallel import SINGLE_THREAD_ENV, map_with_state
from monodock.errors import InputError, MonodockError
from monodock.evaluation.dock_results import TrialResult
from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import TrainingResult, train

SRC = Path(monodock.__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parents[1]


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The address of a running scheduler with two single-threaded workers, all on 127.0.0.1."""
    import distributed

    root = tmp_path_factory.mktemp("dask")
    file = root / "scheduler.json"
    env = {
        **os.environ,
        **SINGLE_THREAD_ENV,
        "PYTHONPATH": os.pathsep.join([str(SRC), str(TESTS)]),
        "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1",
    }
    procs: list[subprocess.Popen[bytes]] = []
    with (root / "log.txt").open("wb") as log:

        def start(*args: str) -> None:
            procs.append(subprocess.Popen([sys.executable, "-m", *args], env=env, stdout=log, stderr=log, cwd=root))

        try:
            start(
                "distributed.cli.dask_scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(file),
            )
            deadline = time.monotonic() + 90
            while not file.exists() or not file.read_text().strip().endswith("}"):
                assert procs[0].poll() is None, (root / "log.txt").read_text()
                assert time.monotonic() < deadline, "the scheduler did not start in 90 s"
                time.sleep(0.1)
            address = json.loads(file.read_text())["address"]
            for i in range(2):
                start(
                    "distributed.cli.dask_worker",
                    address,
                    "--nthreads",
                    "1",
                    "--host",
                    "127.0.0.1",
                    "--no-dashboard",
                    "--name",
                    f"w{i}",
                )
            with distributed.Client(address, timeout=60) as client:
                client.wait_for_workers(2, timeout=240)
            yield address
        finally:
            _stop(procs)


def _wait_for_two_workers(address: str) -> None:
    """After a test that killed a worker: its nanny starts another."""
    import distributed

    with distributed.Client(address, timeout=30) as client:
        client.wait_for_workers(2, timeout=240)


def test_sweep_on_the_cluster_is_the_local_sweep_and_uses_both_workers(scheduler: str) -> None:
    state = (7, "x" * 200_000)  # sent once to each worker, not with each of the 30 tasks
    local = list(map_with_state(cluster_tasks.seeded_draw, state, list(range(30)), jobs=1))
    with cluster_session(scheduler) as client:
        assert active_client() is client
        remote = list(map_with_state(cluster_tasks.seeded_draw, state, list(range(30)), jobs=1))
        pids = client.run(os.getpid)
    assert active_client() is None
    assert remote == local  # the same draws, in the tasks' order
    assert [r[0] for r in remote] == list(range(30))
    assert len(set(pids.values()) - {os.getpid()}) == 2


def _without_timing(r: TrialResult) -> TrialResult:
    """Everything a run measured but the computer's clocks (wall and CPU seconds differ between any two runs)."""
    clocks = ("wall_s", "render_s", "perceive_s", "cpu_s", "render_cpu_s", "perceive_cpu_s")
    return dataclasses.replace(r, **dict.fromkeys(clocks, 0.0))


@pytest.mark.slow  # 4 closed-loop runs: ~25 s of CPU, minutes on a loaded machine
@pytest.mark.timeout(900)
def test_dock_sim_sweep_on_the_cluster_is_the_local_sweep(scheduler: str) -> None:
    """Two closed-loop board runs: every number of every run (path, log, end pose, frames) as on the local core."""
    config = DockSimConfig(cases=(1,), trials=2, methods=("board",), supersample=4, distance=(1.4, 1.8), jobs=1)
    local = run_dock_sim(config, progress=False)
    with cluster_session(scheduler):
        remote = run_dock_sim(config, progress=False)
    assert len(local) == 2
    assert all(r.success for r in local)
    assert local[0].start != local[1].start
    assert [_without_timing(r) for r in remote] == [_without_timing(r) for r in local]


@pytest.mark.slow  # 2 x 240 fits
def test_model_selection_on_the_cluster_is_the_local_one(
    scheduler: str, data: TrainingSet, result: TrainingResult
) -> None:
    """joblib's dask backend: the same chosen models, draws, scores and test predictions as one local process."""
    with cluster_session(scheduler):
        other = train([data], TrainConfig(trials=2, jobs=1, seed=3), progress=False)
    for a, b in zip(
        (result.sets[0].depth, *result.sets[0].angle), (other.sets[0].depth, *other.sets[0].angle), strict=True
    ):
        assert a.chosen == b.chosen
        np.testing.assert_array_equal(a.test_rows, b.test_rows)
        np.testing.assert_array_equal(a.y_pred, b.y_pred)
        for m, sa in a.scores.items():
            sb = b.scores[m]
            assert (sa.params, sa.mse, sa.n_fit) == (sb.params, sb.mse, sb.n_fit)


def test_simulate_command_on_the_cluster_writes_the_same_frames(
    scheduler: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command line: ``--cluster ADDRESS`` renders on the workers the very images the local cores render."""
    args = ["simulate", "--frames", "6", "--supersample", "2", "--seed", "5"]
    assert main([*args, "--out", str(tmp_path / "local"), "--jobs", "1"]) == 0
    assert main([*args, "--out", str(tmp_path / "cluster"), "--cluster", scheduler]) == 0
    assert "error" not in capsys.readouterr().err
    local = sorted(p for p in (tmp_path / "local").rglob("*") if p.is_file())
    assert len([p for p in local if p.suffix == ".png"]) == 6
    for p in local:
        assert (tmp_path / "cluster" / p.relative_to(tmp_path / "local")).read_bytes() == p.read_bytes(), p.name


def test_a_task_whose_worker_dies_runs_again(scheduler: str, tmp_path: Path) -> None:
    marker = tmp_path / "died"
    with cluster_session(scheduler):
        out = list(map_with_state(cluster_tasks.die_once, str(marker), list(range(6)), jobs=1))
    assert marker.read_text() == "died"  # task 3 did kill its worker once
    assert out == [i * i for i in range(6)]
    _wait_for_two_workers(scheduler)


def test_a_task_that_kills_every_worker_is_one_error(scheduler: str) -> None:
    with cluster_session(scheduler), pytest.raises(MonodockError, match=r"a Dask worker died running task 0 of 2"):
        list(map_with_state(cluster_tasks.always_die, None, [0, 1], jobs=1))
    _wait_for_two_workers(scheduler)


def test_leaving_a_sweep_early_cancels_its_tasks(scheduler: str) -> None:
    """What Ctrl-C does (the KeyboardInterrupt leaves the loop): nothing submitted stays on the cluster."""
    with cluster_session(scheduler) as client:
        sweep = map_with_state(cluster_tasks.slow, None, list(range(40)), jobs=1)
        assert next(sweep) == 0
        assert client.run_on_scheduler(cluster_tasks.scheduler_tasks) > 0
        sweep.close()
        deadline = time.monotonic() + 10
        while client.run_on_scheduler(cluster_tasks.scheduler_tasks) > 0:
            assert time.monotonic() < deadline, "tasks left on the scheduler 10 s after the sweep was left"
            time.sleep(0.1)


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--cluster", "tcp://127.0.0.1:9"], "--cluster tcp://127.0.0.1:9: no Dask scheduler answered"),
        (["--cluster", "scheduler.example:8786"], "--cluster: expected tcp://HOST:PORT of a Dask scheduler, or auto"),
        (["--cluster", "tcp://127.0.0.1:9", "--jobs", "2"], "--jobs sets the workers of --cluster auto"),
    ],
)
def test_a_cluster_that_cannot_be_had_is_one_line_and_exit_2(
    option: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    t0 = time.monotonic()
    assert main(["dock-sim", "--cases", "1", "--trials", "1", "--method", "board", *option]) == 2
    assert time.monotonic() - t0 < 30  # the connection's timeout is 5 s (the rest: loading Dask on a loaded machine)
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"monodock dock-sim: error: {message}"), err


def test_without_the_cluster_extra_the_option_says_how_to_get_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # `import distributed` raises ImportError
    with pytest.raises(InputError, match="pip install 'monodock\\[cluster\\]'"), cluster_session("auto"):
        pass
    assert main(["train", "missing.parquet", "--out", "x", "--cluster", "auto"]) == 2
    assert capsys.readouterr().err == f"monodock train: error: {MISSING_EXTRA}\n"


def test_without_the_option_dask_is_not_loaded() -> None:
    code = "import sys; from monodock.cli.main import parser; parser()\n"
    code += "assert 'distributed' not in sys.modules and 'dask' not in sys.modules"
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, check=False)
    assert done.returncode == 0, done.stderr.decode()
