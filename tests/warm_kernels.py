"""Compile every numba kernel into numba's on-disk cache once, before the tests start (``.ci/run``).

Why: on a fresh clone the cache is empty, and every process the tests start (two xdist workers, their render
and training workers, CLI runs, ROS 2 nodes) compiles the same kernels at the same time until one has written
them: ~20 s of a core for the renderer alone, in each. Run once beside the static checks, it is paid once.
The kernels run on the code paths the tests use (a simulated frame with its LiDAR scan, a docking run with motion
blur, the fused method on a normal and a clipped view), so each is compiled for the argument types they pass.

    python tests/warm_kernels.py
"""

from __future__ import annotations

import time

import numpy as np

from monodock.estimation.estimator import Estimator
from monodock.estimation.fused import FusedEstimator, FusionTables
from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim
from monodock.sim.nuisance import Nuisances
from monodock.sim.simulator import Simulator


def main() -> None:
    started = time.perf_counter()
    sim = Simulator(seed=0)
    frame = sim.frame(sim.sample_pose(), 0.0, np.random.default_rng(0))  # renderer, sensor, LiDAR, lens
    Simulator(nuisances=Nuisances.clean(), seed=0).frame(sim.sample_pose(), 0.0, np.random.default_rng(0))
    fused = FusedEstimator(sim.camera, sim.layout, sim.robot, FusionTables(0.22))
    estimator = Estimator(sim.camera, sim.layout, sim.robot, ("fused", "board", "pnp"), fused=fused)
    estimator.warm_up()
    image = frame.image.copy()
    image.flags.writeable = False  # as decoded from a recording: numba compiles read-only arrays separately
    estimator.estimate("read-only", 0.0, image)
    run_dock_sim(DockSimConfig(cases=(1,), trials=1, methods=("board",), jobs=1), progress=False)  # motion blur
    print(f"numba kernels cached in {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()
