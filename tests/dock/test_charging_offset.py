"""The taught charging pose (``DockingConfig.charging_offset``): the frame the mission docks in, and docking to it.

Ground truth: the planar geometry written out here, and the simulator's contacts (its robot's true
``front_offset``: where the front edge meets the face).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import ChargingOffset, DockingConfig, load_docking_config
from monodock.dock.tracking import DockTrack, Observation
from monodock.errors import ConfigError
from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim


def test_the_target_frame_puts_the_taught_pose_at_the_nominal_docked_pose() -> None:
    """A robot standing where it was taught to charge is docked, by the mission's reckoning, in the target frame:
    (front_offset, 0, 0) as a DockPose."""
    f = 0.34
    offset = ChargingOffset(x=0.006, y=-0.004, yaw_deg=0.7)
    taught = Pose2D(-f + 0.006, -0.004, math.radians(0.7))  # base_link in the dock frame, as written in the file
    target = offset.dock_T_target(f)
    in_target = taught.relative_to(target)
    assert in_target.x == pytest.approx(-f, abs=1e-12)
    assert in_target.y == pytest.approx(0.0, abs=1e-12)
    assert in_target.theta == pytest.approx(0.0, abs=1e-12)
    assert ChargingOffset().dock_T_target(f) == Pose2D(0.0, 0.0, 0.0)


def test_the_track_reads_every_frame_in_the_target_frame() -> None:
    f = 0.34
    target = ChargingOffset(x=0.01, y=0.002, yaw_deg=-1.0).dock_T_target(f)
    track = DockTrack(DockingConfig().track, DockingConfig().measurement, target)
    from monodock.dock.interface import Odometry

    track.move(Odometry(0.0, Pose2D(0.0, 0.0, 0.0), 0.0, 0.0))
    dock = DockPose(1.2, 0.05, 0.1)  # the dock frame in base_link, as a camera saw it
    placed = track.place(Observation(0.0, dock, 3))
    assert placed is not None
    _, seen, _ = placed
    expected = Pose2D(1.2, 0.05, 0.1).compose(target)
    assert (seen.x, seen.y, seen.yaw) == pytest.approx((expected.x, expected.y, expected.theta), abs=1e-12)


def test_a_docking_config_with_a_charging_offset_loads_and_refuses_a_wrong_one(tmp_path: Path) -> None:
    path = tmp_path / "docking.yaml"
    path.write_text("charging_offset: {x: -0.007, y: 0.0021, yaw_deg: -0.4}\n", encoding="utf-8")
    assert load_docking_config(path).charging_offset == ChargingOffset(-0.007, 0.0021, -0.4)
    path.write_text("charging_offset: {x: -0.7}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"charging_offset beyond 20 cm or 20 degrees .* got x -0.7"):
        load_docking_config(path)


@pytest.mark.slow
def test_docking_to_the_taught_pose_charges_at_the_first_seat() -> None:
    """Contacts 9 mm further in than the robot file's front_offset: at the nominal pose the robot stops short and
    does not charge at its first seat; taught (the offset measured, ``monodock teach``), it charges at once."""
    nominal = RobotConfig.default()
    true = dataclasses.replace(nominal, front_offset=nominal.front_offset - 0.009)
    outcomes = {}
    for label, offset in (("nominal", ChargingOffset()), ("taught", ChargingOffset(x=0.009))):
        config = DockSimConfig(
            cases=(1, 6), trials=1, methods=("board",), jobs=1, seed=3, robot=true, believed_robot=nominal,
            mission=DockingConfig(charging_offset=offset),
        )  # fmt: skip
        outcomes[label] = run_dock_sim(config, progress=False)
    for r in outcomes["taught"]:
        assert r.charging
        assert r.reseats == 0
        assert abs(r.longitudinal_cm) < 0.3
    assert all(r.reseats > 0 or not r.charging for r in outcomes["nominal"])
