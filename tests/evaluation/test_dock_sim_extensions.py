"""Another ``ControlLaw`` plugged into the docking mission, judged in dock-sim by the simulator's truth: Moving₃'s
P-control at half monodock's gains still docks within the tolerances (rendered camera, the board method)."""

from __future__ import annotations

import math

import pytest

from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig
from monodock.dock.controller import DockingMission
from monodock.dock.extensions import PControlLaw
from monodock.dock.interface import Odometry
from monodock.evaluation import dock_sim
from monodock.evaluation.dock_sim import DockSimConfig, _run_trial, _Task


class _HalfGains:
    """Moving₃'s P-control on the lateral and heading errors at half monodock's gains; the other motions its own."""

    def __init__(self, config: DockingConfig) -> None:
        self.inner = PControlLaw(config)
        self.approach_steps = 0

    def limit_command(
        self, v: float, w: float, previous: tuple[float, float], max_speed: float, max_turn: float
    ) -> tuple[float, float]:
        return self.inner.limit_command(v, w, previous, max_speed, max_turn)

    def is_still(self, odom: Odometry) -> bool:
        return self.inner.is_still(odom)

    def turn_in_place(self, heading: float, odom: Odometry, max_turn: float) -> tuple[bool, float]:
        return self.inner.turn_in_place(heading, odom, max_turn)

    def drive_straight(
        self, target: Pose2D, pose: Pose2D, reverse: bool, max_speed: float
    ) -> tuple[float, float, bool]:
        return self.inner.drive_straight(target, pose, reverse, max_speed)

    def heading_reference(self, lateral: float, gap: float) -> float:
        return self.inner.heading_reference(0.5 * lateral, gap)  # atan(k_lateral / 2 * lateral)

    def approach_command(self, heading: float, reference: float, gap: float) -> tuple[float, float]:
        self.approach_steps += 1
        v, w = self.inner.approach_command(heading, reference, gap)
        return v, 0.5 * w  # k_heading / 2

    def reverse_stopping_distance(self, speed: float) -> float:
        return self.inner.reverse_stopping_distance(speed)


def test_half_the_p_gains_still_dock_within_the_tolerances(monkeypatch: pytest.MonkeyPatch) -> None:
    laws: list[_HalfGains] = []

    def mission(config: DockingConfig, robot: RobotConfig, blind: float, **kwargs: str) -> DockingMission:
        laws.append(_HalfGains(config))
        return DockingMission(config, robot, blind, law=laws[-1], **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(dock_sim, "DockingMission", mission)
    config = DockSimConfig(methods=("board",), jobs=1, seed=3, supersample=4)
    r = _run_trial(config, _Task(1, 0, "board", Pose2D(-1.3, 0.2, math.radians(-8)), "monodock"))
    assert laws
    assert laws[0].approach_steps > 0  # the mission drove Moving₃ by the plugged-in law
    c = config.mission
    assert r.success, r.log
    assert r.charging is True
    assert not r.collided
    assert abs(r.lateral_cm) <= 100 * c.retry.tolerance_lateral
    assert abs(r.longitudinal_cm) <= 100 * c.retry.tolerance_longitudinal
    assert abs(r.heading_deg) <= c.retry.tolerance_heading_deg
