"""Bias-free sub-pixel corners of the dock markers, from their four straight outer edges.

OpenCV's ArUco corners sit ~0.2-0.35 px *inside* the true corners (``bench/corner_accuracy.py``), which
biases PnP depth by 1-3 % at range. This refiner measures the marker's outer edge (white charger face to
black border) instead of the corner itself:

1. along each of the 4 sides, ``PROFILES`` short intensity profiles across the side (one ``cv2.remap`` for
   every profile of every marker), away from the corners, where the two edges of a corner mix;
2. in each profile, the edge position by a blurred-step fit (free bright and dark levels, position and
   blur width): a few vectorised Gauss-Newton steps on all profiles at once;
3. the edge points through the lens to undistorted normalised coordinates, where the sides are straight;
4. one line per side by robustly reweighted total least squares (occluders, clutter, glints drop out);
5. the corners as the intersections of adjacent lines, mapped back through the lens to pixels;
6. on a marker whose profiles hold clipped pixels (255 or 0), the clipping's shift of its edges, measured on
   the border's inner edge, and the lines moved back by it before step 5 (``_bloom``).

Clipping: an over-exposed white face reads 255 (noise may even pull a clipped pixel below 255, when the
sensor saturates before the read-out), so the blurred step is cut off near its top and every fitted edge
sits too far towards the black, by an amount that depends on the unknown level above full scale and on the
exact blur. No fit of a single profile can undo that: with one or two unclipped pixels on the slope it would
rest on the tails of an assumed blur. The black border's inner edge, where it meets a white code cell, is
the same edge mirrored (white to black, outward): the same fit moves it towards the black by the same
amount, outward, so the border looks 2 delta too thin. The marker's own geometry (its corners through a
homography, the inner edge one module in) says where that edge is, whatever the blur: the difference gives
delta. Under-exposure (a black level clipped at 0) is the same with the signs swapped.

The profiles reach only a fraction of the border width inwards, so that they do not see the code pattern
behind the border. A marker with a side that has too few good profiles (cut by the image border, hidden
behind something) keeps OpenCV's corners, and ``refine_detection`` lists its role in
``Detection.unrefined``.

Everything runs on arrays of all the profiles of all the markers at once, in a fixed small number of numpy
calls: a frame with three markers costs a small fraction of the marker detection itself (about 1.5 times
as much when its markers are clipped: the inner profiles join the same fit).

The correction assumes that the white right outside the border (the marker's quiet zone) and the code's
white cells are the same white, and it would read printer ink spread (a wider black border) as negative
clipping shift: it runs only on clipped markers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.camera import CameraModel
from monodock.detect import Detection
from monodock.errors import InputError

__all__ = ["refine_detection", "refine_marker"]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

PROFILES = 16  # profiles per side
SAMPLES = 14  # samples per profile
REACH = 0.6  # a profile reaches this fraction of the border width either side of the detected edge
MIN_REACH_PX = 1.6
MAX_REACH_PX = 4.5
CORNER_SKIP_PX = 1.5  # profiles keep this far from a corner, where the two edges of the corner mix ...
CORNER_BLUR = 2.5  # ... and this many blur sigmas
MAX_STEPS = 3  # Gauss-Newton steps of the edge fit; one is enough from the start below unless the blur is wide
CONVERGED_PX = 0.02  # ... that is, unless the first step still moves the typical edge further than this
MIN_GOOD = 5  # a side needs this many good profiles, else the marker keeps OpenCV's corners
MAX_SHIFT = 0.5  # a refined corner further than this fraction of the border width from OpenCV's is rejected
MIN_CLIPPED = 4  # a marker with this many clipped samples (255 or 0) gets its clipping shift measured ...
MIN_INNER = 3  # ... on at least this many white cells along its border, else it takes the frame's median shift

# Sample offsets across the edge in [-1, 1] of the reach, denser near the middle where the edge lies.
_U = np.linspace(-1.0, 1.0, SAMPLES)
_GRID = (_U * (0.55 + 0.45 * _U * _U)).astype(np.float32)
_ALONG = (np.arange(PROFILES) + 0.5) / PROFILES
_PROBE = np.array([0.0, 1.0])[:, None, None]
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)
# Logistic approximation of the standard normal CDF (error < 1.4e-4): Phi(z) ~ 1 / (1 + exp(-(C1 z + C3 z^3))).
_C1 = np.float32(1.5976)
_C3X3 = np.float32(3 * 0.070566)
_C1N, _C3N = -_C1, np.float32(-0.070566)


def refine_marker(
    gray: NDArray[np.uint8],
    corners: NDArray[np.float64],
    camera: CameraModel,
    *,
    modules: int = 6,
) -> NDArray[np.float64] | None:
    """One marker's refined corners (4, 2), ArUco order, or None when they cannot be refined.

    Args:
        gray: the image, 8-bit single channel (``monodock.detect.as_gray``).
        corners: the detected corners (4, 2), pixels, ArUco order TL, TR, BR, BL.
        camera: the camera that took the image (its lens model straightens the sides).
        modules: the marker's width in modules, border included (bits + 2: 6 for a 4x4 dictionary).
    """
    img = _check_image(gray, camera, modules)
    c = np.asarray(corners, dtype=np.float64)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        raise InputError(f"marker corners must be 4 finite (x, y) pixels, got an array of shape {c.shape}")
    out, ok = _refine(img, c, camera, modules)
    return out[0] if ok[0] else None


def refine_detection(
    gray: NDArray[np.uint8],
    detection: Detection,
    camera: CameraModel,
    *,
    modules: int = 6,
) -> Detection:
    """The detection with its markers' corners refined; the roles that could not be are in ``unrefined``.

    All the markers are refined together (one image sampling, one fit), which costs little more than one.
    """
    img = _check_image(gray, camera, modules)
    roles = [r for r, o in detection.observations.items() if np.shape(o.corners) == (4, 2)]
    roles = [r for r in roles if np.all(np.isfinite(detection.observations[r].corners))]
    if not roles:
        return replace(detection, unrefined=tuple(detection.observations))
    stack = np.concatenate([np.asarray(detection.observations[r].corners, dtype=np.float64) for r in roles])
    out, ok = _refine(img, stack, camera, modules)
    observations = dict(detection.observations)
    refined = set()
    for i, role in enumerate(roles):
        if ok[i]:
            observations[role] = replace(observations[role], corners=out[i])
            refined.add(role)
    unrefined = tuple(r for r in detection.observations if r not in refined)
    return replace(detection, observations=observations, unrefined=unrefined)


def _check_image(gray: NDArray[np.uint8], camera: CameraModel, modules: int) -> NDArray[np.uint8]:
    if not isinstance(gray, np.ndarray) or gray.dtype != np.uint8 or gray.ndim != 2:
        shape = getattr(gray, "shape", None)
        dtype = getattr(gray, "dtype", type(gray).__name__)
        raise InputError(f"refine needs an 8-bit single-channel image (as_gray), got {dtype} of shape {shape}")
    if (gray.shape[1], gray.shape[0]) != camera.size:
        raise InputError(
            f"image is {gray.shape[1]}x{gray.shape[0]} but camera '{camera.name}' is {camera.width}x{camera.height}"
        )
    if modules < 3:
        raise InputError(f"a marker is at least 3 modules wide (bits + 2), got {modules}")
    return gray


def _distort(camera: CameraModel, x: F64, y: F64) -> tuple[F64, F64]:
    """Pixels (u, v) of undistorted normalised coordinates, through the lens (OpenCV's plumb_bob / rational)."""
    d = camera.D
    k1, k2, p1, p2, k3 = d[:5]
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    if len(d) == 8:
        radial = radial / (1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7])))
    xd = x * radial + (2.0 * p1) * xy + p2 * (r2 + 2.0 * xx)
    yd = y * radial + p1 * (r2 + 2.0 * yy) + (2.0 * p2) * xy
    K = camera.K
    return K[0] * xd + K[1] * yd + K[2], K[4] * yd + K[5]


