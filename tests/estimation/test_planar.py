"""The maximum-likelihood planar fit (estimation.planar) on the simulator's true corners: exact recovery, the
Cramér–Rao bound reached by Monte Carlo, candidates, priors, the pitch and roll offsets."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monodock.core.pose import DockPose, wrap_angle
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.crlb import crlb, visible_roles
from monodock.estimation.planar import PlanarFit, PosePrior, planar_model, pose_information, solve_planar
from monodock.estimation.planar_starts import planar_candidates
from monodock.sim import Simulator
from shared import pose_at

ROLE_SETS = [("center",), ("left", "center"), ("left", "center", "right")]


def _errors(a: DockPose, b: DockPose) -> np.ndarray:
    return np.array([a.x - b.x, a.y - b.y, wrap_angle(a.yaw - b.yaw)])


@pytest.mark.parametrize("lens", ["default", "k1=-0.2"])
@pytest.mark.parametrize("roles", ROLE_SETS, ids=["1 marker", "2 markers", "3 markers"])
@pytest.mark.parametrize("truth", [pose_at(1.0, 0.05, 10.0), pose_at(0.7, -0.04, -12.0), pose_at(1.8, 0.2, 25.0)])
def test_exact_corners_recover_the_true_pose(
    sim: Simulator, strong_sim: Simulator, lens: str, roles: tuple[str, ...], truth: DockPose
) -> None:
    """From a start 10 cm and 10 degrees off, exact corners give the true pose to 1e-6 (m and rad)."""
    s = sim if lens == "default" else strong_sim
    corners = s.true_corners(truth)
    assert all(s.in_view(corners[r]) for r in roles)
    start = DockPose(truth.x + 0.06, truth.y - 0.08, truth.yaw + math.radians(10.0))
    fit = solve_planar({r: corners[r] for r in roles}, s.camera, s.layout, s.robot, start=start)
    assert fit.converged
    assert np.all(np.abs(_errors(fit.pose, truth)) < 1e-6), (fit.pose, truth)
    assert fit.rms_px < 1e-3
    assert fit.roles == roles


def test_start_far_off_still_converges(sim: Simulator) -> None:
    """Three markers, a start 40 cm and 25 degrees off: the damping keeps it on the way to the truth."""
    truth = pose_at(1.2, 0.1, -8.0)
    corners = sim.true_corners(truth)
    start = DockPose(truth.x - 0.3, truth.y + 0.25, truth.yaw + math.radians(25.0))
    fit = solve_planar(corners, sim.camera, sim.layout, sim.robot, start=start, max_iterations=50)
    assert fit.converged
    assert np.all(np.abs(_errors(fit.pose, truth)) < 1e-6)


@pytest.mark.parametrize(
    "truth", [pose_at(0.5, 0.0, 3.0), pose_at(1.25, 0.08, -10.0), pose_at(2.2, -0.15, 15.0)], ids=["near", "mid", "far"]
)
def test_monte_carlo_covariance_matches_the_bound(sim: Simulator, truth: DockPose) -> None:
    """iid σ = 0.2 px on the true corners: the estimates' covariance is the CRLB (±15 % per variance)."""
    sigma = 0.2
    corners = sim.true_corners(truth)
    roles = visible_roles(truth, sim.camera, sim.layout, sim.robot)
    assert roles == ("left", "center", "right")
    bound = crlb(truth, sim.camera, sim.layout, sim.robot, sigma)
    rng = np.random.default_rng(11)
    n = 2000
    errs = np.empty((n, 3))
    scales = np.empty(n)
    for k in range(n):
        noisy = {r: corners[r] + rng.normal(0.0, sigma, (4, 2)) for r in roles}
        fit = solve_planar(noisy, sim.camera, sim.layout, sim.robot, start=truth, corner_sigma=sigma)
        assert fit.converged
        errs[k] = _errors(fit.pose, truth)
        scales[k] = fit.noise_scale
    emp = np.cov(errs.T)
    ratio = np.diag(emp) / np.diag(bound)
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
    corr_emp = emp / np.sqrt(np.outer(np.diag(emp), np.diag(emp)))
    corr_bound = bound / np.sqrt(np.outer(np.diag(bound), np.diag(bound)))
    assert np.all(np.abs(corr_emp - corr_bound) < 0.1), (corr_emp, corr_bound)
    # Unbiased to well within the noise, and the residuals measure the true sigma.
    assert np.all(np.abs(errs.mean(axis=0)) < 0.15 * np.sqrt(np.diag(bound)))
    assert abs(np.mean(scales**2) - 1.0) < 0.05
    # The solver's own covariance at its estimate is the bound at the truth.
    assert np.allclose(np.diag(fit.covariance), np.diag(bound), rtol=0.1)


