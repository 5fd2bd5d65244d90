"""Nav2's codes in one table (``dock.nav2``): each code's exception type carries it, and a mission's failure ends
its goal with the type Nav2's docking server would raise."""

from __future__ import annotations

import pytest

from monodock.dock.nav2 import (
    DockingError,
    DockNotInDB,
    DockNotValid,
    FailedToCharge,
    FailedToControl,
    FailedToDetectDock,
    FailedToStage,
    Nav2Code,
    docking_error,
)
from monodock.dock.states import FailureReason


@pytest.mark.parametrize(
    ("code", "kind"),
    [
        (901, DockNotInDB),
        (902, DockNotValid),
        (903, FailedToStage),
        (904, FailedToDetectDock),
        (905, FailedToControl),
        (906, FailedToCharge),
        (907, DockingError),
        (999, DockingError),
    ],
)
def test_each_code_ends_a_goal_with_opennav_dockings_exception(code: int, kind: type[DockingError]) -> None:
    error = docking_error(Nav2Code(code), "why")
    assert type(error) is kind
    assert error.code == code
    assert str(error) == "why"


def test_every_failure_reason_maps_to_an_exception_of_its_own_code() -> None:
    for reason in FailureReason:
        error = docking_error(reason.nav2_error_code, str(reason))
        assert error.code == reason.nav2_error_code
        if reason is not FailureReason.CANCELLED:  # a cancelled goal ends with no error code (NONE)
            assert type(error) is not DockingError  # 903-906: each has opennav_docking's type
