"""The perception tests' simulator and its frames of the dock: all markers in view, and the left one out."""

from __future__ import annotations

import pytest

from monodock.sim import Nuisances, SimFrame, Simulator
from shared import ALL_IN_VIEW, LEFT_OUT_OF_VIEW


@pytest.fixture(scope="module")
def sim() -> Simulator:
    return Simulator(nuisances=Nuisances.clean(), seed=1)


@pytest.fixture(scope="module")
def frames(sim: Simulator) -> dict[str, SimFrame]:
    return {"all": sim.frame(ALL_IN_VIEW), "left_out": sim.frame(LEFT_OUT_OF_VIEW)}