def test_monte_carlo_per_corner_sigma(sim: Simulator) -> None:
    """Unequal noise (left marker 0.5 px, others 0.15 px): the weighted fit reaches the weighted bound,
    and beats the unweighted fit on the same draws."""
    truth = pose_at(1.5, -0.05, 12.0)
    corners = sim.true_corners(truth)
    roles = ("left", "center", "right")
    per_corner = np.array([0.5] * 4 + [0.15] * 8)
    bound = crlb(truth, sim.camera, sim.layout, sim.robot, per_corner, roles=roles)
    rng = np.random.default_rng(5)
    n = 1500
    weighted = np.empty((n, 3))
    plain = np.empty((n, 3))
    for k in range(n):
        noisy_all = np.concatenate([corners[r] for r in roles]) + rng.normal(0.0, 1.0, (12, 2)) * per_corner[:, None]
        noisy = {r: noisy_all[4 * i : 4 * i + 4] for i, r in enumerate(roles)}
        weighted[k] = _errors(
            solve_planar(noisy, sim.camera, sim.layout, sim.robot, start=truth, corner_sigma=per_corner).pose, truth
        )
        plain[k] = _errors(solve_planar(noisy, sim.camera, sim.layout, sim.robot, start=truth).pose, truth)
    ratio = weighted.var(axis=0) / np.diag(bound)
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
    assert np.all(weighted.var(axis=0) < plain.var(axis=0))


def test_corner_covariance_blocks_equal_scalar_sigma(sim: Simulator) -> None:
    """A 2x2 covariance σ²I per corner, a sigma per corner and a scalar σ are the same noise model."""
    truth = pose_at(1.1, 0.03, 7.0)
    rng = np.random.default_rng(3)
    noisy = {r: c + rng.normal(0.0, 0.3, (4, 2)) for r, c in sim.true_corners(truth).items()}
    a = solve_planar(noisy, sim.camera, sim.layout, sim.robot, start=truth, corner_sigma=0.3)
    b = solve_planar(noisy, sim.camera, sim.layout, sim.robot, start=truth, corner_sigma=np.full(12, 0.3))
    c = solve_planar(
        noisy, sim.camera, sim.layout, sim.robot, start=truth, corner_sigma=np.tile(0.09 * np.eye(2), (12, 1, 1))
    )
    for f in (b, c):
        assert np.allclose(_errors(f.pose, a.pose), 0.0, atol=1e-9)
        assert np.allclose(f.covariance, a.covariance, rtol=1e-6)


@pytest.mark.parametrize("truth", [pose_at(2.3, 0.1, 20.0), pose_at(2.0, 0.3, 0.0)])
def test_lone_far_marker_candidates_contain_the_truth(sim: Simulator, truth: DockPose) -> None:
    corners = {"center": sim.true_corners(truth)["center"]}
    cands = planar_candidates(corners, sim.camera, sim.layout, sim.robot)
    assert len(cands) >= 2, "the yaw sign ambiguity has two minima"
    assert cands[0].cost < 1e-6
    assert np.all(np.abs(_errors(cands[0].pose, truth)) < 1e-6)
    assert abs(math.degrees(wrap_angle(cands[1].pose.yaw - truth.yaw))) > 5.0
    assert all(c.converged for c in cands)
    # With noise the wrong minimum may fit better, but one candidate stays within 3 sd of the truth.
    sd = np.sqrt(np.diag(crlb(truth, sim.camera, sim.layout, sim.robot, 0.3, roles=("center",))))
    rng = np.random.default_rng(7)
    for _ in range(5):
        noisy = {"center": corners["center"] + rng.normal(0.0, 0.3, (4, 2))}
        cands = planar_candidates(noisy, sim.camera, sim.layout, sim.robot, corner_sigma=0.3)
        assert any(np.all(np.abs(_errors(c.pose, truth)) < 3 * sd) for c in cands)


