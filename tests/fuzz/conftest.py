"""The fuzz suite's fixtures: the valid world every hostile input starts from, and Hypothesis's two profiles.

Profiles (see README.md): every property test exists twice, ``test_x`` under ``fuzz`` (bounded, derandomized: the
same examples on every run, so CI is reproducible; the whole default ``tests/fuzz`` run stays within ~90 s) and
``test_x_slow`` under ``fuzz-slow`` (many more examples, also derandomized unless MONODOCK_FUZZ_RANDOM=1), marked
``slow`` so that only ``pytest -m slow`` runs it.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, settings

from fuzz.world import World, build_world

_COMMON = {
    "deadline": None,  # hangs are caught by the harness's alarm and pytest-timeout, not by per-example timing
    "database": None,
    "suppress_health_check": [HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
    "print_blob": True,
}
# No shrinking in the bounded profile: a failure is reported as found (shrinking costs minutes per failure).
settings.register_profile("fuzz", max_examples=20, derandomize=True, phases=[Phase.explicit, Phase.generate], **_COMMON)
# The slow profile is derandomized too, so that CI's verdict does not change from run to run; its examples are
# not the bounded profile's (each test function has its own seed). MONODOCK_FUZZ_RANDOM=1 draws fresh ones.
settings.register_profile(
    "fuzz-slow", max_examples=300, derandomize=os.environ.get("MONODOCK_FUZZ_RANDOM") != "1", **_COMMON
)


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory) -> World:
    """The valid inputs (built once per session, ~7 s)."""
    return build_world(Path(tmp_path_factory.mktemp("fuzz-world")))
