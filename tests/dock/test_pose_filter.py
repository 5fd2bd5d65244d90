"""The dock filter (an EKF on the dock's pose in odometry) against the simulator's truth.

The robot is the simulated differential drive of ``monodock.sim.diffdrive`` (wheel scale error per run, noise
per step), so odometry drifts as it does in closed-loop docking; the frames are the true DockPose plus noise
of a known covariance drawn from a seeded generator (no rendering: the statistics need hundreds of frames).
Errors are measured against the truth: the dock's true pose in the odometry frame is odom ∘ pose⁻¹ (the dock
frame is the simulator's world).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.stats import chi2

from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import DockingConfig
from monodock.dock.controller import DockingMission
from monodock.dock.interface import Odometry
from monodock.dock.pose_filter import (
    GATE_CHI2_3DOF,
    DockFilter,
    MeasurementNoise,
    OdometryNoise,
    measurement_model,
    process_jacobian,
)
from monodock.dock.tracking import Observation
from monodock.sim import Nuisances, Simulator
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot

NOISE = MeasurementNoise.for_method("board")
START = Pose2D(-2.2, 0.10, math.radians(4.0))  # base_link in the dock frame: 2.2 m out, 10 cm left, 4° off
SIM = Simulator(nuisances=Nuisances.clean(), seed=0)  # only its robot and charger are used: nothing is rendered


def _noisy(truth: DockPose, rng: np.random.Generator) -> DockPose:
    """The true DockPose plus a draw of the board method's default covariance."""
    x, y, yaw = np.array([truth.x, truth.y, truth.yaw]) + rng.multivariate_normal(
        np.zeros(3), NOISE.covariance(truth, 3)
    )
    return DockPose(float(x), float(y), float(yaw))


def _state_error(f: DockFilter, robot: SimulatedRobot) -> NDArray[np.float64]:
    """The filter's state minus the dock's true pose in the odometry frame (angle wrapped)."""
    assert f.mean is not None
    truth = robot.odom.compose(robot.pose.inverse())
    e = np.array(f.mean) - np.array(truth)
    e[2] = wrap_angle(float(e[2]))
    return e


@dataclass
class Approach:
    """Per frame: filtered and single-frame DockPose errors (x, y, yaw) and the NEES of the state."""

    filtered: NDArray[np.float64]
    raw: NDArray[np.float64]
    nees: NDArray[np.float64]
    accepted: list[bool]
    traces: list[float]


def approach(
    seed: int,
    *,
    seconds: float = 10.0,
    frame_every: int = 3,
    measure: Callable[[int, DockPose, np.random.Generator], DockPose | None] | None = None,
    start: Pose2D = START,
) -> Approach:
    """A straight-ish approach at 0.12 m/s, steering towards the dock on the truth, frames at ~17 Hz.

    ``measure(i, truth, rng)`` makes frame i's DockPose (None: no markers); default: truth + N(0, NOISE).
    The filter is predicted every 20 ms tick from the odometry and updated at the frames.
    """
    rng = np.random.default_rng([seed, 7])
    robot = SimulatedRobot(SIM, start, DiffDriveConfig(), np.random.default_rng([seed, 3]))
    f = DockFilter()
    out = Approach(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), [], [])
    filtered, raw, nees = [], [], []
    last = robot.odom
    frame = 0
    for tick in range(round(seconds / 0.02)):
        # Steer on the truth (the filter is under test, not the controller): towards the axis, square on.
        w = -2.0 * robot.pose.theta - 3.0 * robot.pose.y
        robot.send_velocity(0.12, float(np.clip(w, -0.3, 0.3)))
        robot.sleep(0.02)
        f.predict(last, robot.odom, 0.02)
        last = robot.odom
        if tick % frame_every:
            continue
        truth = robot.dock_pose()
        cov = NOISE.covariance(truth, 3)
        if measure is None:
            z: DockPose | None = _noisy(truth, rng)
        else:
            z = measure(frame, truth, rng)
        frame += 1
        if z is None:
            out.accepted.append(False)
        else:
            out.accepted.append(f.update(robot.odom, z, cov))
        out.traces.append(float(np.trace(f.cov)))
        if f.mean is None or f.updates < 5:
            continue
        est, _ = f.dock_pose(robot.odom)
        filtered.append([est.x - truth.x, est.y - truth.y, wrap_angle(est.yaw - truth.yaw)])
        raw.append([math.nan] * 3 if z is None else [z.x - truth.x, z.y - truth.y, wrap_angle(z.yaw - truth.yaw)])
        e = _state_error(f, robot)
        nees.append(float(e @ np.linalg.solve(f.cov, e)))
    out.filtered, out.raw, out.nees = np.array(filtered), np.array(raw), np.array(nees)
    return out


