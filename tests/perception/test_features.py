"""The papers' features (perception.features): side lengths and the centre offset, against the true corners."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from monodock.core import transforms
from monodock.core.layout import ROLES
from monodock.perception.detect import MarkerDetector
from monodock.perception.features import FEATURE_NAMES, feature_vector, marker_features
from monodock.sim import SimFrame, Simulator


def test_side_lengths_of_true_corners(frames: dict[str, SimFrame]) -> None:
    """Side lengths top (TL-TR), bottom (BR-BL), left (BL-TL), right (TR-BR) = distances of the true corners."""
    for role in ROLES:
        c = frames["all"].truth.corners[role]

        f = marker_features(c)

        expected = [math.dist(c[0], c[1]), math.dist(c[2], c[3]), math.dist(c[3], c[0]), math.dist(c[1], c[2])]
        np.testing.assert_allclose([f.top, f.bottom, f.left, f.right], expected, rtol=1e-12)
        np.testing.assert_allclose(f.corners, c)


def test_side_lengths_reflect_the_view() -> None:
    """A hand-made trapezoid (left side nearer, so taller): the named sides get the right lengths."""
    corners = np.array([[100.0, 50.0], [180.0, 60.0], [180.0, 120.0], [100.0, 130.0]])

    f = marker_features(corners)

    assert (f.top, f.bottom) == pytest.approx((math.hypot(80, 10), math.hypot(80, 10)))
    assert (f.left, f.right) == pytest.approx((80.0, 60.0))
    # The diagonals cross where the perspective image of the centre is, not at the corners' mean.
    np.testing.assert_allclose(f.centre, [100.0 + 80.0 * 80.0 / 140.0, 90.0], atol=1e-9)


@pytest.mark.parametrize("which", ["all", "left_out"])
def test_m2_offset_is_projected_centre_minus_principal_point(
    sim: Simulator, frames: dict[str, SimFrame], which: str
) -> None:
    """m2_offset_u/v = projection of marker 2's 3D centre through the lens minus (cx, cy), within 0.5 px."""
    frame = frames[which]
    detection = MarkerDetector(sim.layout).detect(frame.image)
    features = dict(zip(FEATURE_NAMES, feature_vector(detection, sim.camera), strict=True))
    m2 = sim.layout.marker("center")
    optical_T_dock = transforms.invert(sim.world_T_optical(frame.truth.pose))
    centre = transforms.apply(optical_T_dock, np.array([0.0, m2.y, m2.z]))
    px, _ = cv2.projectPoints(centre.reshape(1, 3), np.zeros(3), np.zeros(3), sim.camera.matrix, sim.camera.dist)
    u, v = px.reshape(2)

    assert abs(u - sim.camera.cx) > 40.0  # off the principal point, so cx vs the image centre matters
    assert features["m2_offset_u"] == pytest.approx(u - sim.camera.cx, abs=0.5)
    assert features["m2_offset_v"] == pytest.approx(v - sim.camera.cy, abs=0.5)
