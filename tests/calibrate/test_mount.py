"""The camera mount from a drive (``calibrate.mount``) and the taught charging pose (``calibrate.teach``), against
the simulator's truth: a robot whose camera sits off its drawing, whose wheels are not the same size, and whose
contacts are not where ``front_offset`` says."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from monodock.calibrate.mount import calibrate_mount_of, frames_from_recording
from monodock.calibrate.teach import teach_from_recording
from monodock.cli.main import main
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import InputError
from monodock.sim import Nuisances, Simulator
from monodock.sim.continuous import commissioning_route, record_drive, teach_route, teach_start
from monodock.sim.diffdrive import SimulatedRobot
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording

FAST = Nuisances().updated(supersample=2)
NOMINAL = RobotConfig.default()
# The drawing says 17 cm ahead, centred, 25 cm up, square; the robot was built otherwise.
TRUE = dataclasses.replace(
    NOMINAL,
    camera_mount=Mount(0.1815, -0.0110, 0.2620, math.radians(1.2), math.radians(-1.4), math.radians(1.3)),
    front_offset=NOMINAL.front_offset - 0.008,
)
WHEELS = (1.0052, 0.9961)


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mount") / "drive"
    sim = Simulator(robot=TRUE, nuisances=FAST, seed=7)
    start, legs = commissioning_route(np.random.default_rng(7), stations=3)
    robot = SimulatedRobot(sim, start, rng=np.random.default_rng(8), wheel_scale=WHEELS)
    record_drive(path, robot, legs, frame_every=3, progress=False)
    return path


def test_the_drive_finds_the_mount_within_3_mm_and_0_2_degrees(drive: Path) -> None:
    """x, y, roll, pitch, yaw within 3 mm and 0.2°; z within 1 mm (the layout's heights are exact here); the
    odometry's distance scale and heading drift those of the wheels (within what the fit says it knows)."""
    sim = Simulator(robot=TRUE, nuisances=FAST, seed=7)
    result = calibrate_mount_of(frames_from_recording(str(drive), sim.layout), sim.layout, NOMINAL)
    m, t = result.mount, TRUE.camera_mount
    for k in ("x", "y"):
        assert abs(getattr(m, k) - getattr(t, k)) < 0.003, k
    assert abs(m.z - t.z) < 0.001
    for k in ("roll", "pitch", "yaw"):
        assert math.degrees(abs(getattr(m, k) - getattr(t, k))) < 0.2, k
    assert result.odometry_scale == pytest.approx(np.mean(WHEELS), abs=0.003)
    true_drift = (WHEELS[1] - WHEELS[0]) / 0.40  # the simulated base's track width
    # A short drive leaves the drift loose: within a degree per metre of the wheels' 1.3.
    assert math.degrees(abs(result.drift_per_m - true_drift)) < 1.0
    assert not result.unexcited
    assert result.robot(NOMINAL).camera_mount == m
    assert result.robot(NOMINAL).odometry.drift_per_m == result.drift_per_m


def test_a_recording_without_odometry_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sim = Simulator(nuisances=FAST, seed=1)
    write_recording(tmp_path / "stops", sim, plan_drive(sim, DriveConfig(stops=3), np.random.default_rng(1)), seed=1,
                    progress=False)  # fmt: skip
    with pytest.raises(InputError, match=r"has no odometry \(nav_msgs/Odometry\): record the robot's odom topic too$"):
        frames_from_recording(str(tmp_path / "stops"), sim.layout)
    layout, robot = tmp_path / "layout.yaml", tmp_path / "robot.yaml"
    sim.layout.save(layout)
    NOMINAL.save(robot)
    code = main(["calibrate", "mount", str(tmp_path / "stops"), "--layout", str(layout), "--robot", str(robot),
                 "--out", str(tmp_path / "out.yaml")])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert "has no odometry" in err[0]


def test_teaching_finds_where_the_robot_charges(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Pushed onto the contacts 8 mm before where front_offset says, a few millimetres off the axis: the taught
    pose within 1 mm and 0.15° of where the robot stood, with the wheels' errors calibrated; the CLI writes a
    docking config that dock-sim and the docking node read; a back-off without charging is refused."""
    sim = Simulator(robot=TRUE, nuisances=FAST, seed=9)
    home = teach_start(TRUE.front_offset, np.random.default_rng(9))
    robot = SimulatedRobot(sim, home, rng=np.random.default_rng(10), wheel_scale=WHEELS)
    record_drive(tmp_path / "teach", robot, teach_route(), frame_every=1, progress=False)
    w = np.mean(WHEELS)
    calibrated = dataclasses.replace(
        TRUE, front_offset=NOMINAL.front_offset,
        odometry=dataclasses.replace(TRUE.odometry, distance_scale=w, rotation_scale=w - 1.0,
                                     drift_per_m=(WHEELS[1] - WHEELS[0]) / 0.40 / w),
    )  # fmt: skip
    taught = teach_from_recording(str(tmp_path / "teach"), sim.layout, calibrated)
    assert taught.pose.x == pytest.approx(home.x, abs=0.001)
    assert taught.pose.y == pytest.approx(home.y, abs=0.001)
    assert math.degrees(abs(taught.pose.theta - home.theta)) < 0.15
    # Its front edge is 8 mm shorter than the file says: it charges 8 mm further in, less the 1 mm left at the face.
    assert taught.offset.x == pytest.approx(0.008 - 0.001, abs=0.0015)
    layout, robot_file, out = tmp_path / "layout.yaml", tmp_path / "robot.yaml", tmp_path / "docking.yaml"
    sim.layout.save(layout)
    calibrated.save(robot_file)
    args = ["teach", str(tmp_path / "teach"), "--layout", str(layout), "--robot", str(robot_file), "--out", str(out)]
    assert main(args) == 0
    from monodock.dock.config import load_docking_config

    assert load_docking_config(out).charging_offset.x == pytest.approx(taught.offset.x, abs=1e-9)
    capsys.readouterr()
    # Never charging: a recording of a robot that never touched the contacts.
    away = SimulatedRobot(sim, home._replace(x=home.x - 0.05), rng=np.random.default_rng(11))
    record_drive(tmp_path / "away", away, teach_route(0.4), frame_every=4, progress=False)
    assert main([*args[:1], str(tmp_path / "away"), *args[2:-1], str(tmp_path / "d2.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "never reports CHARGING" in err[0]