def test_candidates_for_three_markers_and_extra_starts(sim: Simulator) -> None:
    truth = pose_at(1.4, -0.1, 15.0)
    corners = sim.true_corners(truth)
    cands = planar_candidates(corners, sim.camera, sim.layout, sim.robot, starts=[DockPose(1.0, 0.0, 0.0)])
    assert np.all(np.abs(_errors(cands[0].pose, truth)) < 1e-6)
    costs = [c.cost for c in cands]
    assert costs == sorted(costs)


def test_prior_pulls_as_expected(sim: Simulator) -> None:
    truth = pose_at(1.3, 0.05, 8.0)
    corners = sim.true_corners(truth)
    offset = np.array([0.05, -0.03, math.radians(4.0)])
    mean = DockPose(truth.x + offset[0], truth.y + offset[1], truth.yaw + offset[2])

    def solve(prior: PosePrior | None) -> PlanarFit:
        return solve_planar(corners, sim.camera, sim.layout, sim.robot, start=truth, prior=prior, max_iterations=50)

    free = solve(None)
    tight = solve(PosePrior(mean, np.diag([1e-14, 1e-14, 1e-14])))
    assert np.all(np.abs(_errors(tight.pose, mean)) < 1e-5)
    assert np.allclose(tight.covariance, np.diag([1e-14] * 3), rtol=1e-3)
    loose = solve(PosePrior(mean, np.eye(3) * 1e6))
    assert np.all(np.abs(_errors(loose.pose, free.pose)) < 1e-8)
    # A prior as informative as the corners, a little off: the answer lands half-way (linear regime).
    small = np.array([0.002, -0.001, math.radians(0.2)])
    near = DockPose(truth.x + small[0], truth.y + small[1], truth.yaw + small[2])
    half = solve(PosePrior(near, free.covariance))
    assert np.allclose(_errors(half.pose, truth), small / 2, atol=0.03 * np.abs(small).max())
    assert np.allclose(half.covariance, free.covariance / 2, rtol=0.02)


def test_bad_input_raises_input_error(sim: Simulator) -> None:
    truth = pose_at(1.0, 0.0, 0.0)
    corners = sim.true_corners(truth)
    args = (sim.camera, sim.layout, sim.robot)
    with pytest.raises(InputError, match="unknown marker role"):
        solve_planar({"middle": corners["center"]}, *args, start=truth)
    with pytest.raises(InputError, match="4 corners"):
        solve_planar({"center": corners["center"][:3]}, *args, start=truth)
    with pytest.raises(InputError, match="finite"):
        solve_planar({"center": np.full((4, 2), np.nan)}, *args, start=truth)
    with pytest.raises(InputError, match="no marker"):
        solve_planar({}, *args, start=truth)
    with pytest.raises(InputError, match="corner sigma"):
        solve_planar({"center": corners["center"]}, *args, start=truth, corner_sigma=np.ones(5))
    with pytest.raises(InputError, match="positive"):
        solve_planar({"center": corners["center"]}, *args, start=truth, corner_sigma=-1.0)
    with pytest.raises(InputError, match="positive definite"):
        solve_planar({"center": corners["center"]}, *args, start=truth, prior=PosePrior(truth, -np.eye(3)))
    with pytest.raises(InputError, match="no dock marker"):
        crlb(DockPose(-2.0, 0.0, 0.0), *args, 0.3)


def test_start_behind_the_camera_is_reported_not_raised(sim: Simulator) -> None:
    corners = sim.true_corners(pose_at(1.0, 0.0, 0.0))
    fit = solve_planar(corners, sim.camera, sim.layout, sim.robot, start=DockPose(-1.0, 0.0, 0.0))
    assert not fit.converged
    assert math.isinf(fit.cost)