# --- the models against the maths -------------------------------------------------------------------------


def _numeric_jacobian(
    fun: Callable[[NDArray[np.float64]], NDArray[np.float64]], x: NDArray[np.float64]
) -> NDArray[np.float64]:
    h = 1e-6
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = h
        diff = fun(x + d) - fun(x - d)
        diff[2] = wrap_angle(float(diff[2]))
        cols.append(diff / (2 * h))
    return np.array(cols).T


def test_measurement_jacobian_is_the_derivative_of_h() -> None:
    """h(s, r) = r⁻¹ ∘ s: the analytic H against finite differences at a generic pose."""
    dock, odom = Pose2D(1.3, -0.4, 2.9), Pose2D(0.2, 0.5, -2.8)
    z, H = measurement_model(dock, odom)
    assert z == pytest.approx(np.array(dock.relative_to(odom)))
    numeric = _numeric_jacobian(lambda s: np.array(Pose2D(*s).relative_to(odom)), np.array(dock))
    np.testing.assert_allclose(H, numeric, atol=1e-7)


def test_process_jacobian_is_the_derivative_of_the_drift() -> None:
    """s' = r ∘ e⁻¹ ∘ r⁻¹ ∘ s: G = ∂s'/∂e at e = 0, lever arm included."""
    dock, odom = Pose2D(2.0, 1.0, 0.3), Pose2D(0.4, -0.2, 1.1)

    def drifted(e: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.array(odom.compose(Pose2D(*e).inverse()).compose(dock.relative_to(odom)))

    numeric = _numeric_jacobian(drifted, np.zeros(3))
    np.testing.assert_allclose(process_jacobian(dock, odom), numeric, atol=1e-7)


def test_odometry_noise_defaults_are_the_simulated_wheels() -> None:
    """The filter's default odometry noise is the simulated base's wheel model (0.5 % per run, 5 % per step)."""
    wheels, noise = DiffDriveConfig(), OdometryNoise()
    assert noise.track_width == wheels.track_width
    assert noise.wheel_scale_sd == wheels.wheel_scale_sd
    assert noise.wheel_noise_sd == wheels.wheel_noise_sd
    assert noise.noise_period == wheels.physics_dt


def test_odometry_noise_covers_the_simulated_drift() -> None:
    """Monte Carlo of the simulated base over 0.5 m straight and a 90° turn in place: the predicted spread of
    the odometry error (summed over the 20 ms steps) is at least the true one and at most ~2x it (the per-run
    scale bias is carried as a random walk that matches it at 1 m)."""
    noise = OdometryNoise()
    for v, w, seconds in ((0.125, 0.0, 4.0), (0.0, 0.5, math.pi)):
        errors = []
        predicted = np.zeros((3, 3))
        for seed in range(150):
            robot = SimulatedRobot(SIM, Pose2D(-2.0, 0.0, 0.0), DiffDriveConfig(), np.random.default_rng(seed))
            robot.send_velocity(v, w)
            last = robot.odom
            for _ in range(round(seconds / 0.02)):
                robot.sleep(0.02)
                if seed == 0:
                    u = robot.odom.relative_to(last)
                    step = noise.increment_covariance(u.x, u.theta, 0.02)
                    # The error so far, E, seen from the new end: u⁻¹ ∘ E ∘ u, linearised (an earlier heading
                    # error swings the later step sideways).
                    c, s = math.cos(u.theta), math.sin(u.theta)
                    T = np.array([[c, s, s * u.x - c * u.y], [-s, c, c * u.x + s * u.y], [0.0, 0.0, 1.0]])
                    predicted = T @ predicted @ T.T + step
                    last = robot.odom
            true_move = robot.pose.relative_to(Pose2D(-2.0, 0.0, 0.0))
            err = robot.odom.inverse().compose(true_move)  # e: the true end seen from the odometry's end
            errors.append([err.x, err.y, wrap_angle(err.theta)])
        sd_true = np.std(np.array(errors), axis=0)
        sd_model = np.sqrt(np.diag(predicted))
        # Heading and along-track: the dominant terms.
        for i in (0, 2):
            assert sd_model[i] > 0.9 * sd_true[i], (v, w, i, sd_model, sd_true)
            assert sd_model[i] < 2.5 * sd_true[i], (v, w, i, sd_model, sd_true)


# --- the filter along an approach --------------------------------------------------------------------------


def test_filtered_error_is_well_below_the_single_frame_error() -> None:
    runs = [approach(seed) for seed in range(4)]
    filtered = np.concatenate([np.abs(r.filtered) for r in runs])
    raw = np.concatenate([np.abs(r.raw) for r in runs])
    mae_f, mae_r = filtered.mean(axis=0), raw.mean(axis=0)
    # Depth and yaw (the noisy components of a frame) at most a third of the single frame's; lateral, which a
    # frame already measures to a few millimetres and the odometry's heading drift swings by the lever arm,
    # at most two thirds (measured: 0.17, 0.48, 0.20).
    assert np.all(mae_f < np.array([0.33, 0.67, 0.33]) * mae_r), (mae_f, mae_r)
    assert all(all(r.accepted) for r in runs)  # honest frames pass the gate


def test_covariance_is_consistent() -> None:
    """NEES of the state against the truth: its mean over runs and frames inside the chi-square band.

    The band is the two-sided 99 % interval of the mean of 3-dof chi-square values from the runs (frames in
    one run are correlated, so only the runs count as independent: a wide band, still failing a filter whose
    covariance is off by a factor of two).
    """
    runs = [approach(seed, seconds=6.0) for seed in range(12)]
    per_run = np.array([r.nees.mean() for r in runs])
    n = len(runs)
    lo, hi = chi2.ppf(0.005, 3 * n) / n, chi2.ppf(0.995, 3 * n) / n
    assert lo < per_run.mean() < hi, (per_run, lo, hi)


def test_a_50cm_outlier_is_rejected() -> None:
    """One frame 50 cm too deep mid-approach: gated out, and the estimate does not move."""

    def measure(i: int, truth: DockPose, rng: np.random.Generator) -> DockPose:
        z = _noisy(truth, rng)
        return DockPose(z.x + 0.5, z.y, z.yaw) if i == 60 else z

    run = approach(1, measure=measure)
    assert run.accepted[60] is False
    assert sum(run.accepted) == len(run.accepted) - 1
    k = 60 - 4  # errors are recorded from the fifth frame on
    assert abs(run.filtered[k, 0] - run.filtered[k - 1, 0]) < 0.003  # the depth did not jump
    assert np.abs(run.filtered[k:, 0]).max() < 0.01


def test_coasting_through_a_blackout_stays_bounded_and_grows_the_covariance() -> None:
    """No markers for 3.6 s (43 cm driven) mid-approach: predict only.

    The covariance grows every frame of it; the error stays within the filter's own gate; the first frame
    after it is accepted; and the covariance at its end is not overconfident: the mean NEES over 30 runs is
    below the chi-square band's top, and above 1 (the per-run wheel-scale bias, carried as a random walk that
    matches it after 1 m, makes it conservative over shorter coasts; measured 2.1).
    """
    dark = range(40, 100)

    def measure(i: int, truth: DockPose, rng: np.random.Generator) -> DockPose | None:
        return None if i in dark else _noisy(truth, rng)

    at_end = []
    for seed in range(30):
        run = approach(seed, seconds=8.0, measure=measure)
        traces = run.traces[dark.start : dark.stop]
        assert all(b > a for a, b in itertools.pairwise(traces))
        assert traces[-1] > 2.0 * run.traces[dark.start - 1]
        assert run.accepted[dark.stop]
        coast = slice(dark.start - 4, dark.stop - 4)  # nees and errors start after 5 updates
        assert run.nees[coast].max() < GATE_CHI2_3DOF
        assert np.abs(run.filtered[coast, :2]).max() < 0.05
        at_end.append(run.nees[dark.stop - 5])
    n = len(at_end)
    assert 1.0 < np.mean(at_end) < chi2.ppf(0.995, 3 * n) / n, at_end


def test_mission_reads_the_observation_covariance() -> None:
    """The mission's track folds a frame in with the covariance it came with, and falls back to the mission's
    defaults (``DockingConfig.measurement``) when it has none or one the filter cannot invert."""
    robot = RobotConfig.default()
    mission = DockingMission(DockingConfig(measurement=NOISE), robot, 0.1)
    pose = DockPose(1.2, 0.05, 0.02)
    assert mission.track.place(Observation(0.0, pose, 3)) is None  # no odometry yet: the frame cannot be placed
    here = Pose2D(0.4, -0.1, 0.3)
    mission.track.move(Odometry(0.0, here, 0.0, 0.0))

    def placed_covariance(observation: Observation) -> NDArray[np.float64]:
        placed = mission.track.place(observation)
        assert placed is not None
        at, seen, cov = placed
        assert at == here
        assert seen == observation.pose  # no taught charging pose: the dock's own
        return cov

    own = np.diag([1e-4, 4e-6, 1e-4])
    np.testing.assert_array_equal(placed_covariance(Observation(0.0, pose, 3, own)), own)
    np.testing.assert_array_equal(placed_covariance(Observation(0.0, pose, 3)), NOISE.covariance(pose, 3))
    broken = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    np.testing.assert_array_equal(placed_covariance(Observation(0.0, pose, 3, broken)), NOISE.covariance(pose, 3))
    assert mission.track.place(Observation(0.0, None, 0)) is None
