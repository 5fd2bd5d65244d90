"""Docking: the eight cases, the mission in closed loop with the camera, its states, its failure behaviour (each
way to fail ends with its ``FailureReason``), and the base.

Every check is against the simulator's truth (where the robot really is), never against the controller's own
belief about itself.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from monodock.cli.main import main
from monodock.core import settings
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.projection import blind_gap
from monodock.core.robot import RobotConfig
from monodock.dock import (
    CASES,
    DockingConfig,
    DockingMission,
    Observation,
    PlannerConfig,
    State,
    classify,
    plan,
    point_a,
    run_mission,
)
from monodock.dock.pose_filter import DockFilter, MeasurementNoise
from monodock.dock.states import FailureReason
from monodock.dock.tracking import make_perceive
from monodock.estimation.estimator import Estimator
from monodock.sim import Nuisances, Simulator
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot
from shared import truthful_robot

FRONT = RobotConfig.default().front_offset

# A hand-placed start per case: (x, y, heading in degrees) of base_link in the dock frame. Point A sits at
# x = -1.34 (1.0 m of floor before the face, front edge 0.34 m ahead of base_link).
HAND_PLACED = {
    1: (-2.0, 0.30, -12.0),  # left, turned right (towards the axis), before A
    2: (-2.0, -0.30, 12.0),  # right, turned left, before A
    3: (-1.9, 0.20, 8.0),  # left, turned left (away), before A
    4: (-1.9, -0.20, -8.0),  # right, turned right (away), before A
    5: (-1.15, 0.25, -25.0),  # left, towards, past A
    6: (-1.15, -0.25, 25.0),  # right, towards, past A
    7: (-1.20, 0.15, 4.0),  # left, away, past A
    8: (-1.20, -0.15, -4.0),  # right, away, past A
}


def _start(case: int) -> Pose2D:
    x, y, h = HAND_PLACED[case]
    return Pose2D(x, y, math.radians(h))


# --- the planner ------------------------------------------------------------------------------------------


def test_point_a_is_on_the_axis_at_the_standoff() -> None:
    a = point_a(PlannerConfig(standoff=0.8), front_offset=0.3)
    assert a == Pose2D(-1.1, 0.0, 0.0)


@pytest.mark.parametrize("case", sorted(CASES))
def test_planner_classifies_hand_placed_starts(case: int) -> None:
    a = point_a(PlannerConfig(), FRONT)
    assert classify(_start(case), a) == case


@pytest.mark.parametrize("case", sorted(CASES))
def test_manoeuvre_reaches_point_a_and_ends_square(case: int) -> None:
    """Executing the plan exactly (turn, straight leg, turn) lands on Point A facing the charger."""
    start = _start(case)
    m = plan(start, PlannerConfig(), FRONT)
    assert m.case == case
    heading = start.theta + m.first_turn
    direction = -1.0 if m.reverse else 1.0
    end_x = start.x + direction * m.drive_distance * math.cos(heading)
    end_y = start.y + direction * m.drive_distance * math.sin(heading)
    assert end_x == pytest.approx(m.point_a.x, abs=1e-9)
    assert end_y == pytest.approx(0.0, abs=1e-9)
    assert wrap_angle(heading + m.second_turn) == pytest.approx(0.0, abs=1e-9)
    # Past Point A the robot backs onto it; before it, it drives forwards.
    assert m.reverse == (CASES[case].zone == "past")
    # The last turn squares up towards the side the robot came from: left of the axis, a left turn before A.
    side = 1.0 if CASES[case].side == "left" else -1.0
    expected_second = side if CASES[case].zone == "before" else -side
    assert math.copysign(1.0, m.second_turn) == expected_second


def test_heading_away_takes_the_longer_first_turn() -> None:
    """Same place, mirrored headings: turning away from the axis first costs more than turning towards it."""
    towards = plan(Pose2D(-2.0, 0.3, math.radians(-10)), PlannerConfig(), FRONT)
    away = plan(Pose2D(-2.0, 0.3, math.radians(10)), PlannerConfig(), FRONT)
    assert (towards.case, away.case) == (1, 3)
    assert abs(away.first_turn) > abs(towards.first_turn)
    assert away.first_turn < 0
    assert towards.first_turn < 0


# --- the dock filter -----------------------------------------------------------------------------------------


def test_filter_averages_frames_and_gates_outliers() -> None:
    """Frames with known noise from one standing pose: the filter lands on the truth; a 50 cm outlier is refused."""
    rng = np.random.default_rng(0)
    dock_in_odom = Pose2D(1.5, 0.2, math.radians(5.0))
    track = DockFilter()
    noise = MeasurementNoise()
    robot = Pose2D(0.0, 0.0, 0.0)
    truth = DockPose(*dock_in_odom.relative_to(robot))
    for _ in range(60):
        frame = DockPose(truth.x + rng.normal(0, 0.01), truth.y + rng.normal(0, 0.003), truth.yaw + rng.normal(0, 0.04))
        track.update(robot, frame, noise.covariance(frame, 3))
    assert track.mean is not None
    assert track.mean.x == pytest.approx(dock_in_odom.x, abs=0.005)
    assert track.mean.y == pytest.approx(dock_in_odom.y, abs=0.002)
    assert math.degrees(track.mean.theta - dock_in_odom.theta) == pytest.approx(0.0, abs=0.6)
    before = track.mean
    assert not track.update(robot, DockPose(truth.x + 0.5, truth.y, truth.yaw), noise.covariance(truth, 3))
    assert track.mean == before


# --- the simulated base ---------------------------------------------------------------------------------------


def _robot(start: Pose2D, **drive: object) -> SimulatedRobot:
    sim = Simulator(nuisances=Nuisances().updated(supersample=4), seed=1)
    return SimulatedRobot(sim, start, DiffDriveConfig(**drive), np.random.default_rng(3))  # type: ignore[arg-type]


def test_ideal_base_drives_as_commanded_and_odometry_is_exact() -> None:
    robot = _robot(Pose2D(-2.0, 0.0, 0.0), wheel_scale_sd=0.0, wheel_noise_sd=0.0)
    robot.send_velocity(0.2, 0.0)
    robot.sleep(2.0)
    robot.send_velocity(0.0, 0.0)
    robot.sleep(1.0)
    moved = robot.pose.x + 2.0
    # 2 s at 0.2 m/s, less the command latency, give or take the motors' lag on both ends.
    assert moved == pytest.approx(0.2 * 2.0, abs=0.01)
    assert robot.odom.x == pytest.approx(moved, abs=1e-9)
    assert robot.pose.y == pytest.approx(0.0, abs=1e-12)


def test_wheel_slip_makes_odometry_drift_from_the_truth() -> None:
    robot = _robot(Pose2D(-2.0, 0.0, 0.0), wheel_scale_sd=0.02)
    robot.send_velocity(0.2, 0.0)
    robot.sleep(5.0)
    true_move = Pose2D(robot.pose.x + 2.0, robot.pose.y, robot.pose.theta)
    odom = robot.odom
    assert abs(odom.theta - true_move.theta) > math.radians(0.2) or abs(odom.x - true_move.x) > 0.005


def test_camera_runs_at_its_rate_and_frames_arrive_late() -> None:
    robot = _robot(Pose2D(-1.5, 0.0, 0.0))
    stamps = []
    for _ in range(100):
        robot.sleep(0.02)
        f = robot.latest_frame()
        if f is not None and (not stamps or f.stamp != stamps[-1]):
            assert robot.now() - f.stamp >= robot.config.camera_latency - 1e-9
            stamps.append(f.stamp)
    gaps = np.diff(stamps)
    assert np.allclose(gaps, 1.0 / 15.0, atol=robot.config.physics_dt + 1e-9)


def test_the_face_is_solid() -> None:
    robot = _robot(Pose2D(-(FRONT + 0.05), 0.0, 0.0), wheel_scale_sd=0.0, wheel_noise_sd=0.0)
    robot.send_velocity(0.1, 0.0)
    robot.sleep(2.0)
    assert robot.front_gap() == pytest.approx(0.0, abs=1e-9)
    assert robot.pushed > 0.1
    assert robot.longitudinal_error() < -0.1
    assert robot.impact_speed == pytest.approx(0.1, abs=0.01)


# --- the mission in closed loop ------------------------------------------------------------------------------


def _mission(robot: SimulatedRobot, **config: object) -> DockingMission:
    sim = robot.sim
    cfg = settings.replace(DockingConfig(measurement=MeasurementNoise.for_method("board")), **config)
    return DockingMission(cfg, sim.robot, blind_gap(sim.camera, sim.layout, sim.robot))


def _board(robot: SimulatedRobot) -> Estimator:
    sim = robot.sim
    return Estimator(sim.camera, sim.layout, sim.robot, ("board",))


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_case_docks_from_a_hand_placed_start(case: int) -> None:
    """The mission classifies the start from its own estimate, drives its manoeuvre and docks, by the truth."""
    robot = _robot(_start(case))
    mission = _mission(robot)
    result = run_mission(robot, make_perceive(_board(robot), "board"), mission)
    assert result.state is State.DOCKED, result.log
    assert (result.failure, result.reason) == (None, "")
    assert result.case == case
    p = robot.pose
    assert abs(p.y) < 0.01  # lateral, metres
    assert abs(math.degrees(p.theta)) < 1.5
    assert abs(robot.longitudinal_error()) < 0.01
    assert robot.impact_speed is not None
    assert robot.impact_speed < 0.05
    # It went through Point A (within the odometry's drift), backwards when it started past it.
    path = np.array([(s.pose.x, s.pose.y) for s in robot.truth])
    a = point_a(PlannerConfig(), FRONT)
    assert np.min(np.hypot(path[:, 0] - a.x, path[:, 1] - a.y)) < 0.05
    if CASES[case].zone == "past":
        assert path[:, 0].min() < _start(case)[0] - 0.05  # it backed away from the face first


@pytest.mark.parametrize(
    "start",
    [
        Pose2D(-2.2, 0.45, math.radians(-18)),  # crossing ahead: forward to A, then Θab
        Pose2D(-1.3, 0.25, math.radians(15)),  # heading away from the axis: A behind, on the heading line; reverse
    ],
)
def test_the_papers_planner_drives_straight_along_its_heading_line_and_docks(start: Pose2D) -> None:
    """``kind="papers"``: Point A on the heading line, Moving₁ a straight leg there with no turn of its own (a
    centring turn for a lone marker is undone), Moving₂ the turn by Θab; docked within the tolerances by the truth."""
    robot = _robot(start)
    mission = _mission(robot, planner=PlannerConfig(kind="papers"))
    result = run_mission(robot, make_perceive(_board(robot), "board"), mission)
    assert result.state is State.DOCKED, result.log
    m = mission.manoeuvre
    assert m is not None
    assert m.first_turn == 0.0
    assert m.reverse == (start.y * math.sin(start.theta) > 0)
    # The drive to A is one straight leg, along the start's heading (within the estimate's and odometry's errors).
    entered = {entry.split(":")[0]: t for t, entry in result.log}
    leg = np.array([(s.pose.x, s.pose.y) for s in robot.truth if entered["moving1-drive"] <= s.t <= entered["moving2"]])
    chord = leg[-1] - leg[0]
    normal = np.array([-chord[1], chord[0]]) / np.linalg.norm(chord)
    # Straight to within the wheels' drift: the base steers on odometry, whose per-run wheel-scale error bows the
    # true path by ~1 cm over a 1.4 m leg.
    assert np.max(np.abs((leg - leg[0]) @ normal)) < 0.02
    assert abs(
        wrap_angle(math.atan2(chord[1], chord[0]) + (math.pi if m.reverse else 0.0) - start.theta)
    ) < math.radians(3)
    assert abs(robot.pose.y) < 0.01
    assert abs(math.degrees(robot.pose.theta)) < 1.5
    assert abs(robot.longitudinal_error()) < 0.01


def test_markers_hidden_mid_approach_stop_the_robot_within_the_timeout() -> None:
    """With no retries left, markers lost mid-approach end the mission: stopped within the lost-markers timeout."""
    robot = _robot(Pose2D(-1.6, 0.0, 0.0))
    hidden_from: list[float] = []

    def hide(t: float, pose: Pose2D) -> bool:
        if pose.x > -0.9:  # base_link 0.9 m from the face: the front edge ~0.56 m away, well before the blind zone
            if not hidden_from:
                hidden_from.append(t)
            return True
        return False

    robot.hide_markers = hide
    mission = _mission(robot, max_retries=0)
    result = run_mission(robot, make_perceive(_board(robot), "board"), mission)
    assert result.state is State.FAILED
    assert result.failure is FailureReason.MARKERS_LOST
    assert "markers lost" in result.reason
    assert hidden_from
    # Stopped: the last commanded and measured speeds are zero, and it did so within the timeout, plus the
    # frame latency and braking at the acceleration limit.
    robot.sleep(0.5)
    assert abs(robot.odometry().linear) < 1e-3
    braking = mission.config.limits.approach_speed / mission.config.limits.linear_accel
    assert result.duration - hidden_from[0] < mission.config.watch.lost_timeout + 0.2 + braking
    assert robot.front_gap() > 0.3  # nowhere near the face


def _nothing(stamp: float, _image: np.ndarray) -> Observation:
    return Observation(stamp, None)


def test_estimator_with_nothing_means_no_motion() -> None:
    robot = _robot(Pose2D(-1.5, 0.1, 0.0))
    result = run_mission(robot, _nothing, _mission(robot, acquire=False))
    assert result.state is State.FAILED
    assert result.failure is FailureReason.NOT_IN_VIEW
    assert "acquire is off" in result.reason
    path = np.array([s.pose for s in robot.truth])
    assert np.ptp(path[:, 0]) == 0.0
    assert np.ptp(path[:, 1]) == 0.0
    assert np.ptp(path[:, 2]) == 0.0


def test_acquire_gives_up_cleanly_after_a_full_turn() -> None:
    """Nothing to find: the robot turns on the spot once, slowly, stops, and says so."""
    robot = _robot(Pose2D(-1.5, 0.1, 0.0))
    mission = _mission(robot, acquire_turn_rate=0.8)  # faster than the default 0.3 rad/s, to keep the test short
    result = run_mission(robot, _nothing, mission)
    assert result.state is State.FAILED
    assert result.failure is FailureReason.NOT_FOUND
    assert "full turn" in result.reason
    headings = np.unwrap([s.pose.theta for s in robot.truth])
    assert headings[-1] - headings[0] > math.radians(350)
    path = np.array([(s.pose.x, s.pose.y) for s in robot.truth])
    assert np.max(np.hypot(path[:, 0] - path[0, 0], path[:, 1] - path[0, 1])) < 0.01  # on the spot
    robot.sleep(0.5)
    assert abs(robot.odometry().angular) < 1e-3


def test_acquire_finds_a_dock_out_of_view_and_docks() -> None:
    robot = _robot(Pose2D(-1.8, -0.1, math.radians(-60)))  # the charger is 60 degrees to the left, out of view
    corners = robot.sim.true_corners(robot.dock_pose())["center"]
    assert not robot.sim.in_view(corners)
    result = run_mission(robot, make_perceive(_board(robot), "board"), _mission(robot))
    assert any("markers in view" in entry for _, entry in result.log)
    assert result.state is State.DOCKED, result.log
    assert abs(robot.pose.y) < 0.01
    assert abs(math.degrees(robot.pose.theta)) < 1.5


def test_mission_time_out_stops_the_robot_and_says_so() -> None:
    """Still searching when the mission's time is up: a zero command and ``TIMEOUT``, not a silent hang."""
    robot = truthful_robot(Pose2D(-1.5, 0.1, 0.0))
    mission = _mission(robot, mission_timeout=2.0)
    result = run_mission(robot, _nothing, mission)
    assert result.state is State.FAILED
    assert result.failure is FailureReason.TIMEOUT
    assert result.reason == "mission took longer than 2 s"
    assert result.duration == pytest.approx(2.0, abs=2 * mission.config.limits.control_period)
    headings = np.unwrap([s.pose.theta for s in robot.truth])
    assert headings[-1] - headings[0] > math.radians(10)  # it was turning to look when the time ran out
    robot.sleep(0.5)
    assert abs(robot.odometry().angular) < 1e-3


