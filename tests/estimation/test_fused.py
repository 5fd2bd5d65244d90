"""The fused estimator: its statistics against synthetic ground truth, and on simulated frames against the truth."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimation.fused import (
    Correction,
    FusedEstimator,
    FusionTables,
    band_index,
    fuse_gaussians,
    fusion_holdout,
    three_cornered_hat,
)


def _draw(rng: np.random.Generator, cov: np.ndarray, n: int) -> np.ndarray:
    return rng.multivariate_normal(np.zeros(3), cov, size=n)


def test_three_cornered_hat_separates_the_reference_noise_from_both_methods() -> None:
    rng = np.random.default_rng(0)
    n = 20000
    cov_a = np.diag([0.002**2, 0.001**2, math.radians(0.1) ** 2])
    cov_b = np.array([[0.006**2, 0.3 * 0.006 * 0.003, 0], [0.3 * 0.006 * 0.003, 0.003**2, 0], [0, 0, 0.03**2]])
    cov_ref = np.diag([0.004**2, 0.002**2, math.radians(0.4) ** 2])
    truth = np.zeros((n, 3))
    a, b, ref = truth + _draw(rng, cov_a, n), truth + _draw(rng, cov_b, n), truth + _draw(rng, cov_ref, n)
    got_a, got_b, got_ref = three_cornered_hat(a - ref, b - ref)
    for got, want in ((got_a, cov_a), (got_b, cov_b), (got_ref, cov_ref)):
        np.testing.assert_allclose(np.sqrt(np.diag(got)), np.sqrt(np.diag(want)), rtol=0.12)
    # Without the hat, method a's variance would be swamped by the reference's (4x its own).
    assert np.cov(a - ref, rowvar=False)[0, 0] > 4 * cov_a[0, 0]


def test_three_cornered_hat_ignores_a_few_gross_rows() -> None:
    rng = np.random.default_rng(1)
    n = 3000
    cov = np.diag([0.003**2, 0.003**2, 0.01**2])
    a, b, ref = (_draw(rng, cov, n) for _ in range(3))
    a[:15] += 0.5  # mislabelled rows
    got_a, _, _ = three_cornered_hat(a - ref, b - ref)
    assert math.sqrt(got_a[0, 0]) == pytest.approx(0.003, rel=0.15)


def test_fusing_two_independent_estimates_beats_both_by_the_expected_amount() -> None:
    rng = np.random.default_rng(2)
    n = 4000
    truth = np.column_stack([rng.uniform(0.5, 2.5, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-3.1, 3.1, n)])
    cov_g = np.diag([0.002**2, 0.004**2, 0.02**2])
    cov_r = np.diag([0.004**2, 0.002**2, 0.02**2])
    g = truth + _draw(rng, cov_g, n)
    r = truth + _draw(rng, cov_r, n)
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


def test_the_correction_undoes_a_miscalibrated_camera() -> None:
    """A mount turned 1 degree and a marker 5 % larger than declared: the learned correction recovers the truth."""
    rng = np.random.default_rng(3)
    n = 600
    pivot = (0.17, 0.02)
    truth = np.column_stack([rng.uniform(0.45, 2.7, n), rng.uniform(-0.4, 0.4, n), np.radians(rng.uniform(-30, 30, n))])
    # The camera's view: turned by -1 degree about the camera and every distance along it 5 % short.
    turned = Correction(yaw_offset=math.radians(-1.0), pivot_x=pivot[0], pivot_y=pivot[1]).apply(truth)
    geometry = Correction(x_scale=1 / 1.05, pivot_x=pivot[0], pivot_y=pivot[1]).apply(turned)
    geometry += _draw(rng, np.diag([0.001**2, 0.001**2, 0.002**2]), n)
    labels = truth + _draw(rng, np.diag([0.003**2, 0.002**2, math.radians(0.4) ** 2]), n)
    labels[:10, 0] += 0.3  # a few bad labels
    c = Correction.fit(geometry, labels, pivot)
    err = c.apply(geometry) - truth
    assert np.abs(err[:, 0]).mean() < 0.003
    assert np.abs(err[:, 1]).mean() < 0.003
    assert math.degrees(np.abs(err[:, 2]).mean()) < 0.15
    before = geometry - truth
    assert np.abs(before[:, 0]).mean() > 0.03  # what the correction removed
    assert np.abs(before[:, 1]).mean() > 0.01


def test_the_correction_leaves_a_calibrated_camera_alone() -> None:
    """Labels with a small bias of their own (0.05 degrees, 1 mm) must not move an exact geometry."""
    rng = np.random.default_rng(5)
    n = 600
    truth = np.column_stack([rng.uniform(0.45, 2.7, n), rng.uniform(-0.4, 0.4, n), np.radians(rng.uniform(-30, 30, n))])
    labels = truth + _draw(rng, np.diag([0.003**2, 0.002**2, math.radians(0.4) ** 2]), n)
    labels[:, 0] += 0.001
    labels[:, 2] += math.radians(0.05)
    c = Correction.fit(truth, labels, (0.17, 0.0))
    assert c.identity
    assert Correction.fit(truth[:5], labels[:5]).identity


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


def test_bands_and_holdout() -> None:
    assert [band_index(d) for d in (0.10, 0.26, 0.51, 3.0)] == [0, 0, 1, 8]
    m = fusion_holdout(1000, 0.1, seed=4)
    assert m.sum() == 100
    np.testing.assert_array_equal(m, fusion_holdout(1000, 0.1, seed=4))
    with pytest.raises(InputError):
        fusion_holdout(10, 1.5)


def _rows_of(fits: list[Any], truth: list[tuple[float, float, float]], camera_x: float) -> Any:
    """Training rows of geometry fits (with their pitch and roll offsets) against the true poses."""
    from monodock.estimation.fused import TrainingRows

    n = len(fits)
    return TrainingRows(
        geometry=np.array([f.pose for f in fits]),
        geometry_cov=np.tile(np.eye(3), (n, 1, 1)),
        geometry_set=["m1m2m3"] * n,
        residual_sigma=np.full(n, 0.05),
        side_px=np.full(n, 40.0),
        regression=np.full((n, 3), np.nan),
        regression_set=[""] * n,
        labels=np.array(truth),
        depth_from_camera=np.array(truth)[:, 0] - camera_x,
        pitch_offset=np.array([f.pitch_offset for f in fits]),
        roll_offset=np.array([f.roll_offset for f in fits]),
    )


def test_the_camera_mount_pitch_and_height_are_learned_from_the_images() -> None:
    """The robot file says the camera is 1 degree less pitched and 1 cm lower than it is: the 4-DoF fits of a few
    dozen views give both errors back, and the 3-DoF fit with them is as good as with the true mount."""
    from dataclasses import replace

    from monodock.estimation.fused import FusedEstimator, fit_mount_offsets
    from monodock.perception.detect import Detection, MarkerObservation
    from monodock.sim import PoseDistribution, Simulator

    sim = Simulator(seed=3)
    m = sim.robot.camera_mount
    wrong = replace(sim.robot, camera_mount=replace(m, pitch=m.pitch - math.radians(1.0), z=m.z - 0.01))
    rng = np.random.default_rng(8)
    dets, truth = [], []
    while len(dets) < 40:
        pose = sim.sample_pose(PoseDistribution(depth=(0.6, 2.4), require_in_view=("left", "center", "right")))
        obs = {
            r: MarkerObservation(r, sim.layout.marker(r).id, c + rng.normal(0, 0.05, c.shape))
            for r, c in sim.true_corners(pose).items()
        }
        dets.append(Detection(obs, (), sim.camera.size))
        truth.append((pose.x, pose.y, pose.yaw))
    probe = FusedEstimator(sim.camera, sim.layout, wrong, FusionTables(0.2))
    fits = [probe.geometry(d, d, pitch_sd=math.radians(3.0)) for d in dets]
    assert all(f is not None for f in fits)
    rows = _rows_of(fits, truth, m.x)
    pitch, height = fit_mount_offsets(rows, wrong.camera_mount.x)
    assert math.degrees(pitch) == pytest.approx(1.0, abs=0.05)
    assert height == pytest.approx(0.01, abs=0.002)

    def depth_error(tables: FusionTables) -> float:
        est = FusedEstimator(sim.camera, sim.layout, wrong, tables)
        got = [est.geometry(d, d) for d in dets]
        return float(np.mean([abs(g.pose[0] - t[0]) for g, t in zip(got, truth, strict=True) if g is not None]))

    assert depth_error(FusionTables(0.2)) > 0.02  # the 3-DoF fit on the wrong mount
    assert depth_error(FusionTables(0.2, mount_pitch_offset=pitch, mount_z_offset=height)) < 0.003


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


def _noisy_detection(sim: object, pose: object, roles: tuple[str, ...], seed: int) -> object:
    from monodock.perception.detect import Detection, MarkerObservation

    rng = np.random.default_rng(seed)
    corners = sim.true_corners(pose)  # type: ignore[attr-defined]
    obs = {
        r: MarkerObservation(r, sim.layout.marker(r).id, corners[r] + rng.normal(0, 0.05, (4, 2)))  # type: ignore[attr-defined]
        for r in roles
    }
    return Detection(obs, (), sim.camera.size)  # type: ignore[attr-defined]


def test_the_regression_runs_only_where_it_can_improve_the_answer() -> None:
    """Three markers at 1 m: a regression 1 cm / 1 degree good cannot improve the planar fit and is not run; one
    as good as the corners is run and pulls the answer; a lone far marker always asks it (the yaw sign). The
    answer does not depend on whether the caller already had the regression's."""
    from monodock.core.pose import DockPose
    from monodock.estimation.fused import FusedEstimator
    from monodock.estimation.pnp import PoseEstimate
    from monodock.sim import Simulator

    sim = Simulator(seed=4)
    truth = DockPose(1.17, 0.05, math.radians(10.0))
    det = _noisy_detection(sim, truth, ("left", "center", "right"), 0)

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
    lone = _noisy_detection(sim, far, ("center",), 1)
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
    from monodock.estimation.fused import _FLOOR_SD, _psd_floor

    s = _FLOOR_SD
    above = np.diag(np.square(10 * s))
    above[0, 1] = above[1, 0] = 0.5 * 100 * s[0] * s[1]
    np.testing.assert_array_equal(_psd_floor(above), above)
    # One direction (x - y) far below the floor: it comes back at the floor, the rest is untouched.
    rank1 = np.outer([1e-3, 1e-3, 0.0], [1e-3, 1e-3, 0.0])
    got = _psd_floor(rank1)
    w = np.linalg.eigvalsh(got / np.outer(s, s))
    assert w.min() == pytest.approx(1.0, rel=1e-9)
    np.testing.assert_allclose(got[0, 0] + got[1, 1] + 2 * got[0, 1], 4e-6, rtol=1e-6)


