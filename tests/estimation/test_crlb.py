"""The Cramér–Rao bound (estimation.crlb), the corner-noise model (estimation.corner_noise) and what set-up changes
buy (evaluation.what_if)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose import DockPose
from monodock.errors import InputError
from monodock.estimation.corner_noise import CornerNoise, corner_sides_px
from monodock.estimation.crlb import crlb, pose_jacobian, visible_roles
from monodock.evaluation.what_if import Variant, default_variants, scaled_camera, what_if
from monodock.sim import Simulator
from shared import pose_at


@pytest.mark.parametrize("lens", ["default", "k1=-0.2"])
@pytest.mark.parametrize("truth", [pose_at(0.6, 0.02, 5.0), pose_at(2.0, -0.3, -25.0)])
def test_jacobian_matches_finite_differences_of_true_corners(
    sim: Simulator, strong_sim: Simulator, lens: str, truth: DockPose
) -> None:
    s = sim if lens == "default" else strong_sim
    roles = visible_roles(truth, s.camera, s.layout, s.robot)
    assert roles
    J = pose_jacobian(truth, s.camera, s.layout, s.robot, roles)
    h = 1e-6
    fd = np.empty_like(J)
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        plus = s.true_corners(DockPose(truth.x + d[0], truth.y + d[1], truth.yaw + d[2]))
        minus = s.true_corners(DockPose(truth.x - d[0], truth.y - d[1], truth.yaw - d[2]))
        fd[:, k] = (np.concatenate([plus[r] for r in roles]) - np.concatenate([minus[r] for r in roles])).ravel() / (
            2 * h
        )
    assert np.allclose(J, fd, rtol=1e-6, atol=1e-5), np.abs(J - fd).max()


def test_crlb_scales_with_sigma_and_adds_markers(sim: Simulator) -> None:
    pose = pose_at(1.5, 0.0, 10.0)
    args = (sim.camera, sim.layout, sim.robot)
    one = crlb(pose, *args, 0.3, roles=("center",))
    three = crlb(pose, *args, 0.3)
    assert np.allclose(crlb(pose, *args, 0.6), 4 * three)
    assert np.allclose(crlb(pose, *args, np.full(12, 0.3)), three)
    assert np.all(np.diag(three) < np.diag(one))


def test_corner_noise_model() -> None:
    square = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    assert np.allclose(corner_sides_px(square), 40.0)
    noise = CornerNoise(c=1.5, floor_px=0.05, small_side_px=31.0, small_sigma_px=0.5)
    assert np.allclose(noise.sigma(square), 1.5 / math.sqrt(40.0))
    assert np.allclose(noise.sigma(square * 1e4), 0.05)
    assert np.allclose(noise.sigma(square * 0.7), 0.5)  # 28 px: the small-marker regime
    assert np.allclose(CornerNoise(c=1.5, small_sigma_px=0.0).sigma(square * 0.7), 1.5 / math.sqrt(28.0))
    with pytest.raises(InputError):
        CornerNoise(c=-1.0)


def test_what_if_resolution_law(sim: Simulator) -> None:
    """Twice the pixels at the same field of view: J doubles and σ = c/√L shrinks by √2, so every bound
    standard deviation falls to 2^-1.5 of the current one; larger markers help at every depth past 1 m
    (nearer, they leave the picture sooner)."""
    cam, layout, robot = sim.camera, sim.layout, sim.robot
    variants = [v for v in default_variants(cam, layout, robot) if v.name in ("current", "marker x1.5")]
    variants.append(Variant("resolution x2", scaled_camera(cam, 2.0), layout, robot))
    res = what_if(
        cam,
        layout,
        robot,
        variants=variants,
        grid=(1, 3, 3),
        noise=CornerNoise(c=0.6, floor_px=0.0, small_sigma_px=0.0),
    )
    assert res.sd.shape == (3, 9, 3)
    assert np.all(res.poses[0] > 0)
    ratio = res.ratio()
    assert np.allclose(ratio[2], 2**-1.5, rtol=1e-6)
    assert np.all(ratio[1, 3:] < 0.8)
    # Bounds grow with depth.
    assert np.all(np.diff(res.sd[0, :, 0]) > 0)


def test_crlb_with_correlated_corners(sim: Simulator) -> None:
    """Independent corners are the identity correlation; when a marker's four corners shift sideways together
    (correlation rho between their u errors), its lateral position is ~sqrt(1 + 3 rho) times less certain,
    as for the mean of four correlated readings."""
    truth = pose_at(1.0, 0.0, 0.0)
    roles = ("center",)
    iid = crlb(truth, sim.camera, sim.layout, sim.robot, 0.05, roles)
    np.testing.assert_allclose(crlb(truth, sim.camera, sim.layout, sim.robot, 0.05, roles, np.eye(8)), iid)
    rho = 0.8
    C = np.eye(8)
    u = np.arange(0, 8, 2)
    C[np.ix_(u, u)] = rho + (1 - rho) * np.eye(4)
    corr = crlb(truth, sim.camera, sim.layout, sim.robot, 0.05, roles, C)
    assert math.sqrt(corr[1, 1] / iid[1, 1]) == pytest.approx(math.sqrt(1 + 3 * rho), rel=0.15)
    with pytest.raises(InputError):
        crlb(truth, sim.camera, sim.layout, sim.robot, 0.05, roles, np.ones((8, 8)))  # not positive definite
    with pytest.raises(InputError):
        crlb(truth, sim.camera, sim.layout, sim.robot, 0.05, roles, np.eye(4))