def test_final_pose_outside_the_tolerances_fails_after_the_retries() -> None:
    """A tolerance nothing meets: one retry from Point A, then ``OUTSIDE_TOLERANCES``, stopped at the face."""
    robot = truthful_robot(Pose2D(-1.6, 0.0, 0.0))
    result = run_mission(robot, robot.perceive_truth, _mission(robot, tolerance_lateral=0.0, max_retries=1))
    assert result.state is State.FAILED, result.log
    assert result.failure is FailureReason.OUTSIDE_TOLERANCES
    assert result.reason.startswith("final pose outside the tolerances: lateral ")
    assert result.retries == 1
    states = [entry.split(":")[0] for _, entry in result.log]
    assert states.count(State.SETTLE.value) == 2
    assert states[-2:] == [State.SETTLE.value, State.FAILED.value]
    # By the truth it is at the face and still: the judgement failed, not the driving.
    assert robot.front_gap() < 0.01
    robot.sleep(0.5)
    assert abs(robot.odometry().linear) < 1e-3


def test_failure_reasons_map_to_nav2_docking_error_codes() -> None:
    """Each reason has the nearest ``nav2_msgs/action/DockRobot`` result code (903 stage, 904 detect, 905 control,
    906 charge), as Nav2's docking server raises them: its time-outs end 905, never 907 (docking_server.cpp, Kilted)."""
    codes = {reason: reason.nav2_error_code for reason in FailureReason}
    assert codes == {
        FailureReason.NOT_IN_VIEW: 904,
        FailureReason.NOT_FOUND: 904,
        FailureReason.MARKERS_LOST: 904,
        FailureReason.DOCK_LOST: 904,
        FailureReason.APPROACH_STALLED: 905,
        FailureReason.OUTSIDE_TOLERANCES: 905,
        FailureReason.OBSTACLE_BEHIND: 905,
        FailureReason.REVERSE_LIMIT: 905,
        FailureReason.NOT_CHARGING: 906,
        FailureReason.TIMEOUT: 905,
        FailureReason.STAGING_TIMEOUT: 903,
        FailureReason.ODOMETRY_LOST: 905,
        FailureReason.CANCELLED: 0,
    }