PITCH_SD = math.radians(2.0)


def _mount_off(**change: float) -> RobotConfig:
    """The default robot with its camera mount changed: what the simulator renders while the estimator keeps
    RobotConfig.default()."""
    d = RobotConfig.default()
    return dataclasses.replace(d, camera_mount=dataclasses.replace(d.camera_mount, **change))


MOUNT_ERRORS = {
    "pitch +1 deg": {"pitch": math.radians(1.0)},
    "pitch -1 deg": {"pitch": math.radians(-1.0)},
    "height +1 cm": {"z": 0.26},
    "height -1 cm": {"z": 0.24},
}


@pytest.mark.parametrize("error", list(MOUNT_ERRORS))
def test_pitch_offset_absorbs_a_wrong_mount(error: str) -> None:
    """The simulator's camera is pitched 1 degree (or raised 1 cm) against the estimator's RobotConfig.
    Exact corners, 3 markers, 1-2.5 m: the 3-DoF fit is centimetres and degrees off, the fit with the pitch
    offset is within 1 cm and 0.3 degrees (and finds the pitch error itself, sign included)."""
    truth_sim = Simulator(robot=_mount_off(**MOUNT_ERRORS[error]), seed=0)
    believed = RobotConfig.default()
    args = (truth_sim.camera, truth_sim.layout, believed)
    worst3 = 0.0
    for depth in (1.0, 1.75, 2.5):
        for y, yaw_deg in ((0.05, 10.0), (-0.08, -10.0), (0.0, 0.0)):
            truth = pose_at(depth, y, yaw_deg)
            corners = truth_sim.true_corners(truth)
            assert all(truth_sim.in_view(c) for c in corners.values())
            start = DockPose(truth.x + 0.05, truth.y - 0.03, truth.yaw + math.radians(5.0))
            f3 = solve_planar(corners, *args, start=start, max_iterations=50)
            f4 = solve_planar(corners, *args, start=start, max_iterations=50, pitch_sd=PITCH_SD)
            assert f4.converged
            e3, e4 = _errors(f3.pose, truth), _errors(f4.pose, truth)
            assert np.all(np.abs(e4[:2]) < 0.01), (depth, yaw_deg, e4)
            assert abs(math.degrees(e4[2])) < 0.3, (depth, yaw_deg, e4)
            worst3 = max(worst3, abs(e3[0]))
            if error.startswith("pitch"):
                # δ is the mount pitch error (zero roll): exact, and the pose with it.
                want = MOUNT_ERRORS[error]["pitch"]
                assert abs(f4.pitch_offset - want) < 1e-5, (f4.pitch_offset, want)
                assert np.all(np.abs(e4) < 1e-4)
                assert abs(e3[0]) > 0.02
            else:
                # A raised camera looks like one pitched up: δ has the opposite sign of the height error.
                assert f4.pitch_offset * (MOUNT_ERRORS[error]["z"] - RobotConfig.default().camera_mount.z) < 0
    assert worst3 > 0.05, f"the 3-DoF fit should be several cm off, worst {worst3:.3f} m"


def test_pitch_offset_candidates_find_the_truth() -> None:
    """planar_candidates with pitch_sd (IPPE starts only) under a 1 degree mount pitch error."""
    truth_sim = Simulator(robot=_mount_off(pitch=math.radians(1.0)), seed=0)
    truth = pose_at(1.6, -0.1, 12.0)
    corners = truth_sim.true_corners(truth)
    args = (truth_sim.camera, truth_sim.layout, RobotConfig.default())
    best = planar_candidates(corners, *args, pitch_sd=PITCH_SD)[0]
    # Exact but for the prior's small pull towards δ = 0 (a MAP estimate).
    assert np.all(np.abs(_errors(best.pose, truth)) < 1e-4)
    assert abs(best.pitch_offset - math.radians(1.0)) < 1e-5
    plain = planar_candidates(corners, *args)[0]
    assert abs(plain.pose.x - truth.x) > 0.1
    assert plain.pitch_offset == 0.0


