"""The picture of an estimate (the detector's ~/debug_image, monodock show, the reports): its outlines sit on the
markers the simulator drew, and its caption gives the estimate and its sigma."""

from __future__ import annotations

import math

import numpy as np

from monodock.core.pose import DockPose
from monodock.estimation.factory import make_estimator
from monodock.estimation.overlay import _caption_lines, draw_overlay
from monodock.sim import Nuisances, Simulator

GREEN = np.array((60, 200, 60))


def test_the_outlines_sit_on_the_true_corners_and_the_caption_gives_the_pose_and_its_sigma() -> None:
    sim = Simulator(nuisances=Nuisances().updated(supersample=2), seed=4)
    truth = DockPose(1.1, 0.05, math.radians(6.0))
    frame = sim.frame(truth, rng=np.random.default_rng(4))
    estimator = make_estimator(method="fused", camera=sim.camera, layout=sim.layout, robot=sim.robot)
    result = estimator.estimate("f", 0.0, frame.image)
    est = result.estimates["fused"]
    assert result.detection is not None
    assert est.pose is not None
    assert est.covariance is not None
    picture = draw_overlay(frame.image, result.detection, sim.layout, sim.camera, sim.robot, est, scale=1.0)
    assert picture.shape == (*frame.image.shape[:2], 3)
    # Each true corner has the outline's green within a pixel of it.
    greenish = np.all(np.abs(picture.astype(int) - GREEN) < 40, axis=2)
    for role, quad in frame.truth.corners.items():
        for u, v in quad:
            x, y = round(u), round(v)
            assert greenish[y - 1 : y + 2, x - 1 : x + 2].any(), (role, u, v)
    # The caption (the image's bottom rows, darkened) holds two lines of text: the pose, then its sigma.
    bottom = picture[-60:]
    assert (bottom.max(axis=2) > 200).sum() > 300  # white text
    lines = _caption_lines(result.detection, est)
    sx, sy, syaw = np.sqrt(np.diag(est.covariance))
    assert lines[0].startswith(f"fused: x {est.pose.x:.3f} m")
    assert lines[1] == f"sigma: x {sx * 1e3:.1f} mm  y {sy * 1e3:.1f} mm  yaw {math.degrees(syaw):.2f} deg"