def test_every_state_has_its_own_handler() -> None:
    """The dispatch table covers every state; each state that is not final has a handler of its own."""
    mission = DockingMission(DockingConfig(), RobotConfig.default(), 0.1)
    handlers = mission._handlers
    assert set(handlers) == set(State)
    working = [s for s in State if not s.final]
    assert {s for s in State if s.final} == {State.DOCKED, State.UNDOCKED, State.FAILED}
    assert len({handlers[s].__name__ for s in working}) == len(working)
    for s in working:
        assert handlers[s].__name__ == f"_on_{s.name.lower()}"


def test_a_docking_with_a_retry_goes_through_every_state() -> None:
    """From a start with the dock out of view and a checkpoint nothing passes (one retry allowed), the log of a
    successful docking visits every state of a docking that went well but for the checkpoint, in the order the
    handlers hand over. (Recovering from lost markers, re-seating and undocking have tests of their own, in
    test_mission_recovery.py; the far approach, which a start 1.8 m out on the axis does not need, in
    test_far_approach.py.)"""
    robot = truthful_robot(Pose2D(-1.8, -0.1, math.radians(-60)))  # the dock out of view, to the left
    mission = _mission(robot, retry_lateral=0.0, max_retries=1)
    result = run_mission(robot, robot.perceive_truth, mission)
    assert result.state is State.DOCKED, result.log
    assert (result.failure, result.retries) == (None, 1)
    states = [State(entry.split(":")[0]) for _, entry in result.log]
    skipped = {State.FAILED, State.RECOVER, State.RESEAT, State.UNDOCK, State.UNDOCKED, State.FAR_APPROACH}
    assert set(states) == set(State) - skipped
    assert states[:2] == [State.ACQUIRE, State.CALCULATE]
    for before, after in (
        (State.CENTER, State.CALCULATE),
        (State.MOVING1_BACK, State.MOVING1_TURN),
        (State.CHARGE_WAIT, State.DOCKED),
        (State.MOVING1_TURN, State.MOVING1_DRIVE),
        (State.MOVING1_DRIVE, State.MOVING2),
        (State.MOVING2, State.MOVING3),
        (State.BACK_OFF, State.CALCULATE),
    ):
        assert all(states[i + 1] is after for i, s in enumerate(states) if s is before)
    assert abs(robot.pose.y) < 0.01
    assert abs(math.degrees(robot.pose.theta)) < 1.5


