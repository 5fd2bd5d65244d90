"""Fixtures several test folders share: a labelled, trained model bundle from a simulated drive (built once)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from monodock.cli.main import main
from monodock.sim import Nuisances, Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording

FAST = Nuisances().updated(supersample=2)


def _record(path: Path, sim: Simulator, stops: int, seed: int) -> None:
    plan = plan_drive(sim, DriveConfig(stops=stops), np.random.default_rng(seed))
    write_recording(path, sim, plan, seed=seed, jobs=2, progress=False)


@pytest.fixture(scope="session")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A training drive (labelled, trained with one draw per model) and a held-out drive of another seed."""
    root = tmp_path_factory.mktemp("pipeline")
    _record(root / "train_rec", Simulator(nuisances=FAST, seed=1), 240, 1)
    _record(root / "test_rec", Simulator(nuisances=FAST, seed=2), 40, 2)
    Simulator().layout.save(root / "layout.yaml")
    layout = str(root / "layout.yaml")
    assert main(["label", str(root / "train_rec"), "--layout", layout, "--out", str(root / "train.parquet")]) == 0
    code = main(["train", str(root / "train.parquet"), "--out", str(root / "bundle"), "--trials", "1", "--jobs", "2"])
    assert code == 0
    return root