def test_the_camera_mount_roll_is_learned_from_the_images() -> None:
    """The robot file says the camera is 1 degree less rolled than it is: the 3-DoF fit is centimetres off, the
    roll-offset fits of a few dozen views give the error back, and the fit with it is as good as the truth's."""
    from dataclasses import replace

    from monodock.estimation.fused import FusedEstimator, fit_mount_roll
    from monodock.sim import PoseDistribution, Simulator

    sim = Simulator(seed=5)
    m = sim.robot.camera_mount
    wrong = replace(sim.robot, camera_mount=replace(m, roll=m.roll - math.radians(1.0)))
    dets, truth = [], []
    while len(dets) < 40:
        pose = sim.sample_pose(PoseDistribution(depth=(0.6, 2.4), require_in_view=("center",)))
        dets.append(
            _noisy_detection(
                sim, pose, tuple(r for r in sim.true_corners(pose) if _in_view(sim, pose, r)), 10 + len(dets)
            )
        )
        truth.append((pose.x, pose.y, pose.yaw))
    probe = FusedEstimator(sim.camera, sim.layout, wrong, FusionTables(0.2))
    fits = [probe.geometry(d, d, roll_sd=math.radians(3.0)) for d in dets]  # type: ignore[arg-type]
    assert all(f is not None for f in fits)
    rows = _rows_of(fits, truth, m.x)
    roll = fit_mount_roll(rows)
    assert math.degrees(roll) == pytest.approx(1.0, abs=0.05)

    def errors(tables: FusionTables) -> np.ndarray:
        est = FusedEstimator(sim.camera, sim.layout, wrong, tables)
        got = [est.geometry(d, d) for d in dets]  # type: ignore[arg-type]
        return np.array([np.abs(g.pose[:2] - t[:2]) for g, t in zip(got, truth, strict=True) if g is not None])

    assert errors(FusionTables(0.2)).mean(axis=0).max() > 0.01  # the 3-DoF fit on the wrong mount
    assert errors(FusionTables(0.2, mount_roll_offset=roll)).mean(axis=0).max() < 0.002