# --- the dock-sim command -----------------------------------------------------------------------------------

ERROR_KEYS = {"mean", "median", "p95", "max"}
CONTRACT_KEYS = {
    "runs",
    "successes",
    "success_rate",
    "final_lateral_cm",
    "final_longitudinal_cm",
    "final_heading_deg",
    "time_s",
}


def test_dock_sim_writes_the_summary_contract(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "dock"
    args = ["dock-sim", "--cases", "2,7", "--trials", "1", "--method", "board", "--out", str(out), "--jobs", "2"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["cases"]) == {"2", "7"}
    for block in (summary["overall"], *summary["cases"].values()):
        assert set(block) >= CONTRACT_KEYS
        for key in ("final_lateral_cm", "final_longitudinal_cm", "final_heading_deg", "time_s"):
            assert set(block[key]) == ERROR_KEYS
    assert summary["overall"]["runs"] == 2
    assert summary["overall"]["success_rate"] == summary["overall"]["successes"] / 2
    assert summary["overall"]["successes"] == 2  # board PnP from two ordinary starts
    # The numbers are the truth's: the CSV's per-run errors agree with the summary.
    with (out / "runs.csv").open() as f:
        rows = list(csv.DictReader(f))
    lateral = [abs(float(r["lateral_cm"])) for r in rows]
    assert summary["overall"]["final_lateral_cm"]["max"] == pytest.approx(max(lateral), abs=1e-3)
    assert max(lateral) < 1.0
    # The filter against single frames, by the truth: every Moving₃ frame recorded, its errors small.
    acc = summary["filter"]["board"]
    assert [b["depth_cm"] for b in acc["bands"]] == [[d, d + 25] for d in range(25, 250, 25)]
    assert acc["all"]["frames"] == sum(b["frames"] for b in acc["bands"]) > 50
    assert acc["under_25cm"]["coasting_frames"] > 0  # the blind zone, driven on the filter alone
    assert acc["all"]["filtered"]["depth_cm"] < 1.0
    assert acc["all"]["filtered"]["lateral_cm"] < 0.5
    assert acc["all"]["filtered"]["yaw_deg"] < acc["all"]["single_frame"]["yaw_deg"]
    assert acc["under_25cm"]["coasting"]["lateral_cm"] < 0.5
    for name in ("report.html", "final_errors.png", "trajectories_case_2.png", "monodock_case_7.png"):
        assert (out / name).is_file(), name
    assert "docked 2/2" in capsys.readouterr().out
    # Nothing is replaced without --force.
    before = (out / "summary.json").read_bytes()
    assert main(args) == 2
    assert (out / "summary.json").read_bytes() == before


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--cases", "9"], "eight cases"),
        (["--method", "sonar"], "unknown method"),
        (["--method", "regression", "--model", "/nonexistent/bundle"], "bundle"),
        (["--distance", "2.0", "1.0"], "--distance"),
        (["--standoff", "3.0"], "no starts"),
        (["--max-heading", "-5"], "--max-heading"),
        (["--starts", "room", "--cases", "1"], "drop --cases"),
        (["--starts", "room", "--distance", "1", "2"], "drop --distance"),
        (["--starts", "room", "--max-heading", "20"], "drop --max-heading"),
        (["--starts", "hall"], "--starts"),
    ],
)
def test_dock_sim_bad_options_are_one_line(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("MONODOCK_CACHE", str(tmp_path / "cache"))  # never train into the user's cache
    try:
        code = main(["dock-sim", "--trials", "1", "--jobs", "1", *args])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    assert code == 2
    assert not (tmp_path / "cache").exists()  # refused before any training
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert message in err
