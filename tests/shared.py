"""Helpers several test files share (on the path through pytest's ``pythonpath``): what a test drive looks like,
the command line as a library, synthetic training rows with a known answer."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.cli.main import parser
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D
from monodock.core.settings import to_mapping
from monodock.dock.tracking import Observation
from monodock.learning.tasks import TrainingSet
from monodock.perception.detect import Detection, MarkerObservation
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from monodock.sim.nuisance import Nuisances
from monodock.sim.simulator import Simulator

# The video drive of the live and ROS tests (conftest.drive).
FRAMES = 30
BLACK = 12  # the frame that is all black: no markers

# The default robot's camera mount x: DockPose.x = depth from the camera + CAMERA_X.
CAMERA_X = 0.17
ALL_IN_VIEW = DockPose(CAMERA_X + 0.9, 0.15, math.radians(-8.0))
LEFT_OUT_OF_VIEW = DockPose(CAMERA_X + 0.5, 0.20, 0.0)
STRONG_LENS = CameraModel.from_intrinsics(640, 480, 615.0, 613.0, 322.4, 237.1, (-0.2, 0.0, 0.0, 0.0, 0.0))

# Synthetic training rows (synthetic_set).
SET = "m1m2m3"
FEATURES = ("size", "ratio", "noise_a", "noise_b")
SPARSE_SEGMENT = 3  # 40-45 cm: only 10 rows of its own
META = {"feature_schema": "test-features/1", "layout": to_mapping(DockLayout.default())}


def pose_at(depth: float, y: float, yaw_deg: float) -> DockPose:
    """The DockPose of a dock ``depth`` metres from the camera."""
    return DockPose(depth + CAMERA_X, y, math.radians(yaw_deg))


def calibration(folder: Path) -> list[str]:
    """The CLI options of the calibration files saved in ``folder``."""
    return [f"--{k}={folder / f'{k}.yaml'}" for k in ("camera", "layout", "robot")]


def run_cli(argv: list[str]) -> int:
    """``monodock ARGV`` through the real parser, with its errors raised (not printed)."""
    args = parser().parse_args(argv)
    return int(args.func(args))


def synthetic_set(seed: int = 0) -> TrainingSet:
    """Rows from a known function: depth = 60 / size, yaw linear in a ratio whose slope grows with depth.

    Depths cover 25-60 cm (segments 0-6), with segment 3 nearly empty; farther segments have no rows.
    """
    rng = np.random.default_rng(seed)
    per_segment = [70, 70, 70, 10, 70, 70, 70]
    depth = np.concatenate([rng.uniform(0.25 + 0.05 * k, 0.30 + 0.05 * k, n) for k, n in enumerate(per_segment)])
    n = len(depth)
    yaw = rng.uniform(-30.0, 30.0, n)
    size = 60.0 / depth + rng.normal(0.0, 0.2, n)
    ratio = yaw * (0.01 + 0.02 * depth) + rng.normal(0.0, 0.01, n)
    X = np.column_stack([size, ratio, rng.normal(size=n), 50.0 * rng.normal(size=n)])
    return TrainingSet(SET, FEATURES, X, depth + rng.normal(0.0, 0.003, n), yaw, depth)


def as_float32(X: NDArray[np.float64]) -> NDArray[np.float64]:
    return X.astype(np.float32).astype(np.float64)


def draw_gaussian(rng: np.random.Generator, cov: np.ndarray, n: int) -> np.ndarray:
    """``n`` zero-mean draws of covariance ``cov``."""
    return rng.multivariate_normal(np.zeros(3), cov, size=n)


def noisy_detection(sim: object, pose: object, roles: tuple[str, ...], seed: int) -> object:
    """The true corners of ``roles`` at ``pose`` with 0.05 px of Gaussian noise, as a Detection."""
    rng = np.random.default_rng(seed)
    corners = sim.true_corners(pose)  # type: ignore[attr-defined]
    obs = {
        r: MarkerObservation(r, sim.layout.marker(r).id, corners[r] + rng.normal(0, 0.05, (4, 2)))  # type: ignore[attr-defined]
        for r in roles
    }
    return Detection(obs, (), sim.camera.size)  # type: ignore[attr-defined]


def in_view(sim: object, pose: object, role: str) -> bool:
    """Whether a marker's true corners are all in the image (2 px margin)."""
    corners = sim.true_corners(pose)[role]  # type: ignore[attr-defined]
    return bool(np.all(np.isfinite(corners)) and sim.in_view(corners, 2.0))  # type: ignore[attr-defined]


# --- docking missions without the camera ------------------------------------------------------------------


class TruthfulRobot(SimulatedRobot):
    """The simulated base whose camera renders nothing: the state machine's own tests see the true pose.

    A frame's "image" is empty; ``perceive_truth`` turns its stamp into the exact DockPose at that exposure and
    the number of markers wholly in the image (none: no pose). The base, its odometry, latency and the face
    are the simulator's as usual; only the vision, tested elsewhere, is left out, which makes a mission seconds.
    """

    def __post_init__(self) -> None:
        super().__post_init__()
        self.exposed: dict[float, Pose2D] = {}

    def render(self, stamp: float, pose: Pose2D) -> np.ndarray:
        self.exposed[stamp] = pose
        self.frames_rendered += 1
        return np.zeros((1, 1), np.uint8)

    def perceive_truth(self, stamp: float, _image: np.ndarray) -> Observation:
        if self.hide_markers is not None and self.hide_markers(stamp, self.exposed[stamp]):
            return Observation(stamp, None)
        dock = self.dock_pose(self.exposed[stamp])
        markers = sum(self.sim.in_view(quad) for quad in self.sim.true_corners(dock).values())
        return Observation(stamp, dock if markers else None, markers)


def truthful_robot(start: Pose2D, **drive: object) -> TruthfulRobot:
    return TruthfulRobot(
        Simulator(nuisances=Nuisances.clean(), seed=1),
        start,
        DiffDriveConfig(**drive),  # type: ignore[arg-type]
        np.random.default_rng(3),
    )


def worker_pid(_: object, __: object) -> int:
    """The process a task ran in (``compute.parallel`` tests: a module-level function, so it pickles)."""
    import os

    return os.getpid()


# Stand-ins for rclpy, so that the nodes' modules import in full without ROS 2 (and without a DDS participant): the
# first lines of a script that a test runs in a child process.
RCLPY_STAND_INS = """
import sys, types

class Node:
    def __init__(self, *args, **kwargs):
        pass
for name in ("rclpy", "rclpy.node", "rclpy.lifecycle", "rclpy.utilities"):
    sys.modules[name] = types.ModuleType(name)
sys.modules["rclpy.node"].Node = Node
sys.modules["rclpy.lifecycle"].LifecycleNode = Node
sys.modules["rclpy.utilities"].remove_ros_args = lambda args: args
"""


def json_with_stand_ins(script: str) -> Any:
    """What ``script`` prints as JSON, run in a child process after ``RCLPY_STAND_INS`` (argparse at 100 columns)."""
    env = {**os.environ, "COLUMNS": "100"}
    done = subprocess.run(
        [sys.executable, "-c", RCLPY_STAND_INS + textwrap.dedent(script)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)
