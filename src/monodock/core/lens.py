"""OpenCV's lens model (pinhole + plumb_bob or rational_polynomial distortion) as compiled kernels.

What ``cv2.projectPoints`` computes, but callable per point from inside other kernels: the corner refiner's
profiles and the planar fit's Levenberg–Marquardt loop, where an OpenCV call (and its argument checks) per
evaluation would cost more than the arithmetic. ``tests/core/test_lens.py`` holds both to ``cv2.projectPoints``.
The skew term of K is applied (OpenCV's projectPoints ignores it; calibrated cameras have none).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.compiled import kernel

__all__ = ["distort", "lens_of", "project"]


@functools.lru_cache(maxsize=16)
def lens_of(camera: CameraModel) -> NDArray[np.float64]:
    """The camera as the kernels read it (14,): fx, skew, cx, fy, cy, k1, k2, p1, p2, k3, k4, k5, k6, rational."""
    d = np.zeros(8)
    d[: len(camera.D)] = camera.D
    K = camera.K
    out = np.array([K[0], K[1], K[2], K[4], K[5], *d, 1.0 if len(camera.D) == 8 else 0.0])
    out.flags.writeable = False
    return out


@kernel
def distort(lens: NDArray[np.float64], x: Any, y: Any) -> tuple[Any, Any]:  # pragma: no cover - compiled
    """Pixels (u, v) of undistorted normalised coordinates (x, y): scalars or arrays alike."""
    k1, k2, p1, p2, k3 = lens[5], lens[6], lens[7], lens[8], lens[9]
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    if lens[13] != 0.0:
        radial = radial / (1.0 + r2 * (lens[10] + r2 * (lens[11] + r2 * lens[12])))
    xd = x * radial + (2.0 * p1) * xy + p2 * (r2 + 2.0 * xx)
    yd = y * radial + p1 * (r2 + 2.0 * yy) + (2.0 * p2) * xy
    return lens[0] * xd + lens[1] * yd + lens[2], lens[3] * yd + lens[4]


@kernel
def project(lens: NDArray[np.float64], X: float, Y: float, Z: float) -> tuple[float, ...]:  # pragma: no cover
    """The pixel (u, v) of a point (X, Y, Z) in the optical frame, Z > 0, and its Jacobian d(u, v)/d(X, Y, Z).

    Returns u, v, du/dX, du/dY, du/dZ, dv/dX, dv/dY, dv/dZ.
    """
    k1, k2, p1, p2, k3 = lens[5], lens[6], lens[7], lens[8], lens[9]
    iz = 1.0 / Z
    x, y = X * iz, Y * iz
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    if lens[13] != 0.0:
        k4, k5, k6 = lens[10], lens[11], lens[12]
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dden = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
        radial = num / den
        dradial = (dnum * den - num * dden) / (den * den)  # d radial / d r2
    else:
        radial, dradial = num, dnum
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx)
    yd = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy
    # d(xd, yd)/d(x, y)
    a = radial + 2.0 * xx * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * xy * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    d = radial + 2.0 * yy * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    fx, skew, fy = lens[0], lens[1], lens[3]
    # d(u, v)/d(x, y): u = fx xd + skew yd + cx, v = fy yd + cy; the symmetric b is both cross terms.
    ux, uy = fx * a + skew * b, fx * b + skew * d
    vx, vy = fy * b, fy * d
    # d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]
    return (
        fx * xd + skew * yd + lens[2],
        fy * yd + lens[4],
        ux * iz,
        uy * iz,
        -(ux * x + uy * y) * iz,
        vx * iz,
        vy * iz,
        -(vx * x + vy * y) * iz,
    )
