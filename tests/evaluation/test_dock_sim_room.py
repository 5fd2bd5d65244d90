"""dock-sim's room envelope (``--starts room``, issue 28 item 5): the starts it draws, a run from the command line
with its report, and (slow) docking from far, off-axis and behind starts with a far-field marker, by the sim's truth.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from monodock.cli.main import main
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.evaluation.dock_sim import (
    ROOM_BEARING_DEG,
    ROOM_DISTANCE,
    DockSimConfig,
    _run_trial,
    _Task,
    room_tasks,
    sample_room_start,
)
from monodock.sim.diffdrive import DiffDriveConfig

ROOM = Path(__file__).resolve().parents[2] / "bench" / "setups" / "room"


def test_room_starts_cover_the_envelope_and_are_seeded() -> None:
    config = DockSimConfig(starts="room", trials=400, seed=3)
    tasks = room_tasks(config, config.mission.planner)
    assert [t for _, t, _ in tasks] == list(range(400))
    starts = [s for _, _, s in tasks]
    d = np.array([math.hypot(s.x, s.y) for s in starts])
    bearing = np.degrees([math.atan2(s.y, -s.x) for s in starts])
    assert d.min() >= ROOM_DISTANCE[0]
    assert d.max() <= ROOM_DISTANCE[1]
    assert d.max() > 4.8
    assert np.abs(bearing).max() <= ROOM_BEARING_DEG
    assert np.abs(bearing).max() > 55
    # any heading: the dock behind the robot (its bearing from the robot more than 90 degrees off the heading)
    behind = [abs(wrap_angle(math.atan2(-s.y, -s.x) - s.theta)) > math.pi / 2 for s in starts]
    assert 0.3 < np.mean(behind) < 0.7
    # the robot clears the face turning on the spot (front, back and corners)
    robot, drive = RobotConfig.default(), DiffDriveConfig()
    reach = math.hypot(max(robot.front_offset, drive.rear_offset), drive.footprint_width / 2)
    assert min(-s.x for s in starts) > reach
    again = room_tasks(config, config.mission.planner)
    assert again == tasks
    other = room_tasks(DockSimConfig(starts="room", trials=400, seed=4), config.mission.planner)
    assert other != tasks
    assert sample_room_start(np.random.default_rng(0), robot, drive) == sample_room_start(
        np.random.default_rng(0), robot, drive
    )


def test_dock_sim_room_writes_the_room_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "room"
    args = ["dock-sim", "--starts", "room", "--trials", "1", "--method", "board", "--jobs", "1", "--out", str(out)]
    args += ["--layout", str(ROOM / "layout.yaml"), "--camera", str(ROOM / "camera.yaml")]
    args += ["--robot", str(ROOM / "robot.yaml"), "--seed", "2"]
    assert main(args) == 0
    for name in ("room_map.png", "room_time.png", "room_far.png", "report.html", "runs.csv"):
        assert (out / name).is_file(), name
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "The room envelope" in html
    assert "Wilson 95 %" in html
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["overall"]["runs"] == 1
    capsys.readouterr()


# Far, off-axis and behind starts (distance from the face centre m, bearing off the axis deg, heading deg).
FAR_STARTS = [(4.5, 50.0, 180.0), (4.8, -30.0, 0.0), (3.5, 55.0, -90.0), (1.2, -58.0, 150.0)]


@pytest.mark.slow
@pytest.mark.parametrize(("distance", "bearing", "heading"), FAR_STARTS)
def test_docks_from_far_off_axis_and_behind_starts(distance: float, bearing: float, heading: float) -> None:
    """The designer's far-marker layout, the fused method with motion blur (the default exposure): from each start,
    docked and charging by the sim's truth, within the tolerances."""
    config = DockSimConfig(
        methods=("fused",),
        layout=DockLayout.load(ROOM / "layout.yaml"),
        camera=CameraModel.load(ROOM / "camera.yaml"),
        robot=RobotConfig.load(ROOM / "robot.yaml"),
        jobs=1,
        seed=5,
    )
    b = math.radians(bearing)
    start = Pose2D(-distance * math.cos(b), distance * math.sin(b), math.radians(heading))
    r = _run_trial(config, _Task(1, 0, "fused", start, "monodock"))
    assert r.success, r.log
    assert r.charging is True
    assert abs(r.lateral_cm) < 2.0
    assert abs(r.heading_deg) < 3.0
    assert not r.collided


@pytest.mark.slow
def test_under_heavy_blur_the_run_uses_the_markers_the_track_predicts() -> None:
    """A 30 ms exposure (the robot's own motion smears the markers) from 3.8 m, 23° off the axis, the dock behind:
    docked and charging by the sim's truth, and the frames dock-sim counts as posed with a predicted marker are there
    because the mission's track reaches the estimator (``predicted_markers``, as in the docking node)."""
    config = DockSimConfig(
        methods=("fused",),
        layout=DockLayout.load(ROOM / "layout.yaml"),
        camera=CameraModel.load(ROOM / "camera.yaml"),
        robot=RobotConfig.load(ROOM / "robot.yaml"),
        drive=dataclasses.replace(DiffDriveConfig(), exposure_time=0.03),
        jobs=1,
        seed=5,
    )
    r = _run_trial(config, _Task(1, 0, "fused", Pose2D(-3.5, 1.5, math.radians(150)), "monodock"))
    assert r.success, r.log
    assert r.charging is True
    assert abs(r.lateral_cm) < 2.0
    assert abs(r.heading_deg) < 3.0
    assert 0 < r.predicted_frames < r.posed_frames
