"""Compile every numba kernel into numba's on-disk cache once, before the tests start (``.ci/run``).

Why: on a fresh clone the cache is empty, and every process the tests start (two xdist workers, their render
and training workers, CLI runs, ROS 2 nodes) compiles the same kernels at the same time until one has written
them: ~70 s of one core in all, in each. In CI that storm slowed the default tier by ~100 s and starved the real-time
ROS 2 graphs (docs/development.md). The kernels run here on the code paths the tests use, so each is compiled for
the argument types they pass. Two parts, one process each (they share no kernel that takes long to compile):

    python tests/warm_kernels.py sim          # a simulated frame with its LiDAR scan, a docking run with motion blur
    python tests/warm_kernels.py estimation   # the fused method on a normal, a clipped and a read-only view, and
                                              # the photometric marker fit
"""

from __future__ import annotations

import sys
import time

import numpy as np


def warm_simulator() -> None:
    from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim
    from monodock.sim.nuisance import Nuisances
    from monodock.sim.simulator import Simulator

    sim = Simulator(seed=0)
    sim.frame(sim.sample_pose(), 0.0, np.random.default_rng(0))  # renderer, sensor, LiDAR, lens
    Simulator(nuisances=Nuisances.clean(), seed=0).frame(sim.sample_pose(), 0.0, np.random.default_rng(0))
    run_dock_sim(DockSimConfig(cases=(1,), trials=1, methods=("board",), jobs=1), progress=False)  # motion blur


def warm_estimation() -> None:
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.pose import DockPose
    from monodock.core.robot import RobotConfig
    from monodock.estimation.estimator import Estimator
    from monodock.estimation.fused import FusionTables
    from monodock.estimation.fused import _gain as regression_gain
    from monodock.estimation.methods import MethodSetup, build_methods
    from monodock.perception.detect import as_gray
    from monodock.perception.marker_fit import fit_marker
    from monodock.perception.predicted import predict_corners
    from monodock.perception.synthetic import synthetic_view

    camera, layout, robot = CameraModel.default(), DockLayout.default(), RobotConfig.default()
    setup = MethodSetup(camera, layout, robot, tables=FusionTables(0.22))
    estimator = Estimator(camera, layout, robot, build_methods(("fused", "board", "pnp"), setup))
    estimator.warm_up()  # a normal and a clipped view
    pose = DockPose(robot.camera_mount.x + 0.8, 0.05, 0.1)
    image = synthetic_view(camera, layout, robot, pose)
    image.flags.writeable = False  # as decoded from a recording: numba compiles read-only arrays separately
    estimator.estimate("read-only", 0.0, image)
    # The photometric marker fit (predicted markers, the dock survey), from the corners the pose predicts; and the
    # fused method's test of whether the regression is worth running (only with a regression model).
    gray = as_gray(image)
    for role, corners in predict_corners(camera, layout, robot, pose).items():
        fit_marker(gray, corners, camera, layout.marker_bits(layout.marker(role).id))
    regression_gain(np.eye(3), np.eye(3))


PARTS = {"sim": warm_simulator, "estimation": warm_estimation}


def main(argv: list[str]) -> int:
    names = argv or list(PARTS)
    unknown = [n for n in names if n not in PARTS]
    if unknown:
        print(f"warm_kernels: unknown part(s) {', '.join(unknown)}; choose from {', '.join(PARTS)}", file=sys.stderr)
        return 2
    for name in names:
        started = time.perf_counter()
        PARTS[name]()
        print(f"numba kernels cached: {name} in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
