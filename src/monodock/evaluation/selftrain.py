"""A model bundle trained on the simulator's own robot: the demo's first three steps, and the docking cache.

simulate a stop-and-go data-collection drive (rosbag2) → label it with the LiDAR → train the papers' seven
regressors per segment → save the ONNX bundle. ``cached_bundle`` keeps one such bundle per simulator set-up in
a cache directory, so that ``monodock dock-sim`` trains it once and reuses it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from monodock import __version__
from monodock.core.atomic import atomic_directory
from monodock.core.settings import to_mapping
from monodock.estimation.bundle import load_bundle
from monodock.estimation.fused import FUSION_SCHEMA
from monodock.learning.dataset import Dataset, label_recording
from monodock.learning.fusion import FUSION_LEARNING
from monodock.learning.pipeline import TrainOptions, train_bundle
from monodock.learning.train import TrainingResult
from monodock.sim import Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording

__all__ = ["SelfTrainConfig", "cache_root", "cached_bundle", "simulate_and_train"]


@dataclass(frozen=True)
class SelfTrainConfig:
    """Size of the self-trained bundle. ``supersample``: the renderer's S (see ``Nuisances.supersample``)."""

    stops: int = 3000
    trials: int = 4
    seed: int = 0
    supersample: int = 16


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def simulate_and_train(
    work: Path, out: Path, sim: Simulator, config: SelfTrainConfig, *, jobs: int, steps: str = ""
) -> tuple[Dataset, Any, TrainingResult]:
    """Record a training drive in ``work``, label it, train, and save the bundle to ``out``.

    Returns the labelled dataset, the labelling run's counts and the training result.
    """
    sim_train = Simulator(
        layout=sim.layout,
        camera=sim.camera,
        robot=sim.robot,
        nuisances=sim.nuisances.updated(supersample=config.supersample),
        seed=config.seed,
    )
    _log(f"{steps}simulating the data-collection drive: {config.stops} stops (rosbag2, MCAP) ...")
    stops = plan_drive(sim_train, DriveConfig(stops=config.stops), np.random.default_rng([config.seed, 2]))
    write_recording(work / "train_drive", sim_train, stops, seed=config.seed, jobs=jobs)
    _log(f"{steps}labelling it with the LiDAR ...")
    ds, run, _ = label_recording(work / "train_drive", sim_train.layout, jobs=jobs)
    _log(f"{steps}training the seven regressors per segment ({config.trials} trials each) ...")
    options = TrainOptions(trials=config.trials, seed=config.seed, jobs=jobs, source="simulated training drive")
    result = train_bundle(ds, out, options).result
    return ds, run, result


def cache_root() -> Path:
    """``$MONODOCK_CACHE``, else ``$XDG_CACHE_HOME/monodock``, else ``~/.cache/monodock``."""
    if os.environ.get("MONODOCK_CACHE"):
        return Path(os.environ["MONODOCK_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "monodock"


def cached_bundle(sim: Simulator, config: SelfTrainConfig, *, jobs: int, cache: Path | None = None) -> Path:
    """The self-trained bundle for this simulator set-up, trained the first time it is asked for.

    The key covers what changes the models: the layout, camera, mounts, nuisances, the training size and
    monodock's version. A bundle that no longer loads (e.g. a broken cache) is trained again.
    """
    key_data = {
        "layout": to_mapping(sim.layout),
        "camera": sim.camera.to_ros_dict(),
        "robot": to_mapping(sim.robot),
        "nuisances": repr(sim.nuisances.updated(supersample=config.supersample)),  # the drive's own sampling
        "train": repr(config),
        "version": __version__,
        "fusion": FUSION_SCHEMA,  # bundles from before the fused method lack its tables
        "fusion_learning": FUSION_LEARNING,
    }
    key = hashlib.sha256(json.dumps(key_data, sort_keys=True, default=str).encode()).hexdigest()[:16]
    entry = (cache or cache_root()) / f"bundle-{key}"
    bundle = entry / "bundle"
    if entry.is_dir():
        try:
            load_bundle(bundle)
            return bundle
        except Exception as exc:  # any defect of a cached file means: train again
            _log(f"cached bundle {bundle} is unusable ({exc}); training it again")
            shutil.rmtree(entry, ignore_errors=True)
    entry.parent.mkdir(parents=True, exist_ok=True)
    _log(f"training the regression once for this simulator set-up; cached in {entry}")
    with tempfile.TemporaryDirectory(prefix="monodock-selftrain-") as work, atomic_directory(entry) as tmp:
        simulate_and_train(Path(work), tmp / "bundle", sim, config, jobs=jobs)
    return bundle
