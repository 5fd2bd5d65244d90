"""Learning the fused method's tables: the three-cornered hat, the calibration correction and the camera mount,
against synthetic and simulated ground truth."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimation.fused import Correction, FusionTables
from monodock.learning.fusion import fit_correction, fusion_holdout, three_cornered_hat
from shared import draw_gaussian, in_view, noisy_detection


def test_three_cornered_hat_separates_the_reference_noise_from_both_methods() -> None:
    rng = np.random.default_rng(0)
    n = 20000
    cov_a = np.diag([0.002**2, 0.001**2, math.radians(0.1) ** 2])
    cov_b = np.array([[0.006**2, 0.3 * 0.006 * 0.003, 0], [0.3 * 0.006 * 0.003, 0.003**2, 0], [0, 0, 0.03**2]])
    cov_ref = np.diag([0.004**2, 0.002**2, math.radians(0.4) ** 2])
    truth = np.zeros((n, 3))
    a = truth + draw_gaussian(rng, cov_a, n)
    b = truth + draw_gaussian(rng, cov_b, n)
    ref = truth + draw_gaussian(rng, cov_ref, n)
    got_a, got_b, got_ref = three_cornered_hat(a - ref, b - ref)
    for got, want in ((got_a, cov_a), (got_b, cov_b), (got_ref, cov_ref)):
        np.testing.assert_allclose(np.sqrt(np.diag(got)), np.sqrt(np.diag(want)), rtol=0.12)
    # Without the hat, method a's variance would be swamped by the reference's (4x its own).
    assert np.cov(a - ref, rowvar=False)[0, 0] > 4 * cov_a[0, 0]


def test_three_cornered_hat_ignores_a_few_gross_rows() -> None:
    rng = np.random.default_rng(1)
    n = 3000
    cov = np.diag([0.003**2, 0.003**2, 0.01**2])
    a, b, ref = (draw_gaussian(rng, cov, n) for _ in range(3))
    a[:15] += 0.5  # mislabelled rows
    got_a, _, _ = three_cornered_hat(a - ref, b - ref)
    assert math.sqrt(got_a[0, 0]) == pytest.approx(0.003, rel=0.15)


def test_the_correction_undoes_a_miscalibrated_camera() -> None:
    """A mount turned 1 degree and a marker 5 % larger than declared: the learned correction recovers the truth."""
    rng = np.random.default_rng(3)
    n = 600
    pivot = (0.17, 0.02)
    truth = np.column_stack([rng.uniform(0.45, 2.7, n), rng.uniform(-0.4, 0.4, n), np.radians(rng.uniform(-30, 30, n))])
    # The camera's view: turned by -1 degree about the camera and every distance along it 5 % short.
    turned = Correction(yaw_offset=math.radians(-1.0), pivot_x=pivot[0], pivot_y=pivot[1]).apply(truth)
    geometry = Correction(x_scale=1 / 1.05, pivot_x=pivot[0], pivot_y=pivot[1]).apply(turned)
    geometry += draw_gaussian(rng, np.diag([0.001**2, 0.001**2, 0.002**2]), n)
    labels = truth + draw_gaussian(rng, np.diag([0.003**2, 0.002**2, math.radians(0.4) ** 2]), n)
    labels[:10, 0] += 0.3  # a few bad labels
    c = fit_correction(geometry, labels, pivot)
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
    labels = truth + draw_gaussian(rng, np.diag([0.003**2, 0.002**2, math.radians(0.4) ** 2]), n)
    labels[:, 0] += 0.001
    labels[:, 2] += math.radians(0.05)
    c = fit_correction(truth, labels, (0.17, 0.0))
    assert c.identity
    assert fit_correction(truth[:5], labels[:5]).identity


def test_the_fusion_holdout() -> None:
    m = fusion_holdout(1000, 0.1, seed=4)
    assert m.sum() == 100
    np.testing.assert_array_equal(m, fusion_holdout(1000, 0.1, seed=4))
    with pytest.raises(InputError):
        fusion_holdout(10, 1.5)


def _rows_of(fits: list[Any], truth: list[tuple[float, float, float]], camera_x: float) -> Any:
    """Training rows of geometry fits (with their pitch and roll offsets) against the true poses."""
    from monodock.learning.fusion import TrainingRows

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

    from monodock.estimation.fused import FusedEstimator
    from monodock.learning.fusion import fit_mount_offsets
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


def test_the_camera_mount_roll_is_learned_from_the_images() -> None:
    """The robot file says the camera is 1 degree less rolled than it is: the 3-DoF fit is centimetres off, the
    roll-offset fits of a few dozen views give the error back, and the fit with it is as good as the truth's."""
    from dataclasses import replace

    from monodock.estimation.fused import FusedEstimator
    from monodock.learning.fusion import fit_mount_roll
    from monodock.sim import PoseDistribution, Simulator

    sim = Simulator(seed=5)
    m = sim.robot.camera_mount
    wrong = replace(sim.robot, camera_mount=replace(m, roll=m.roll - math.radians(1.0)))
    dets, truth = [], []
    while len(dets) < 40:
        pose = sim.sample_pose(PoseDistribution(depth=(0.6, 2.4), require_in_view=("center",)))
        dets.append(
            noisy_detection(
                sim, pose, tuple(r for r in sim.true_corners(pose) if in_view(sim, pose, r)), 10 + len(dets)
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


def test_the_geometry_excess_ignores_label_and_regression_sharing_an_error() -> None:
    """Residuals in units of the geometry's Jacobian sd: a geometry as good as it says (variance 1) next to
    labels and a regression whose lateral errors share a common part reads as no excess; a geometry with 4x
    its Jacobian variance in depth and yaw reads as about that."""
    from monodock.learning.fusion import _excess

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
