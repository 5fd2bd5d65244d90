"""The glare nuisance (``Nuisances.glare_probability``): a specular highlight that washes out part of one marker in
view, against the markers' true image quads."""

from __future__ import annotations

import math

import cv2
import numpy as np

from monodock.core.pose import DockPose
from monodock.sim import Nuisances, Simulator

POSE = DockPose(1.2, 0.05, math.radians(5.0))


def _frame(glare: float, k: int) -> np.ndarray:
    sim = Simulator(nuisances=Nuisances(glare_probability=glare).updated(supersample=2), seed=1)
    return sim.frame(POSE, rng=np.random.default_rng(k)).image


def _inside_markers() -> np.ndarray:
    sim = Simulator(seed=1)
    mask = np.zeros((sim.camera.height, sim.camera.width), np.uint8)
    for quad in sim.true_corners(POSE).values():
        cv2.fillConvexPoly(mask, np.round(quad).astype(np.int32), 1)
    return mask.astype(bool)


def test_glare_washes_out_part_of_a_marker() -> None:
    inside = _inside_markers()
    for k in range(3):
        plain = _frame(0.0, k)
        glared = _frame(1.0, k)
        assert int(np.count_nonzero((plain >= 250) & inside)) == 0
        washed = int(np.count_nonzero((glared >= 250) & inside))
        assert washed > 15, washed  # a saturated patch on a marker (its cells' black read as white there)
        # only near one spot: most of the markers' area keeps its black cells
        assert washed < 0.5 * int(np.count_nonzero(inside))