@pytest.mark.parametrize("truth", [pose_at(0.8, 0.05, 10.0), pose_at(2.0, -0.2, -20.0)])
def test_pitch_jacobian_matches_finite_differences_of_true_corners(truth: DockPose) -> None:
    """At a pitch offset of 0.7 degrees the 4-column model reproduces the corners of a simulator whose mount
    is pitched by that much, and its Jacobian matches central differences of those corners in x, y, yaw and
    the mount pitch."""
    p0 = math.radians(0.7)
    believed = RobotConfig.default()

    def corners(pose: DockPose, pitch: float) -> np.ndarray:
        c = Simulator(robot=_mount_off(pitch=pitch), seed=0).true_corners(pose)
        return np.concatenate([c[r] for r in ("left", "center", "right")])

    s = Simulator(seed=0)
    px, J = planar_model(s.camera, s.layout, believed).jacobian(truth, ("left", "center", "right"), pitch_offset=p0)
    assert J.shape == (24, 4)
    assert np.allclose(px, corners(truth, p0), atol=1e-9)
    h = 1e-6
    fd = np.empty_like(J)
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        plus = corners(DockPose(truth.x + d[0], truth.y + d[1], truth.yaw + d[2]), p0)
        minus = corners(DockPose(truth.x - d[0], truth.y - d[1], truth.yaw - d[2]), p0)
        fd[:, k] = (plus - minus).ravel() / (2 * h)
    fd[:, 3] = (corners(truth, p0 + h) - corners(truth, p0 - h)).ravel() / (2 * h)
    assert np.allclose(J, fd, rtol=1e-6, atol=1e-4), np.abs(J - fd).max()


def test_pitch_offset_monte_carlo_reaches_its_bound(sim: Simulator) -> None:
    """Correct mount, σ = 0.05 px on the true corners, 3 markers at 1.5 m: the 4-DoF fit's (x, y, yaw)
    covariance is pose_information(pitch_sd) (±15 %), which costs at most 1.3x the 3-DoF bound."""
    sigma = 0.05
    truth = pose_at(1.5, 0.05, 8.0)
    args = (sim.camera, sim.layout, sim.robot)
    roles = visible_roles(truth, *args)
    assert roles == ("left", "center", "right")
    bound3 = pose_information(truth, *args, roles, sigma)
    bound4 = pose_information(truth, *args, roles, sigma, pitch_sd=PITCH_SD)
    assert np.allclose(bound3, crlb(truth, *args, sigma, roles=roles), rtol=1e-9)
    price = np.diag(bound4) / np.diag(bound3)
    assert np.all(price >= 1.0 - 1e-9), price
    assert np.all(price < 1.3), price
    corners = sim.true_corners(truth)
    rng = np.random.default_rng(17)
    n = 1500
    errs = np.empty((n, 3))
    deltas = np.empty(n)
    for k in range(n):
        noisy = {r: corners[r] + rng.normal(0.0, sigma, (4, 2)) for r in roles}
        fit = solve_planar(noisy, *args, start=truth, corner_sigma=sigma, pitch_sd=PITCH_SD)
        assert fit.converged
        errs[k] = _errors(fit.pose, truth)
        deltas[k] = fit.pitch_offset
    emp = np.cov(errs.T)
    ratio = np.diag(emp) / np.diag(bound4)
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
    assert np.all(np.abs(errs.mean(axis=0)) < 0.15 * np.sqrt(np.diag(bound4)))
    assert abs(deltas.mean()) < 4.0 * deltas.std() / math.sqrt(n)
    assert np.allclose(np.diag(fit.covariance), np.diag(bound4), rtol=0.1)
    # Freeing the pitch is visible in the data: the 3-DoF bound is too small for these errors in depth.
    assert np.diag(emp)[0] > np.diag(bound3)[0]


