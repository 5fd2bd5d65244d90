"""Nav2's docking contract as plain data: the one table of ``DockRobot``/``UndockRobot`` result codes and feedback
states, and opennav_docking's failures as exception types, each carrying its code.

The codes are those of ``nav2_msgs/action/DockRobot.action`` and ``UndockRobot.action`` (interfaces/upstream/, Kilted);
``GOAL_REJECTED`` and ``SEND_GOAL_FAILURE`` come from the newer (Rolling) definitions, where a behaviour tree's action
node reports a goal the server refused or never got. The exception types are those of
``opennav_docking_core/docking_exceptions.hpp``: the docking server catches each and ends the goal with its code
(``docking_server.cpp``, Kilted, lines 357-395), so a caller can react to *why* it failed. Nothing here needs ROS.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any

from monodock.errors import MonodockError

__all__ = [
    "UNDOCK_CODES",
    "DockNotInDB",
    "DockNotValid",
    "DockingError",
    "FailedToCharge",
    "FailedToControl",
    "FailedToDetectDock",
    "FailedToStage",
    "FeedbackState",
    "Nav2Code",
    "docking_error",
]


class Nav2Code(IntEnum):
    """``DockRobot.Result``'s error codes (``UndockRobot.Result`` has the subset ``UNDOCK_CODES``)."""

    NONE = 0
    GOAL_REJECTED = 1  # Rolling's definitions: the server refused the goal (set by the client, e.g. a BT node)
    SEND_GOAL_FAILURE = 2  # Rolling's definitions: the goal never reached a server
    DOCK_NOT_IN_DB = 901
    DOCK_NOT_VALID = 902
    FAILED_TO_STAGE = 903
    FAILED_TO_DETECT_DOCK = 904
    FAILED_TO_CONTROL = 905
    FAILED_TO_CHARGE = 906
    TIMEOUT = 907  # defined, but Nav2's docking server ends no goal with it: its time-outs are 904, 905, 906
    UNKNOWN = 999


UNDOCK_CODES = frozenset(
    {
        Nav2Code.NONE,
        Nav2Code.GOAL_REJECTED,
        Nav2Code.SEND_GOAL_FAILURE,
        Nav2Code.DOCK_NOT_VALID,
        Nav2Code.FAILED_TO_CONTROL,
        Nav2Code.TIMEOUT,
        Nav2Code.UNKNOWN,
    }
)


class FeedbackState(IntEnum):
    """``DockRobot.Feedback``'s states."""

    NONE = 0
    NAV_TO_STAGING_POSE = 1
    INITIAL_PERCEPTION = 2
    CONTROLLING = 3
    WAIT_FOR_CHARGE = 4
    RETRY = 5


class DockingError(MonodockError):
    """A docking goal that failed, with the result code it ends with (``opennav_docking_core::DockingException``).

    A subclass names its code in its header (``class FailedToStage(DockingError, code=Nav2Code.FAILED_TO_STAGE)``),
    which makes it the exception type of that code for ``docking_error``.
    """

    code = Nav2Code.UNKNOWN

    def __init_subclass__(cls, code: Nav2Code | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if code is not None:
            cls.code = code
            _BY_CODE[code] = cls


# Each code's exception type, filled as the types are declared: the one table is Nav2Code and each type's ``code``.
_BY_CODE: dict[Nav2Code, type[DockingError]] = {}


# opennav_docking_core's names, which do not end in Error (hence the noqa: N818).
class DockNotInDB(DockingError, code=Nav2Code.DOCK_NOT_IN_DB):  # noqa: N818
    """The goal's ``dock_id`` is not in the dock database."""


class DockNotValid(DockingError, code=Nav2Code.DOCK_NOT_VALID):  # noqa: N818
    """The dock's type has no plugin (no dock type of that name), or there is nothing to undock from."""


class FailedToStage(DockingError, code=Nav2Code.FAILED_TO_STAGE):  # noqa: N818
    """The staging pose was not reached: navigation failed, timed out (``max_staging_time``) or was preempted."""


class FailedToDetectDock(DockingError, code=Nav2Code.FAILED_TO_DETECT_DOCK):  # noqa: N818
    """The dock was not seen (initial perception) or was lost on the way in."""


class FailedToControl(DockingError, code=Nav2Code.FAILED_TO_CONTROL):  # noqa: N818
    """The robot could not be driven onto (or off) the dock: time-outs, tolerances, obstacles."""


class FailedToCharge(DockingError, code=Nav2Code.FAILED_TO_CHARGE):  # noqa: N818
    """On the contacts, charging never started."""


def docking_error(code: Nav2Code, message: str) -> DockingError:
    """The exception that ends a goal with ``code``: opennav_docking's type of that code, else a DockingError (both
    carrying ``code``)."""
    error = _BY_CODE.get(code, DockingError)(message)
    error.code = code
    return error
