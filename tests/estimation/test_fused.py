"""The fused estimator at run time: its statistics against synthetic ground truth, and on simulated frames against
the truth."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimation.fused import Correction, FusedEstimator, FusionTables, band_index, fuse_gaussians
from shared import draw_gaussian, noisy_detection


def test_fusing_two_independent_estimates_beats_both_by_the_expected_amount() -> None:
    rng = np.random.default_rng(2)
    n = 4000
    truth = np.column_stack([rng.uniform(0.5, 2.5, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-3.1, 3.1, n)])
    cov_g = np.diag([0.002**2, 0.004**2, 0.02**2])
    cov_r = np.diag([0.004**2, 0.002**2, 0.02**2])
    g = truth + draw_gaussian(rng, cov_g, n)
    r = truth + draw_gaussian(rng, cov_r, n)
    fused = np.array([fuse_gaussians([g[i], r[i]], [cov_g, cov_r])[0] for i in range(n)])
    err = fused - truth
    err[:, 2] = (err[:, 2] + math.pi) % (2 * math.pi) - math.pi
    want = np.sqrt(1 / (1 / np.diag(cov_g) + 1 / np.diag(cov_r)))
    np.testing.assert_allclose(err.std(axis=0), want, rtol=0.06)
    _, cov = fuse_gaussians([g[0], r[0]], [cov_g, cov_r])
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), want, rtol=1e-9)
    # Yaws near ±pi average across the seam, not to 0.
    mean, _ = fuse_gaussians([np.array([1, 0, math.pi - 0.01]), np.array([1, 0, -math.pi + 0.01])], [cov_g, cov_g])
    assert abs(abs(mean[2]) - math.pi) < 1e-9


def test_tables_round_trip_and_refuse_malformed_input() -> None:
    cov = np.diag([1e-5, 2e-5, 3e-4])
    t = FusionTables(
        0.7,
        Correction(1.01, 0.001, 0.01, 0.17, 0.0),
        {"m1m2m3": [1.0] * 9},
        {"m2": [cov] * 8 + [None]},
        [cov] * 9,
        {"m2": 100},
    )
    again = FusionTables.from_dict(t.to_dict(), "test")
    assert again.correction == t.correction
    got = again.regression_covariance("m2", 8)
    assert got is not None
    np.testing.assert_array_equal(got, cov)  # the nearest band that has one
    assert again.regression_covariance("m1m2m3", 0) is None
    bad = t.to_dict()
    bad["schema"] = "monodock.fusion/0"
    with pytest.raises(InputError, match="schema"):
        FusionTables.from_dict(bad, "b")
    bad = t.to_dict()
    bad["regression_cov"]["m2"][0] = [[1, 0], [0, 1]]
    with pytest.raises(InputError, match="malformed"):
        FusionTables.from_dict(bad, "b")
    for singular in ([[1e-5, 0, 0], [0, 0, 0], [0, 0, 1e-4]], [[1e-5, 2e-5, 0], [2e-5, 1e-5, 0], [0, 0, 1e-4]]):
        bad = t.to_dict()
        bad["label_cov"][3] = singular
        with pytest.raises(InputError, match="positive definite"):
            FusionTables.from_dict(bad, "b")


def test_bands() -> None:
    assert [band_index(d) for d in (0.10, 0.26, 0.51, 3.0)] == [0, 0, 1, 8]


class _CountingRegression:
    """A stand-in for RegressionEstimator: answers a fixed pose and counts how often it is asked."""

    def __init__(self, answer: object) -> None:
        from types import SimpleNamespace

        self.answer = answer
        self.calls = 0
        self.bundle = SimpleNamespace(sets=("m1m2m3", "m2"))

    def estimate(self, detection: object) -> object:  # noqa: ARG002 (RegressionEstimator's signature)
        self.calls += 1
        return self.answer


def test_the_regression_runs_only_where_it_can_improve_the_answer() -> None:
    """Three markers at 1 m: a regression 1 cm / 1 degree good cannot improve the planar fit and is not run; one
    as good as the corners is run and pulls the answer; a lone far marker always asks it (the yaw sign). The
    answer does not depend on whether the caller already had the regression's."""
    from monodock.core.pose import DockPose
    from monodock.estimation.pnp import PoseEstimate
    from monodock.sim import Simulator

    sim = Simulator(seed=4)
    truth = DockPose(1.17, 0.05, math.radians(10.0))
    det = noisy_detection(sim, truth, ("left", "center", "right"), 0)

    def run(reg_sd: tuple[float, float, float], answer: PoseEstimate, given: bool) -> tuple[PoseEstimate, int]:
        cov = np.diag(np.square(reg_sd))
        tables = FusionTables(0.2, regression_cov={"m1m2m3": [cov] * 9, "m2": [cov] * 9})
        regression = _CountingRegression(answer)
        est = FusedEstimator(sim.camera, sim.layout, sim.robot, tables, regression)
        out = est.estimate(det, det, answer if given else None)  # type: ignore[arg-type]
        return out, regression.calls

    roles = ("left", "center", "right")
    weak_sd = (0.01, 0.01, math.radians(1.0))
    weak, calls = run(weak_sd, PoseEstimate("regression", truth, "", roles), given=False)
    assert calls == 0
    assert weak.pose is not None
    assert weak.covariance is not None
    err = np.array([weak.pose.x - truth.x, weak.pose.y - truth.y, weak.pose.yaw - truth.yaw])
    sd = np.sqrt(np.diag(weak.covariance))
    assert np.all(np.abs(err) < 4 * sd)  # the planar fit alone, inside its own covariance
    assert run(weak_sd, PoseEstimate("regression", truth, "", roles), given=True)[0].pose == weak.pose

    # A regression as good as the geometry (sd ~0.1 mm in depth here), 0.2 mm deeper than the planar fit:
    # it is run, and the fused depth lands about half way between the two.
    reg_pose = DockPose(weak.pose.x + 0.0002, weak.pose.y, weak.pose.yaw)
    strong_sd = (1e-4, 1e-4, math.radians(0.02))
    answer = PoseEstimate("regression", reg_pose, "", roles)
    strong, calls = run(strong_sd, answer, given=False)
    assert calls == 1
    assert strong.pose is not None
    assert 0.2 < (strong.pose.x - weak.pose.x) / 0.0002 < 0.8
    assert run(strong_sd, answer, given=True)[0].pose == strong.pose

    far = DockPose(2.3, 0.0, math.radians(20.0))
    lone = noisy_detection(sim, far, ("center",), 1)
    regression = _CountingRegression(PoseEstimate("regression", far, "", ("center",)))
    cov = np.diag([0.01**2, 0.01**2, math.radians(1.0) ** 2])
    est = FusedEstimator(
        sim.camera, sim.layout, sim.robot, FusionTables(0.2, regression_cov={"m2": [cov] * 9}), regression
    )
    got = est.estimate(lone, lone)  # type: ignore[arg-type]
    assert regression.calls == 1
    assert got.pose is not None
    assert abs(math.degrees(got.pose.yaw - far.yaw)) < 5.0  # the right yaw sign