def _in_view(sim: object, pose: object, role: str) -> bool:
    corners = sim.true_corners(pose)[role]  # type: ignore[attr-defined]
    return bool(np.all(np.isfinite(corners)) and sim.in_view(corners, 2.0))  # type: ignore[attr-defined]


def test_the_geometry_excess_ignores_label_and_regression_sharing_an_error() -> None:
    """Residuals in units of the geometry's Jacobian sd: a geometry as good as it says (variance 1) next to
    labels and a regression whose lateral errors share a common part reads as no excess; a geometry with 4x
    its Jacobian variance in depth and yaw reads as about that."""
    from monodock.estimation.fused import _excess

    rng = np.random.default_rng(11)
    n = 300
    shared = rng.normal(0, 9.0, n)  # the error the regression's and the label's lateral have in common
    label = rng.normal(0, [1.5, 12.0, 1.5], (n, 3))
    label[:, 1] += shared
    reg = rng.normal(0, [3.0, 40.0, 3.0], (n, 3))
    reg[:, 1] += shared
    # A lower bound: 4x reads as 2-4.5 with 300 rows and labels 1.5x noisier than the geometry.
    for true_var, lo, hi in ((1.0, 1.0, 1.3), (4.0, 2.0, 4.5)):
        geo = rng.normal(0, [math.sqrt(true_var), 1.0, math.sqrt(true_var)], (n, 3))
        got = _excess(geo - label, reg - label)
        assert lo <= got <= hi


def test_the_warm_up_runs_both_refiner_paths_on_valid_views() -> None:
    """Before a live stream, ``Estimator.warm_up`` runs the fused method on a normal and an over-exposed view of the
    dock (the clipped-marker path of the refiner has kernels of its own); the board method needs none."""
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.estimation.estimator import Estimator

    camera, layout, robot = CameraModel.default(), DockLayout.default(), RobotConfig.default()
    fused = FusedEstimator(camera, layout, robot, FusionTables(0.22))
    seen: list[tuple[float, Any]] = []
    for methods in (("board",), ("fused",)):
        est = Estimator(camera, layout, robot, methods, fused=fused)
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
