"""What each state of the docking mission keeps while the mission is in it (``DockingMission.phase``).

One small type per state with data of its own, which its handler in ``dock.controller`` reads with
``DockingMission._data``; the other states hold None.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D

__all__: list[str] = []  # nothing public: dock.controller is their one user


@dataclass
class _Acquiring:
    """``ACQUIRE``: how far the robot has turned looking for the dock (rad)."""

    turned: float = 0.0


@dataclass
class _Calculating:
    """``CALCULATE``: the frames taken so far (odometry at the frame, its estimate and covariance), their marker
    counts, and the heading before a centring turn when the robot came from one (it is not centred again)."""

    samples: list[tuple[Pose2D, DockPose, NDArray[np.float64]]] = field(default_factory=list)
    markers: list[int] = field(default_factory=list)
    heading_before_center: float | None = None


@dataclass(frozen=True)
class _Centring:
    """``CENTER``: the heading that faces the dock, and the one the robot had when it began to turn."""

    heading: float
    heading_before: float


@dataclass
class _FarLeg:
    """``FAR_APPROACH``: the leg's step (``turn`` to face its end, ``drive`` there, ``face`` the dock again) and
    where its drive began (odometry; None before it began)."""

    step: str = "turn"
    origin: Pose2D | None = None


@dataclass(frozen=True)
class _Reversing:
    """``MOVING1_BACK``, ``RECOVER``, ``RESEAT`` and ``BACK_OFF``: where the straight reverse leg ends (odometry)."""

    target: Pose2D


@dataclass
class _Undocking:
    """``UNDOCK``: where the back-out ends, set at the first tick from the pose on the contacts."""

    target: Pose2D | None = None


@dataclass
class _Approaching:
    """``MOVING3``: whether the checkpoint (``checkpoint_gap``) has been passed and judged."""

    checked: bool


_Phase = _Acquiring | _Calculating | _Centring | _FarLeg | _Reversing | _Undocking | _Approaching | None
_P = TypeVar("_P", _Acquiring, _Calculating, _Centring, _FarLeg, _Reversing, _Undocking, _Approaching)