def test_the_covariance_floor_only_changes_what_is_below_it() -> None:
    from monodock.estimation.fused import _FLOOR_SD, psd_floor

    s = _FLOOR_SD
    above = np.diag(np.square(10 * s))
    above[0, 1] = above[1, 0] = 0.5 * 100 * s[0] * s[1]
    np.testing.assert_array_equal(psd_floor(above), above)
    # One direction (x - y) far below the floor: it comes back at the floor, the rest is untouched.
    rank1 = np.outer([1e-3, 1e-3, 0.0], [1e-3, 1e-3, 0.0])
    got = psd_floor(rank1)
    w = np.linalg.eigvalsh(got / np.outer(s, s))
    assert w.min() == pytest.approx(1.0, rel=1e-9)
    np.testing.assert_allclose(got[0, 0] + got[1, 1] + 2 * got[0, 1], 4e-6, rtol=1e-6)


def test_the_warm_up_runs_both_refiner_paths_on_valid_views() -> None:
    """Before a live stream, ``Estimator.warm_up`` runs the fused method on a normal and an over-exposed view of the
    dock (the clipped-marker path of the refiner has kernels of its own); the board method needs none."""
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.estimation.estimator import Estimator
    from monodock.estimation.methods import MethodSetup, build_methods

    camera, layout, robot = CameraModel.default(), DockLayout.default(), RobotConfig.default()
    setup = MethodSetup(camera, layout, robot, tables=FusionTables(0.22))
    seen: list[tuple[float, Any]] = []
    for methods in (("board",), ("fused",)):
        est = Estimator(camera, layout, robot, build_methods(methods, setup))
        run = est.estimate

        def spy(name: str, stamp: float, image: Any, run: Any = run) -> Any:
            result = run(name, stamp, image)
            seen.append((float(np.mean(image == 255)), result.estimates["fused"].pose))
            return result

        est.estimate = spy  # type: ignore[method-assign]
        est.warm_up()
    assert len(seen) == 2  # none for the board method
    (normal, pose_a), (bright, pose_b) = seen
    assert normal < 0.01  # the charger's white face clips in the second view only
    assert bright > 0.2
    for pose in (pose_a, pose_b):
        assert pose is not None
        assert abs(pose.x - (robot.camera_mount.x + 1.0)) < 0.01
        assert abs(pose.y) < 0.01
        assert abs(pose.yaw) < 0.01


def test_the_compiled_corner_sigmas_are_the_corner_noise_law() -> None:
    """The board fit's per-corner sigmas (``_corner_sigma``, compiled): a square marker L px on a side gets c/sqrt(L),
    an unrefined marker three times that; any quads get CornerNoise's sigmas (the one model, with its floor and
    small-marker terms too); a non-finite corner gives None (the checked path then names it)."""
    from monodock.estimation.corner_noise import CornerNoise
    from monodock.estimation.fused import UNREFINED_SIGMA_FACTOR, _corner_sigma

    square = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    law = CornerNoise.edge_fit(0.22)
    got = _corner_sigma(np.concatenate([square, 2.0 * square]), (0.22, 0.0, 0.0, 0.0), np.array([1.0, 3.0]))
    assert got is not None
    np.testing.assert_allclose(got[:4], 0.22 / math.sqrt(40.0), rtol=1e-12)
    np.testing.assert_allclose(got[4:], UNREFINED_SIGMA_FACTOR * 0.22 / math.sqrt(80.0), rtol=1e-12)
    rng = np.random.default_rng(5)
    for noise in (law, CornerNoise()):
        quads = square[None] * rng.uniform(0.3, 3.0, (3, 1, 1)) + rng.normal(0.0, 3.0, (3, 4, 2))
        terms = (noise.c, noise.floor_px, noise.small_side_px, noise.small_sigma_px)
        np.testing.assert_allclose(
            _corner_sigma(quads.reshape(-1, 2), terms, np.ones(3)), noise.sigma(quads.reshape(-1, 2)), rtol=1e-12
        )
    broken = square.copy()
    broken[2, 1] = np.nan
    assert _corner_sigma(broken, (0.22, 0.0, 0.0, 0.0), np.ones(1)) is None
