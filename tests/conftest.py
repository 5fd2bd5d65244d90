"""Fixtures several test folders share: a labelled, trained model bundle from a simulated drive (built once)."""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from monodock.cli.main import main
from monodock.core.pose import DockPose
from monodock.learning.export import save_bundle
from monodock.learning.train import TrainConfig, TrainingResult, TrainingSet, train
from monodock.sim import Nuisances, PoseDistribution, Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording
from shared import BLACK, FRAMES, META, synthetic_set

FAST = Nuisances().updated(supersample=2)

# DDS discovers peers by multicast on every interface. No test here starts a DDS participant (the ROS tests run
# the nodes against stand-ins for rclpy); should one ever, it and every process it starts stay on loopback.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "117")


@pytest.fixture(scope="session", autouse=True)
def _no_dds_participant() -> Iterator[None]:
    """The ROS tests use stand-ins: at the end no real rclpy (one loaded from a file) may be in this process."""
    yield
    rclpy = sys.modules.get("rclpy")
    assert rclpy is None or getattr(rclpy, "__file__", None) is None, (
        "a test imported the real rclpy: run ROS 2 graphs in a private network namespace (issue 17)"
    )


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


@pytest.fixture(scope="session")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Simulator, list[DockPose], Path, Path]:
    """A 10 fps MJPG video of simulated frames with one black frame, the poses, and the calibration folder."""
    folder = tmp_path_factory.mktemp("drive")
    sim = Simulator(nuisances=Nuisances(supersample=4), seed=5)  # 4x4 edge samples: fast enough for a test
    poses = [sim.sample_pose(PoseDistribution(depth=(0.4, 1.2))) for _ in range(FRAMES)]
    video = folder / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, sim.camera.size)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    for i, pose in enumerate(poses):
        image = sim.frame(pose, 0.1 * i, rng).image
        if i == BLACK:
            image = np.zeros_like(image)
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    sim.camera.save(folder / "camera.yaml")
    sim.layout.save(folder / "layout.yaml")
    sim.robot.save(folder / "robot.yaml")
    return sim, poses, video, folder


@pytest.fixture(scope="session")
def data() -> TrainingSet:
    return synthetic_set()


@pytest.fixture(scope="session")
def result(data: TrainingSet) -> TrainingResult:
    return train([data], TrainConfig(trials=2, jobs=1, seed=3), progress=False)


@pytest.fixture(scope="session")
def saved(result: TrainingResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_bundle(tmp_path_factory.mktemp("b") / "bundle", result, metadata=META)


@pytest.fixture
def bundle_copy(saved: Path, tmp_path: Path) -> Path:
    out = tmp_path / "bundle"
    shutil.copytree(saved, out)
    return out