def _refine(gray: NDArray[np.uint8], corners: F64, camera: CameraModel, modules: int) -> tuple[F64, NDArray[np.bool_]]:
    """Refined corners (M, 4, 2) of M markers' detected corners (4M, 2), and which markers were refined.

    Arrays are laid out (profile j, side) or (sample, profile j, side), side = 4 * marker + k, where side k
    runs from corner k to corner k + 1, so that every sum runs over the first axis. Each side has its own
    frame in normalised coordinates: ``along`` from its middle towards corner k + 1, ``across`` inwards.
    """
    n_sides = corners.shape[0]
    m = n_sides // 4
    height, width = gray.shape
    idx = np.arange(n_sides)
    nxt = idx - idx % 4 + (idx + 1) % 4
    prv = idx - idx % 4 + (idx + 3) % 4

    # --- the profiles: anchors evenly along each side, straight in normalised coordinates ---------------
    # Only where the anchors go depends on these, not where the edges are found: 20 iterations are plenty.
    xn = np.asarray(
        cv2.undistortPoints(corners[:, None, :], camera.matrix, camera.dist, criteria=_UNDISTORT), np.float64
    )
    xn = xn.reshape(-1, 2)
    cx, cy = corners[:, 0], corners[:, 1]
    side_px = np.hypot(cx[nxt] - cx, cy[nxt] - cy)
    border = (side_px[prv] + side_px[nxt]) / (2.0 * modules)  # the border's width across side k
    reach = np.minimum(np.maximum(REACH * border, MIN_REACH_PX), MAX_REACH_PX)
    skip = np.minimum(CORNER_SKIP_PX / np.maximum(side_px, 1e-9), 0.25)
    frac = skip + (1.0 - 2.0 * skip) * _ALONG[:, None]  # (J, S), 0 at corner k, 1 at corner k + 1
    ux, uy = xn[nxt, 0] - xn[:, 0], xn[nxt, 1] - xn[:, 1]
    ulen = np.hypot(ux, uy)
    # The inward unit normal: ArUco corners run clockwise on screen (a positive shoelace sum in pixels).
    clockwise = (cx * cy[nxt] - cx[nxt] * cy).reshape(m, 4).sum(axis=1) >= 0
    g = np.where(clockwise, 1.0, -1.0)[idx // 4] / ulen
    nnx, nny = -uy * g, ux * g
    along = (frac - 0.5) * ulen
    ax, ay = xn[:, 0] + frac * ux, xn[:, 1] + frac * uy
    # The anchors' pixels and, one pixel-ish further inwards, the pixel direction of the inward normal.
    step = 1.0 / camera.fx
    pu, pv = _distort(camera, ax + _PROBE * (step * nnx), ay + _PROBE * (step * nny))
    px, py = pu[0], pv[0]
    dpx, dpy = pu[1] - px, pv[1] - py
    inv = 1.0 / np.hypot(dpx, dpy)
    nx, ny = (dpx * inv).astype(np.float32), (dpy * inv).astype(np.float32)
    kappa = step * inv  # normalised distance across the side per pixel along the profile

    # --- sample every profile of every marker with one remap -------------------------------------------
    t = (reach * _GRID[:, None]).astype(np.float32)[:, None, :]  # (T, 1, S) pixels, positive inwards
    mapx = (px.astype(np.float32) + t * nx).reshape(SAMPLES, -1)
    mapy = (py.astype(np.float32) + t * ny).reshape(SAMPLES, -1)
    lo_x, hi_x = np.minimum(mapx[0], mapx[-1]), np.maximum(mapx[0], mapx[-1])
    lo_y, hi_y = np.minimum(mapy[0], mapy[-1]), np.maximum(mapy[0], mapy[-1])
    inside = ((lo_x >= 0) & (hi_x <= width - 1) & (lo_y >= 0) & (hi_y <= height - 1)).reshape(PROFILES, n_sides)
    prof = np.asarray(cv2.remap(gray, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), np.uint8)
    prof = prof.reshape(SAMPLES, PROFILES, n_sides)
    # Samples off the image are not data. Clipped samples are: dropping them leaves a fit of the slope alone,
    # wild where only a pixel or two of it is below 255; kept, the clipped plateau is the bright level, and
    # the edge's shift that comes with it is the same on the mirrored inner edge, which measures it (_bloom).
    w = np.empty(prof.shape, np.float32)
    w[...] = inside
    args = (t, prof.astype(np.float32), w, reach.astype(np.float32))
    inner = None
    if prof.max() == 255 or prof.min() == 0:
        inner = _inner_profiles(gray, camera, xn, clockwise, modules, reach, prof, inside)
        if inner is not None:
            args = _with_inner(args, inner)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        e, s, contrast, rms = _fit_edges(*args)
    if inner is not None:
        fit = np.stack([e, s, contrast, rms])
        inner_fit = fit[:, :, n_sides:].reshape(4, -1)[:, : inner.mk.size]
        e, s, contrast, rms = fit[:, :, :n_sides]

    # --- which profiles saw a clean edge -------------------------------------------------------------------
    good = inside & (np.abs(e) < 0.8 * reach) & (s < reach) & (rms < 0.15 * contrast)
    gf = good.astype(np.float64)
    n_side = np.add.reduce(gf, 0) + 1e-9
    # Much less contrast than the side's average: a shadow or an occluder across the profile.
    good &= contrast > 0.5 * np.add.reduce(np.where(good, contrast, 0.0), 0) / n_side
    # Blur rounds a corner off over a few sigmas: drop the profiles that close to a corner.
    blur = np.add.reduce(np.where(good, s, 0.0), 0) / n_side
    good &= np.minimum(frac, 1.0 - frac) * side_px > np.maximum(CORNER_SKIP_PX, CORNER_BLUR * blur)

    # --- a line per side through the edge points, then corner k where side k-1 meets side k ------------
    # A side without good profiles gives a degenerate line: its NaN or infinite corners fail the checks below.
    with np.errstate(all="ignore"):
        across = np.where(good, e, 0.0) * kappa  # a failed fit may be NaN: it must not reach the sums, even weightless
        alpha, beta, n_good = _robust_lines(along, across, good, 0.03 / camera.fx)
        # Side k: X(a) = middle + a (u / |u|) + (alpha + beta a) n, as a line  lx X + ly Y = lc.
        dx, dy = ux / ulen + beta * nnx, uy / ulen + beta * nny
        lx, ly = -dy, dx
        px_, py_ = lx[prv], ly[prv]
        den = px_ * ly - lx * py_

        def intersect(alpha: F64) -> tuple[F64, F64]:
            lc = lx * (xn[:, 0] + 0.5 * ux + alpha * nnx) + ly * (xn[:, 1] + 0.5 * uy + alpha * nny)
            pc = lc[prv]
            return (pc * ly - lc * py_) / den, (px_ * lc - lx * pc) / den

        qx, qy = intersect(alpha)
        if inner is not None:
            contrast_out = np.add.reduce(np.where(good, contrast, 0.0), 0).reshape(m, 4).sum(axis=1)
            contrast_out /= np.maximum(good.reshape(PROFILES, m, 4).sum(axis=(0, 2)), 1)
            delta = _bloom(inner, inner_fit, contrast_out, qx.reshape(m, 4), qy.reshape(m, 4), modules)
            qx, qy = intersect(alpha - delta[idx // 4] * (np.add.reduce(kappa, 0) / PROFILES))
        ou, ov = _distort(camera, qx, qy)
        shift = np.hypot(ou - cx, ov - cy)
        limit = np.maximum(MAX_SHIFT * border.reshape(m, 4).min(axis=1), 1.5)[idx // 4]
    ok = np.all(((n_good >= MIN_GOOD) & (shift < limit)).reshape(m, 4), axis=1)  # NaN fails too
    out = np.stack([ou, ov], axis=1).reshape(m, 4, 2)
    return np.where(ok[:, None, None], out, corners.reshape(m, 4, 2)), ok


@lru_cache(maxsize=4)
def _border_cells(modules: int) -> tuple[F64, F64, NDArray[np.intp]]:
    """The code cells along the border's inner edge, side by side, in marker grid units ([0, 1]^2, TL at 0).

    Returns the middle of each cell's edge on the border's inner line and that line's direction (from corner
    k towards corner k + 1), each (4 (modules - 2), 2), and each cell's side k.
    """
    s = (np.arange(modules - 2) + 1.5) / modules
    one, inner = np.full_like(s, 1.0 / modules), np.full_like(s, 1.0 - 1.0 / modules)
    edge = np.concatenate([np.stack(p, axis=1) for p in ((s, one), (inner, s), (1.0 - s, inner), (one, 1.0 - s))])
    unit = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    side = np.repeat(np.arange(4), modules - 2)
    return edge, unit[side], side


def _square_to_quad(x: F64, y: F64) -> F64:
    """The homographies (8, M) from the unit square onto quads x, y (M, 4), closed form (Heckbert).

    Corners in ArUco order: TL, TR, BR, BL at (0, 0), (1, 0), (1, 1), (0, 1). ``_on_quad`` applies them.
    """
    x0, x1, x2, x3 = x.T
    y0, y1, y2, y3 = y.T
    sx, sy = x0 - x1 + x2 - x3, y0 - y1 + y2 - y3
    dx1, dx2, dy1, dy2 = x1 - x2, x3 - x2, y1 - y2, y3 - y2
    den = dx1 * dy2 - dx2 * dy1
    g, h = (sx * dy2 - dx2 * sy) / den, (dx1 * sy - sx * dy1) / den
    return np.stack([x1 - x0 + g * x1, x3 - x0 + h * x3, x0, y1 - y0 + g * y1, y3 - y0 + h * y3, y0, g, h])


def _on_quad(hom: F64, u: F64, v: F64) -> tuple[F64, F64]:
    """Points (u, v) of the unit square through homographies ``hom`` (8, ...) that broadcast with them."""
    a, b, c, d, e, f, g, h = hom
    w = g * u + h * v + 1.0
    return (a * u + b * v + c) / w, (d * u + e * v + f) / w


@dataclass(frozen=True)
class _Inner:
    """Profiles across the border's inner edge of clipped markers, one per code cell along the border.

    Each runs outward from the middle of the cell's edge, where the detected corners put it: across a white
    cell, the mirror of an outer profile (white to black); across a black cell, nothing (the fit's contrast
    drops it). ``mk`` (N,) marker, ``cell`` (N,) index into ``_border_cells``, ``x``, ``y``, ``nx``, ``ny``
    (N,) anchor and outward unit normal (normalised coordinates), ``kappa`` (N,) normalised distance per
    pixel along the profile, ``lim`` (N,) reach; ``t``, ``prof``, ``w`` (T, N).
    """

    mk: NDArray[np.intp]
    cell: NDArray[np.intp]
    clipped: NDArray[np.bool_]
    x: F64
    y: F64
    nx: F64
    ny: F64
    kappa: F64
    lim: F32
    t: F32
    prof: NDArray[np.uint8]
    w: NDArray[np.bool_]


def _inner_profiles(
    gray: NDArray[np.uint8],
    camera: CameraModel,
    xn: F64,
    clockwise: NDArray[np.bool_],
    modules: int,
    reach: F64,
    prof: NDArray[np.uint8],
    inside: NDArray[np.bool_],
) -> _Inner | None:
    """The profiles across the border's inner edge of the markers with ``MIN_CLIPPED`` clipped samples, or None.

    ``xn`` (4M, 2) are the detected corners (normalised), ``clockwise`` (M,) whether they run clockwise on
    screen, ``reach`` (4M,) the sides' profile reach, ``prof`` (T, J, 4M) and ``inside`` (J, 4M) the outer
    profiles. Built like the outer ones: a straight normal in normalised coordinates, its direction in pixels
    one pixel-ish out, the outer side's reach.
    """
    height, width = gray.shape
    m = xn.shape[0] // 4
    n_clipped = np.add.reduce((prof == 255) | (prof == 0), (0, 1), where=inside)
    clipped = n_clipped.reshape(m, 4).sum(axis=1) >= MIN_CLIPPED
    if not np.any(clipped):
        return None
    edge, direction, side = _border_cells(modules)
    mk = np.repeat(np.flatnonzero(clipped), side.size)
    cell = np.tile(np.arange(side.size), mk.size // side.size)
    # The edge middles and a short step along the edge, through the detected corners' homographies.
    g = edge[cell] + np.array([0.0, 1e-3])[:, None, None] * direction[cell]
    hom = _square_to_quad(xn[:, 0].reshape(m, 4), xn[:, 1].reshape(m, 4))[:, mk]
    x, y = _on_quad(hom, g[..., 0], g[..., 1])
    dx, dy = x[1] - x[0], y[1] - y[0]
    # The outward normal, on the outer sides' outer side (see _refine).
    scale = np.where(clockwise[mk], -1.0, 1.0) / np.hypot(dx, dy)
    nx, ny = -dy * scale, dx * scale
    step = 1.0 / camera.fx
    pu, pv = _distort(camera, x[0] + _PROBE * (step * nx), y[0] + _PROBE * (step * ny))
    dpx, dpy = pu[1] - pu[0], pv[1] - pv[0]
    inv = 1.0 / np.hypot(dpx, dpy)
    lim = reach.reshape(m, 4)[mk, side[cell]].astype(np.float32)
    t = lim * _GRID[:, None]  # (T, N), pixels, positive outward
    mapx, mapy = (pu[0] + t * (dpx * inv)).astype(np.float32), (pv[0] + t * (dpy * inv)).astype(np.float32)
    ok = (
        (np.minimum(mapx[0], mapx[-1]) >= 0)
        & (np.maximum(mapx[0], mapx[-1]) <= width - 1)
        & (np.minimum(mapy[0], mapy[-1]) >= 0)
        & (np.maximum(mapy[0], mapy[-1]) <= height - 1)
    )
    inner_prof = np.asarray(cv2.remap(gray, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), np.uint8)
    w = np.broadcast_to(ok, t.shape)
    return _Inner(mk, cell, clipped, x[0], y[0], nx, ny, step * inv, lim, t, inner_prof, w)


def _with_inner(args: tuple[F32, F32, F32, F32], inner: _Inner) -> tuple[F32, F32, F32, F32]:
    """The outer profiles' fit arguments with the inner profiles as extra columns of PROFILES profiles each."""
    t, intensity, w, lim = args
    n_sides, n = intensity.shape[2], inner.mk.size
    cols = -(-n // PROFILES)
    out = [np.zeros((SAMPLES, PROFILES, n_sides + cols), np.float32) for _ in range(3)]
    lim_out = np.ones((PROFILES, n_sides + cols), np.float32)
    lim_out[:, :n_sides] = lim
    flat = np.zeros((SAMPLES, PROFILES * cols), np.float32)
    extras = (inner.t, inner.prof.astype(np.float32), inner.w.astype(np.float32))
    for dst, outer, extra in zip(out, (t, intensity, w), extras, strict=True):
        dst[:, :, :n_sides] = outer
        flat[:, :n] = extra
        dst[:, :, n_sides:] = flat.reshape(SAMPLES, PROFILES, cols)
    flat[0, :n] = inner.lim
    lim_out[:, n_sides:] = flat[0].reshape(PROFILES, cols)
    return out[0], out[1], out[2], lim_out


def _bloom(inner: _Inner, fit: F32, contrast_out: F64, qx: F64, qy: F64, modules: int) -> F64:
    """Per marker (M,): how far clipping put its fitted outer edges inside the true ones, px (0: not clipped).

    ``fit`` (4, N) holds the inner profiles' edge, blur, contrast and RMS, ``contrast_out`` (M,) the
    markers' mean contrast on their outer edges, ``qx``, ``qy`` (M, 4) the corners from the fitted outer
    edges (normalised). If those edges sit delta inside, the corners put the inner edge 2 delta / modules
    too far in and the fit finds it delta too far out, so that it appears e = 2 delta (1 - 1 / modules)
    outward of where the corners put it, whatever the blur. A clipped marker with fewer than ``MIN_INNER``
    white cells measured takes the median of the others, or 0.
    """
    e, s, contrast, rms = fit
    good = inner.w[0] & (np.abs(e) < 0.8 * inner.lim) & (s < inner.lim) & (rms < 0.15 * contrast)
    good &= contrast > 0.5 * contrast_out[inner.mk]  # a black cell, or a shadow: no edge
    edge, _, _ = _border_cells(modules)
    g = edge[inner.cell]
    x, y = _on_quad(_square_to_quad(qx, qy)[:, inner.mk], g[:, 0], g[:, 1])
    # Each white cell's edge, outward of where the refined corners put it (px); a row per marker, NaN-padded.
    m = qx.shape[0]
    found = np.full((m, edge.shape[0]), np.nan)
    offset = ((inner.x - x) * inner.nx + (inner.y - y) * inner.ny) / inner.kappa
    found[inner.mk, inner.cell] = np.where(good, e + offset, np.nan)
    # A mean (the spread is mostly noise), without the cells more than 3 robust sigmas off the median.
    rows = np.arange(m)
    count = np.bincount(inner.mk, weights=good, minlength=m).astype(np.intp)
    half = np.minimum(count // 2, found.shape[1] - 1)
    off = np.abs(found - np.sort(found, axis=1)[rows, half, None])
    spread = np.maximum(3.0 * 1.4826 * np.sort(off, axis=1)[rows, half], 0.1)
    keep = off <= spread[:, None]  # NaN is not
    with np.errstate(invalid="ignore", divide="ignore"):
        delta = np.add.reduce(np.where(keep, found, 0.0), 1) / keep.sum(axis=1) / (2.0 * (1.0 - 1.0 / modules))
    measured = inner.clipped & (count >= MIN_INNER)
    if not np.any(measured):
        return np.zeros(m)
    delta[inner.clipped & ~measured] = np.sort(delta[measured])[np.count_nonzero(measured) // 2]
    return np.where(inner.clipped, delta, 0.0)


def _fit_edges(t: F32, intensity: F32, w: F32, lim: F32) -> tuple[F32, F32, F32, F32]:
    """Fit I(t) = B + (D - B) Phi((t - e) / s) to every profile: edge e, blur sigma s, contrast B - D, RMS.

    ``t`` (samples, 1 or profiles, sides), ``intensity`` and weights ``w`` (samples, profiles, sides), ``lim``
    (sides,) or (profiles, sides); the results are (profiles, sides). Variable projection: the levels B, D are the
    weighted linear least-squares solution for the current e and s, and each Gauss-Newton step on (e, s)
    uses the Jacobian projected off the levels (Kaufman), so it converges like a full four-parameter fit.
    Starts from the centroid and spread of the intensity drop; e stays within +-lim.
    """
    # Materialised: broadcasting (T, 1, S) against (J, S) runs numpy's inner loops over S only, ~2x slower.
    t = np.ascontiguousarray(np.broadcast_to(t, intensity.shape))
    wi = w * intensity
    n = np.add.reduce(w, 0) + np.float32(1e-6)
    y1 = np.add.reduce(wi, 0)
    yy = np.add.reduce(wi * intensity, 0)
    # Start: centroid and spread of the (positive) intensity drop going inwards.
    mom = np.empty((3, *np.shape(intensity[1:])), np.float32)
    np.multiply(np.maximum(intensity[:-1] - intensity[1:], 0.0), w[:-1] * w[1:], out=mom[0])
    tm = 0.5 * (t[:-1] + t[1:])
    np.multiply(mom[0], tm, out=mom[1])
    np.multiply(mom[1], tm, out=mom[2])
    mass, m1, m2 = np.add.reduce(mom, 1)
    mass += np.float32(1e-6)
    e = m1 / mass
    s = np.minimum(np.maximum(np.sqrt(np.maximum(m2 / mass - e * e, 0.0)), np.float32(0.3)), lim)
    # e and s stacked, so that the step below updates and clamps both at once.
    es = np.stack([e, s])
    lim = np.broadcast_to(lim, e.shape)
    lo = np.stack([-lim, np.full_like(lim, 0.2)])
    hi = np.stack([lim, lim])
    buf = np.empty((12, *np.shape(intensity)), np.float32)
    a = b = y2 = e
    for step in range(MAX_STEPS):
        e, s = es
        z = (t - e) / s
        z2 = z * z
        ex = np.exp(z * (_C1N + _C3N * z2))
        cdf = 1.0 / (1.0 + ex)
        pdf = cdf * (1.0 - cdf) * (_C1 + _C3X3 * z2)  # not ex cdf^2: ex may overflow to inf
        wc = np.multiply(w, cdf, out=buf[0])
        np.multiply(wc, cdf, out=buf[1])
        np.multiply(wc, intensity, out=buf[2])
        wd = np.multiply(w, pdf, out=buf[3])
        wdz = np.multiply(wd, z, out=buf[4])
        np.multiply(wd, cdf, out=buf[5])
        np.multiply(wdz, cdf, out=buf[6])
        np.multiply(wd, intensity, out=buf[7])
        np.multiply(wdz, intensity, out=buf[8])
        np.multiply(wd, pdf, out=buf[9])
        np.multiply(wdz, pdf, out=buf[11])
        np.multiply(buf[11], z, out=buf[10])
        sums = np.add.reduce(buf, 1)
        s1, s2, y2 = sums[0], sums[1], sums[2]
        cc, dd = sums[3:5], sums[5:7]  # [pdf, pdf z] against the basis [1, Phi]
        # Levels: B = b, D - B = a (the basis is [1, Phi], its Gram matrix [[n, s1], [s1, s2]]).
        ig = 1.0 / (n * s2 - s1 * s1)
        a = (n * y2 - s1 * y1) * ig
        b = (y1 - a * s1) / n
        # Gradient against [pdf, pdf z] of the residual I - b - a Phi, and their normal matrix projected off
        # the basis (Kaufman): A - C^T G^-1 C, with C the basis-derivative cross sums.
        grad = sums[7:9] - b * cc - a * dd
        p0 = (s2 * cc - s1 * dd) * ig
        p1 = (n * dd - s1 * cc) * ig
        diag = sums[9:11] * np.float32(1.001) - (cc * p0 + dd * p1)
        off = sums[11] - (cc[0] * p0[1] + dd[0] * p1[1])
        # The model's derivatives are -(a/s) [pdf, pdf z]: the step on (e, s) scales back by -s/a.
        k = s / (a * (diag[0] * diag[1] - off * off))
        move = k * (diag[::-1] * grad - off * grad[::-1])
        es = np.minimum(np.maximum(es - move, lo), hi)
        if step == 0 and abs(float(np.median(move[0]))) < CONVERGED_PX:
            break  # the typical edge moved less than CONVERGED_PX: the start was close
    e, s = es
    # At the least-squares levels the residual is orthogonal to them: sum r^2 = sum r I.
    rms = np.sqrt(np.maximum(yy - b * y1 - a * y2, 0.0) / n)
    return e, s, -a, rms


def _robust_lines(
    along: F64, across: F64, good: NDArray[np.bool_], floor: float, steps: int = 2
) -> tuple[F64, F64, NDArray[np.intp]]:
    """Lines across = alpha + beta along through each side's points (J, S), Tukey-reweighted least squares.

    The points lie within a fraction of a pixel of the side's own frame, so least squares in it is total
    least squares. Points further than 4.7 robust sigmas (median absolute residual, at least ``floor``) from
    a line get no weight. Returns alpha, beta per side and the number of points that kept a weight over 1/2.
    """
    n_pts, n_sides = along.shape
    weight = good.astype(np.float64)
    cols = np.arange(n_sides)
    mid = np.minimum(np.add.reduce(weight, 0).astype(np.intp) // 2, n_pts - 1)
    sq = along * along
    mom = np.empty((5, n_pts, n_sides))
    wt = weight
    for it in range(steps + 1):
        mom[0] = wt
        np.multiply(wt, along, out=mom[1])
        np.multiply(wt, sq, out=mom[2])
        np.multiply(wt, across, out=mom[3])
        np.multiply(mom[1], across, out=mom[4])
        sw, sa, saa, sc, sac = np.add.reduce(mom, 1)
        det = sw * saa - sa * sa + 1e-300
        alpha = (saa * sc - sa * sac) / det
        beta = (sw * sac - sa * sc) / det
        if it == steps:
            break
        res = across - alpha - beta * along
        absr = np.abs(res)
        absr[~good] = np.inf
        sigma = np.maximum(1.4826 * np.sort(absr, axis=0)[mid, cols], floor)
        u = res / (4.685 * sigma)
        wt = weight * np.square(np.maximum(1.0 - u * u, 0.0))
    return alpha, beta, np.add.reduce(wt > 0.5, 0)
