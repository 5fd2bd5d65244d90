"""The compiled lens model against OpenCV's ``cv2.projectPoints``, an independent implementation.

Both distortion models, strong coefficients (a wide lens), points over and beyond the image; the Jacobian
d(u, v)/d(X, Y, Z) against projectPoints' own (its tvec columns, with rvec = tvec = 0).
"""

from __future__ import annotations

import numpy as np
import pytest

from monodock.core.camera import CameraModel
from monodock.core.lens import distort, lens_of, project

CAMERAS = {
    "plumb_bob": CameraModel(
        640, 480, (610.0, 0.0, 322.0, 0.0, 605.0, 238.0, 0.0, 0.0, 1.0), (-0.28, 0.09, 1e-3, -2e-3, -0.012)
    ),
    "rational_polynomial": CameraModel(
        1280,
        720,
        (700.0, 0.0, 645.0, 0.0, 698.0, 355.0, 0.0, 0.0, 1.0),
        (0.6, -0.05, 5e-4, -8e-4, 0.01, 0.95, 0.02, 0.015),
        "rational_polynomial",
    ),
}


def _points(camera: CameraModel, n: int = 300) -> np.ndarray:
    """Points in front of the camera whose rays reach a little beyond the image."""
    rng = np.random.default_rng(5)
    uv = rng.uniform([-0.1 * camera.width, -0.1 * camera.height], [1.1 * camera.width, 1.1 * camera.height], (n, 2))
    z = rng.uniform(0.2, 4.0, n)
    x = (uv[:, 0] - camera.K[2]) / camera.fx * z
    y = (uv[:, 1] - camera.K[5]) / camera.fy * z
    return np.stack([x, y, z], axis=1)


@pytest.mark.parametrize("model", sorted(CAMERAS))
def test_projection_and_jacobian_match_opencv(model: str) -> None:
    camera = CAMERAS[model]
    P = _points(camera)
    px, jac = cv2_project(camera, P)
    lens = lens_of(camera)
    mine = np.array([project(lens, *p) for p in P])
    assert np.max(np.abs(mine[:, :2] - px)) < 1e-8
    assert np.allclose(mine[:, 2:].reshape(-1, 2, 3), jac, rtol=1e-7, atol=1e-9)
    # distort() takes normalised coordinates: the same pixels, for arrays as for scalars.
    u, v = distort(lens, P[:, 0] / P[:, 2], P[:, 1] / P[:, 2])
    assert np.max(np.abs(np.stack([u, v], axis=1) - px)) < 1e-8
    assert np.allclose(distort(lens, P[0, 0] / P[0, 2], P[0, 1] / P[0, 2]), px[0], rtol=0.0, atol=1e-8)


def cv2_project(camera: CameraModel, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    zero = np.zeros(3)
    px, jac = cv2.projectPoints(P, zero, zero, camera.matrix, camera.dist)
    return px.reshape(-1, 2), jac[:, 3:6].reshape(-1, 2, 3)