def test_pitch_sd_none_is_the_three_dof_fit(sim: Simulator) -> None:
    """pitch_sd=None is today's fit (pitch_offset 0), and a vanishing pitch prior converges to it."""
    truth = pose_at(1.2, 0.04, -6.0)
    args = (sim.camera, sim.layout, sim.robot)
    rng = np.random.default_rng(23)
    noisy = {r: c + rng.normal(0.0, 0.3, (4, 2)) for r, c in sim.true_corners(truth).items()}
    plain = solve_planar(noisy, *args, start=truth)
    none = solve_planar(noisy, *args, start=truth, pitch_sd=None)
    assert none.pose == plain.pose
    assert none.cost == plain.cost
    assert none.pitch_offset == 0.0
    assert np.array_equal(none.covariance, plain.covariance)
    tight = solve_planar(noisy, *args, start=truth, pitch_sd=1e-9, max_iterations=50)
    assert np.allclose(_errors(tight.pose, plain.pose), 0.0, atol=1e-7)
    assert np.allclose(tight.covariance, plain.covariance, rtol=1e-5)
    assert abs(tight.pitch_offset) < 1e-12
    assert np.allclose(pose_information(truth, *args, ROLE_SETS[2], 0.3, pitch_sd=1e-9), crlb(truth, *args, 0.3))


@pytest.mark.parametrize("bad", [0.0, -0.01, math.nan, math.inf])
def test_bad_pitch_sd_raises_input_error(sim: Simulator, bad: float) -> None:
    truth = pose_at(1.0, 0.0, 0.0)
    corners = sim.true_corners(truth)
    args = (sim.camera, sim.layout, sim.robot)
    with pytest.raises(InputError, match="pitch_sd"):
        solve_planar(corners, *args, start=truth, pitch_sd=bad)
    with pytest.raises(InputError, match="pitch_sd"):
        planar_candidates(corners, *args, pitch_sd=bad)
    with pytest.raises(InputError, match="pitch_sd"):
        pose_information(truth, *args, ROLE_SETS[2], 0.3, pitch_sd=bad)


def test_pitch_prior_as_strong_as_the_corners_lands_half_way() -> None:
    """Mount pitched by 3 sd of what the corners say about δ, exact corners: with pitch_sd equal to that sd
    the MAP pitch offset is half the truth (linear regime), and a very tight prior gives the 3-DoF fit."""
    believed = RobotConfig.default()
    s = Simulator(seed=0)
    truth = pose_at(1.5, 0.05, 8.0)
    roles = ("left", "center", "right")
    sigma = 0.3
    _, J = planar_model(s.camera, s.layout, believed).jacobian(truth, roles, pitch_offset=0.0)
    sd_delta = math.sqrt(np.linalg.inv(J.T @ J / sigma**2)[3, 3])
    error = 3.0 * sd_delta
    corners = Simulator(robot=_mount_off(pitch=error), seed=0).true_corners(truth)
    args = (s.camera, s.layout, believed)
    half = solve_planar(corners, *args, start=truth, corner_sigma=sigma, pitch_sd=sd_delta, max_iterations=50)
    assert half.converged
    assert abs(half.pitch_offset / error - 0.5) < 0.02, half.pitch_offset / error
    free = solve_planar(corners, *args, start=truth, corner_sigma=sigma, pitch_sd=1.0, max_iterations=50)
    assert abs(free.pitch_offset / error - 1.0) < 1e-3
    plain = solve_planar(corners, *args, start=truth, corner_sigma=sigma, max_iterations=50)
    tight = solve_planar(corners, *args, start=truth, corner_sigma=sigma, pitch_sd=1e-9, max_iterations=50)
    assert np.allclose(_errors(tight.pose, plain.pose), 0.0, atol=1e-7)


