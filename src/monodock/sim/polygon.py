"""Convex polygons on the normalised image plane, for the compiled renderer (:mod:`monodock.sim.raycast`): area,
Sutherland-Hodgman clipping to a half-plane, an edge as a line, and the separating-axis tests against a tile's box.

A polygon is n vertices in two arrays (x, y), or in two rows of one scratch buffer where it is clipped: a view
passed to a compiled call costs reference counting, and clipping runs several times per edge pixel.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from monodock.core.compiled import inlined, kernel

__all__ = ["box_inside", "clip_half_plane", "edge_line", "overlaps_box", "signed_area"]


@inlined
def signed_area(px: NDArray[np.float64], py: NDArray[np.float64], n: int) -> float:
    """Signed shoelace area (positive counter-clockwise in x right, y down... i.e. by the formula's sign)."""
    a = 0.0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        a += px[i] * py[j] - px[j] * py[i]
    return 0.5 * a


@kernel
def clip_half_plane(buf: NDArray[np.float64], src: int, n: int, a: float, b: float, c: float, dst: int) -> int:
    """One Sutherland-Hodgman step: the convex polygon buf[src] (rows src, src+1: x, y; n vertices) clipped to
    a x + b y + c >= 0 into buf[dst]; returns the clipped polygon's vertex count."""
    m = 0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        fi = a * buf[src, i] + b * buf[src + 1, i] + c
        fj = a * buf[src, j] + b * buf[src + 1, j] + c
        if fi >= 0.0:
            buf[dst, m] = buf[src, i]
            buf[dst + 1, m] = buf[src + 1, i]
            m += 1
        if (fi >= 0.0) != (fj >= 0.0):
            f = fi / (fi - fj)
            buf[dst, m] = buf[src, i] + f * (buf[src, j] - buf[src, i])
            buf[dst + 1, m] = buf[src + 1, i] + f * (buf[src + 1, j] - buf[src + 1, i])
            m += 1
    return m


@inlined
def edge_line(px: NDArray[np.float64], py: NDArray[np.float64], i: int, n: int) -> tuple[float, float, float]:
    """Edge i -> i+1 of a polygon as the line a x + b y + c = 0 whose side a x + b y + c >= 0 is the polygon's
    inside when it is positively oriented (cross(edge, p - p_i) >= 0)."""
    j = i + 1 if i + 1 < n else 0
    a, b = -(py[j] - py[i]), px[j] - px[i]
    return a, b, -(a * px[i] + b * py[i])


@kernel
def overlaps_box(
    px: NDArray[np.float64], py: NDArray[np.float64], n: int, x0: float, x1: float, y0: float, y1: float
) -> bool:
    """Separating-axis test of a convex polygon (n vertices, either winding) against an axis-aligned box."""
    if n < 3:
        return False
    lo_x = hi_x = px[0]
    lo_y = hi_y = py[0]
    for i in range(1, n):
        lo_x = min(lo_x, px[i])
        hi_x = max(hi_x, px[i])
        lo_y = min(lo_y, py[i])
        hi_y = max(hi_y, py[i])
    if hi_x < x0 or lo_x > x1 or hi_y < y0 or lo_y > y1:
        return False
    for i in range(n):
        nx, ny, _ = edge_line(px, py, i, n)  # the edge's normal
        pmin = pmax = nx * px[0] + ny * py[0]
        for m in range(1, n):
            v = nx * px[m] + ny * py[m]
            pmin = min(pmin, v)
            pmax = max(pmax, v)
        b00, b01, b10, b11 = nx * x0 + ny * y0, nx * x0 + ny * y1, nx * x1 + ny * y0, nx * x1 + ny * y1
        if max(b00, b01, b10, b11) < pmin or min(b00, b01, b10, b11) > pmax:
            return False
    return True


@kernel
def box_inside(
    px: NDArray[np.float64], py: NDArray[np.float64], n: int, x0: float, x1: float, y0: float, y1: float
) -> bool:
    """Whether the box lies inside the positively oriented convex polygon (all four corners inside)."""
    if n < 3:
        return False
    for i in range(n):
        a, b, c = edge_line(px, py, i, n)
        if a * x0 + b * y0 + c < 0 or a * x0 + b * y1 + c < 0 or a * x1 + b * y0 + c < 0 or a * x1 + b * y1 + c < 0:
            return False
    return True
