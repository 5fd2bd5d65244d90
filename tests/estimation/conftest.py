"""The estimation tests' simulators: the default camera and a strongly distorting lens."""

from __future__ import annotations

import pytest

from monodock.sim import Simulator
from shared import STRONG_LENS


@pytest.fixture(scope="module")
def sim() -> Simulator:
    return Simulator(seed=0)


@pytest.fixture(scope="module")
def strong_sim() -> Simulator:
    return Simulator(camera=STRONG_LENS, seed=0)