@pytest.mark.parametrize("roles", ROLE_SETS, ids=["1 marker", "2 markers", "3 markers"])
def test_board_start_is_near_the_truth_and_the_fit_from_it_reaches_it(sim: Simulator, roles: tuple[str, ...]) -> None:
    from monodock.estimation.planar_starts import board_start

    truth = pose_at(1.6, -0.1, 15.0)
    corners = {r: c for r, c in sim.true_corners(truth).items() if r in roles}
    start = board_start(corners, sim.camera, sim.layout, sim.robot)
    if len(roles) < 2:
        assert start is None  # a lone marker's IPPE solutions are ambiguous: planar_candidates handles it
        return
    assert start is not None
    # IPPE's 6-DoF pose, flattened: close, not exact (it fits height, roll and pitch too).
    assert np.all(np.abs(_errors(start, truth)) < [0.02, 0.01, math.radians(1.0)])
    fit = solve_planar(corners, sim.camera, sim.layout, sim.robot, start=start, corner_sigma=0.1)
    assert fit.converged
    assert np.all(np.abs(_errors(fit.pose, truth)) < 1e-6)


@pytest.mark.parametrize("lens", ["default", "k1=-0.2"])
@pytest.mark.parametrize("roles", ROLE_SETS[1:], ids=["2 markers", "3 markers"])
@pytest.mark.parametrize("truth", [pose_at(0.5, 0.03, -20.0), pose_at(1.6, -0.1, 15.0), pose_at(2.3, 0.25, 30.0)])
def test_the_floor_start_is_the_truth_on_exact_corners(
    sim: Simulator, strong_sim: Simulator, lens: str, roles: tuple[str, ...], truth: DockPose
) -> None:
    """The board fit's start (``_floor_start``): the true corners, through a mild or a strong lens, satisfy its
    linear equations exactly at the true pose, so it is the truth (1e-6 m and rad), and the fit from it stays there;
    ``board_fit_stacked`` (the fused method's call) gives what ``board_fit`` gives."""
    from monodock.core.lens import lens_of
    from monodock.estimation.planar_starts import _floor_start, board_fit, board_fit_stacked

    s = sim if lens == "default" else strong_sim
    corners = {r: c for r, c in s.true_corners(truth).items() if r in roles}
    stacked = np.concatenate([corners[r] for r in roles])
    sigma = np.full(len(stacked), 0.1)
    model = planar_model(s.camera, s.layout, s.robot)
    ok, start = _floor_start(model.parts(roles).Z, stacked, 1, 1.0, np.full(2 * len(stacked), 10.0), lens_of(s.camera))
    assert ok
    assert np.all(np.abs(_errors(DockPose(*start), truth)) < 1e-6)
    fit = board_fit_stacked(model, roles, stacked, sigma)
    assert fit is not None
    assert fit.converged
    assert np.all(np.abs(_errors(fit.pose, truth)) < 1e-6)
    checked = board_fit(corners, s.camera, s.layout, s.robot, corner_sigma=0.1)
    assert checked is not None
    assert np.all(np.abs(_errors(checked.pose, fit.pose)) < 1e-9)


def test_the_board_fit_from_the_floor_start_finds_the_ippe_starts_minimum(sim: Simulator) -> None:
    """Noisy corners (0.3 px): the fit from the floor start and the fit from the board's IPPE solution (the start it
    replaced) land on the same minimum, to a hundredth of its standard deviation (each stops within ~1e-3 of it), on
    40 random poses."""
    from monodock.estimation.planar_starts import board_fit, board_start

    rng = np.random.default_rng(11)
    done = 0
    while done < 40:
        truth = pose_at(rng.uniform(0.4, 2.4), rng.uniform(-0.3, 0.3), rng.uniform(-35.0, 35.0))
        roles = visible_roles(truth, sim.camera, sim.layout, sim.robot)
        if len(roles) < 2:
            continue
        corners = {r: c + rng.normal(0.0, 0.3, c.shape) for r, c in sim.true_corners(truth).items() if r in roles}
        fit = board_fit(corners, sim.camera, sim.layout, sim.robot, corner_sigma=0.3)
        start = board_start(corners, sim.camera, sim.layout, sim.robot)
        assert fit is not None
        assert start is not None
        assert fit.converged
        ippe = solve_planar(corners, sim.camera, sim.layout, sim.robot, start=start, corner_sigma=0.3)
        sd = np.sqrt(np.diag(fit.covariance))
        assert np.all(np.abs(_errors(fit.pose, ippe.pose)) < 1e-2 * sd)
        done += 1
