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

All the profiles of all the markers are sampled (bilinear, as ``cv2.remap``) and fitted in one call of a compiled
kernel (``monodock.core.compiled``), the clipped markers' inner profiles and ``_bloom`` included: a frame with
three markers costs about a twentieth of the marker detection in a loop and a tenth right after it
(``bench/speed.py``), a frame with clipped markers a few times that.

The correction assumes that the white right outside the border (the marker's quiet zone) and the code's
white cells are the same white, and it would read printer ink spread (a wider black border) as negative
clipping shift: it runs only on clipped markers.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.compiled import inlined, kernel
from monodock.core.lens import distort, lens_of
from monodock.errors import InputError
from monodock.perception.checks import check_gray
from monodock.perception.detect import Detection, MarkerObservation

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
CONVERGED_PX = 0.02  # ... that is, unless a step still moves the typical edge further than this
MIN_GOOD = 5  # a side needs this many good profiles, else the marker keeps OpenCV's corners
MAX_SHIFT = 0.5  # a refined corner further than this fraction of the border width from OpenCV's is rejected
MIN_CLIPPED = 4  # a marker with this many clipped samples (255 or 0) gets its clipping shift measured ...
MIN_INNER = 3  # ... on at least this many white cells along its border, else it takes the frame's median shift

# Sample offsets across the edge in [-1, 1] of the reach, denser near the middle where the edge lies.
_U = np.linspace(-1.0, 1.0, SAMPLES)
_GRID = (_U * (0.55 + 0.45 * _U * _U)).astype(np.float32)
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
        gray: the image, 8-bit single channel (``monodock.perception.detect.as_gray``).
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
    quads = {r: o.corners for r, o in detection.observations.items() if np.shape(o.corners) == (4, 2)}
    if not quads:
        return replace(detection, unrefined=tuple(detection.observations))
    stack = np.concatenate(list(quads.values()), dtype=np.float64)
    roles = list(quads)
    if not np.isfinite(stack).all():  # rare: only the markers with finite corners are refined
        finite = np.asarray(np.isfinite(stack).reshape(-1, 8).all(axis=1))
        roles = [r for r, f in zip(quads, finite.tolist(), strict=True) if f]
        if not roles:
            return replace(detection, unrefined=tuple(detection.observations))
        stack = stack[np.repeat(finite, 4)]
    out, ok = _refine(img, stack, camera, modules)
    observations = dict(detection.observations)
    refined = set()
    for i, role in enumerate(roles):
        if ok[i]:
            o = observations[role]
            # Not dataclasses.replace: this runs per marker and frame, and replace costs several microseconds.
            observations[role] = MarkerObservation(o.role, o.marker_id, out[i])
            refined.add(role)
    unrefined = tuple(r for r in detection.observations if r not in refined)
    return replace(detection, observations=observations, unrefined=unrefined)


def _check_image(gray: NDArray[np.uint8], camera: CameraModel, modules: int) -> NDArray[np.uint8]:
    check_gray(gray, "refine", camera)
    if modules < 3:
        raise InputError(f"a marker is at least 3 modules wide (bits + 2), got {modules}")
    return gray


def _refine(gray: NDArray[np.uint8], corners: F64, camera: CameraModel, modules: int) -> tuple[F64, NDArray[np.bool_]]:
    """Refined corners (M, 4, 2) of M markers' detected corners (4M, 2), and which markers were refined.

    Arrays are laid out (profile j, side) or (sample, profile j, side), side = 4 * marker + k, where side k
    runs from corner k to corner k + 1. Each side has its own frame in normalised coordinates: ``along``
    from its middle towards corner k + 1, ``across`` inwards. All of it, the clipped markers' correction
    included, is one call of a compiled kernel.
    """
    edge, direction, cell_side = _border_cells(modules)
    lens = lens_of(camera)
    return _refine_frame(gray, corners, lens, modules, 0.03 / lens[0], edge, direction, cell_side)


@kernel
def _refine_frame(
    gray: NDArray[np.uint8], corners: F64, lens: F64, modules: int, floor: float, edge: F64, direction: F64,
    cell_side: NDArray[np.intp],
) -> tuple[F64, NDArray[np.bool_]]:  # pragma: no cover - compiled  # fmt: skip
    """``_refine`` in one call; ``edge``, ``direction``, ``cell_side``: ``_border_cells(modules)``.

    Samples off the image are not data. Clipped samples are: dropping them leaves a fit of the slope alone,
    wild where only a pixel or two of it is below 255; kept, the clipped plateau is the bright level, and the
    edge's shift that comes with it is the same on the mirrored inner edge, which measures it (``_bloom``).
    """
    height, width = gray.shape
    n = corners.shape[0]
    side_px, border, reach, nnx, nny, frac, along, kappa, inside, t, mapx, mapy, clockwise, xn = _profile_geometry(
        corners, lens, modules, width, height
    )
    prof = _remap_linear(gray, mapx, mapy).reshape(SAMPLES, PROFILES, n)
    clipped = _clipped_markers(prof, inside) if _clipped(prof) else np.zeros(n // 4, np.bool_)
    if not clipped.any():  # the usual frame
        e, s, contrast, rms = _fit_edges(t, prof, inside.reshape(1, PROFILES, n), reach.reshape(1, n))
        alpha, beta, n_good, _, _ = _side_lines(e, s, contrast, rms, inside, reach, frac, side_px, along, kappa, floor)
        qx, qy = _intersect(alpha, beta, xn, nnx, nny)
        return _to_pixels(lens, qx, qy, corners, border, n_good)
    inner = _inner_profiles(gray, lens, xn, clockwise, reach, clipped, edge, direction, cell_side)
    mk, _, _, _, _, _, _, ilim, it, iprof, iw = inner  # the rest is _bloom's
    # One fit of the outer and the inner profiles: the inner ones are extra sides of PROFILES profiles each.
    n_in = mk.shape[0]
    cols = -(-n_in // PROFILES)
    ft = np.zeros((SAMPLES, PROFILES, n + cols), np.float32)
    fi, fw = np.zeros_like(ft), np.zeros_like(ft)
    flim = np.zeros((PROFILES, n + cols), np.float32)
    for j in range(PROFILES):
        for k in range(n):
            flim[j, k] = reach[k]
            for i in range(SAMPLES):
                ft[i, j, k], fi[i, j, k], fw[i, j, k] = t[i, 0, k], prof[i, j, k], inside[j, k]
    for q in range(n_in):
        j, k = q // cols, n + q % cols
        flim[j, k] = ilim[q]
        for i in range(SAMPLES):
            ft[i, j, k], fi[i, j, k], fw[i, j, k] = it[i, q], iprof[i, q], iw[q]
    e, s, contrast, rms = _fit_edges(ft, fi, fw, flim)
    # A line per side through its clean edge points, then corner k where side k-1 meets side k.
    alpha, beta, n_good, contrast_sum, n_clean = _side_lines(
        e[:, :n], s[:, :n], contrast[:, :n], rms[:, :n], inside, reach, frac, side_px, along, kappa, floor
    )
    qx, qy = _intersect(alpha, beta, xn, nnx, nny)
    m = n // 4
    contrast_out = np.empty(m)
    for i in range(m):
        total, count = 0.0, 0
        for k in range(4 * i, 4 * i + 4):
            total += contrast_sum[k]
            count += n_clean[k]
        contrast_out[i] = total / max(count, 1)
    fit = np.empty((4, n_in), np.float32)
    for q in range(n_in):
        j, k = q // cols, n + q % cols
        fit[0, q], fit[1, q], fit[2, q], fit[3, q] = e[j, k], s[j, k], contrast[j, k], rms[j, k]
    delta = _bloom(inner, fit, contrast_out, qx, qy, clipped, modules, edge)
    for k in range(n):  # each side moved back by its marker's delta: kappa's mean over the profiles, px to normalised
        mean_kappa = kappa[0, k]
        for j in range(1, PROFILES):
            mean_kappa += kappa[j, k]
        alpha[k] -= delta[k // 4] * (mean_kappa / PROFILES)
    qx, qy = _intersect(alpha, beta, xn, nnx, nny)
    return _to_pixels(lens, qx, qy, corners, border, n_good)


@kernel
def _clipped_markers(prof: NDArray[np.uint8], inside: NDArray[np.bool_]) -> NDArray[np.bool_]:  # pragma: no cover
    """Per marker (M,): whether its outer profiles (on the image) hold ``MIN_CLIPPED`` samples at 255 or 0."""
    n = prof.shape[2]
    out = np.empty(n // 4, np.bool_)
    for m in range(n // 4):
        count = 0
        for k in range(4 * m, 4 * m + 4):
            for j in range(PROFILES):
                if inside[j, k]:
                    for i in range(SAMPLES):
                        count += prof[i, j, k] == 255 or prof[i, j, k] == 0
        out[m] = count >= MIN_CLIPPED
    return out


@kernel
def _remap_linear(gray: NDArray[np.uint8], mapx: F32, mapy: F32) -> NDArray[np.uint8]:  # pragma: no cover - compiled
    """``cv2.remap(gray, mapx, mapy, INTER_LINEAR, borderMode=BORDER_REPLICATE)``: bilinear in single precision,
    rounded to the nearest level, as OpenCV 5.1 computes it (tests/perception/test_refine.py holds it to cv2)."""
    h, w = gray.shape
    out = np.empty(mapx.shape, np.uint8)
    for i in range(mapx.shape[0]):
        for j in range(mapx.shape[1]):
            x, y = mapx[i, j], mapy[i, j]
            x0, y0 = int(np.floor(x)), int(np.floor(y))
            ax, ay = np.float32(x - np.float32(x0)), np.float32(y - np.float32(y0))
            xa, xb = min(max(x0, 0), w - 1), min(max(x0 + 1, 0), w - 1)
            ya, yb = min(max(y0, 0), h - 1), min(max(y0 + 1, 0), h - 1)
            v0 = np.float32(gray[ya, xa]) + ax * (np.float32(gray[ya, xb]) - np.float32(gray[ya, xa]))
            v1 = np.float32(gray[yb, xa]) + ax * (np.float32(gray[yb, xb]) - np.float32(gray[yb, xa]))
            v = v0 + ay * (v1 - v0)
            out[i, j] = np.uint8(min(max(np.rint(v), 0.0), 255.0))
    return out


@kernel
def _clipped(prof: NDArray[np.uint8]) -> bool:  # pragma: no cover - compiled
    """Whether any sample is 255 or 0."""
    for v in prof.ravel():  # noqa: SIM110 (a plain loop compiles; a generator into any() need not)
        if v == 255 or v == 0:  # noqa: PLR1714
            return True
    return False


@kernel
def _undistort(lens: F64, corners: F64) -> F64:  # pragma: no cover - compiled
    """Undistorted normalised coordinates (N, 2) of pixels (N, 2): ``cv2.undistortPoints`` with 20 iterations and a
    1e-10 px tolerance, its arithmetic in its order (it ignores the skew too). Only where the anchors go depends on
    them, not where the edges are found: 20 iterations are plenty."""
    fx, cx, fy, cy = lens[0], lens[2], lens[3], lens[4]
    k1, k2, p1, p2, k3, k4, k5, k6 = lens[5], lens[6], lens[7], lens[8], lens[9], lens[10], lens[11], lens[12]
    ifx, ify = 1.0 / fx, 1.0 / fy
    out = np.empty((corners.shape[0], 2))
    for i in range(corners.shape[0]):
        u, v = corners[i, 0], corners[i, 1]
        x = x0 = (u - cx) * ifx
        y = y0 = (v - cy) * ify
        error = np.inf
        for _ in range(20):
            if error < 1e-10:
                break
            r2 = x * x + y * y
            icdist = (1 + ((k6 * r2 + k5) * r2 + k4) * r2) / (1 + ((k3 * r2 + k2) * r2 + k1) * r2)
            if icdist < 0:
                x, y = (u - cx) * ifx, (v - cy) * ify
                break
            delta_x = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            delta_y = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x = (x0 - delta_x) * icdist
            y = (y0 - delta_y) * icdist
            r2 = x * x + y * y
            r4 = r2 * r2
            r6 = r4 * r2
            a1, a2, a3 = 2 * x * y, r2 + 2 * x * x, r2 + 2 * y * y
            cdist = 1 + k1 * r2 + k2 * r4 + k3 * r6
            icdist2 = 1.0 / (1 + k4 * r2 + k5 * r4 + k6 * r6)
            xd = x * cdist * icdist2 + p1 * a1 + p2 * a2
            yd = y * cdist * icdist2 + p1 * a3 + p2 * a1
            error = np.sqrt((xd * fx + cx - u) ** 2 + (yd * fy + cy - v) ** 2)
        out[i, 0], out[i, 1] = x, y
    return out


@kernel
def _profile_geometry(
    corners: F64, lens: F64, modules: int, width: int, height: int
) -> tuple[Any, ...]:  # pragma: no cover - compiled
    """Per side of the detected corners (4M, 2): side_px, border, reach, nnx, nny (S,); frac, along, kappa,
    inside (J, S); t (T, 1, S); mapx, mapy (T, J S); then clockwise (M,) and xn (4M, 2), the corners normalised.

    Anchors evenly along each side, straight in normalised coordinates, away from the corners; each profile
    runs along the pixel direction of the side's inward normal, found one pixel-ish further in.
    """
    xn = _undistort(lens, corners)
    n = corners.shape[0]
    m = n // 4
    side_px, ux, uy, ulen = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        nxt = k - k % 4 + (k + 1) % 4
        side_px[k] = np.hypot(corners[nxt, 0] - corners[k, 0], corners[nxt, 1] - corners[k, 1])
        ux[k], uy[k] = xn[nxt, 0] - xn[k, 0], xn[nxt, 1] - xn[k, 1]
        ulen[k] = np.hypot(ux[k], uy[k])
    # The inward normal: ArUco corners run clockwise on screen (a positive shoelace sum in pixels).
    clockwise = np.empty(m, np.bool_)
    for i in range(m):
        area = 0.0
        for k in range(4 * i, 4 * i + 4):
            nxt = k - k % 4 + (k + 1) % 4
            area += corners[k, 0] * corners[nxt, 1] - corners[nxt, 0] * corners[k, 1]
        clockwise[i] = area >= 0
    border, reach, nnx, nny = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    frac, along, kappa = np.empty((PROFILES, n)), np.empty((PROFILES, n)), np.empty((PROFILES, n))
    inside = np.empty((PROFILES, n), np.bool_)
    t = np.empty((SAMPLES, 1, n), np.float32)
    mapx, mapy = np.empty((SAMPLES, PROFILES * n), np.float32), np.empty((SAMPLES, PROFILES * n), np.float32)
    step = 1.0 / lens[0]
    for k in range(n):
        nxt, prv = k - k % 4 + (k + 1) % 4, k - k % 4 + (k + 3) % 4
        border[k] = (side_px[prv] + side_px[nxt]) / (2.0 * modules)  # the border's width across side k
        reach[k] = min(max(REACH * border[k], MIN_REACH_PX), MAX_REACH_PX)
        for i in range(SAMPLES):
            t[i, 0, k] = reach[k] * _GRID[i]
        skip = min(CORNER_SKIP_PX / max(side_px[k], 1e-9), 0.25)
        g = (1.0 if clockwise[k // 4] else -1.0) / ulen[k]
        nnx[k], nny[k] = -uy[k] * g, ux[k] * g
        for j in range(PROFILES):
            f = skip + (1.0 - 2.0 * skip) * (j + 0.5) / PROFILES  # 0 at corner k, 1 at corner k + 1
            frac[j, k] = f
            along[j, k] = (f - 0.5) * ulen[k]
            ax, ay = xn[k, 0] + f * ux[k], xn[k, 1] + f * uy[k]
            pu, pv = distort(lens, ax, ay)
            qu, qv = distort(lens, ax + step * nnx[k], ay + step * nny[k])
            inv = 1.0 / np.hypot(qu - pu, qv - pv)
            kappa[j, k] = step * inv
            dx, dy = np.float32((qu - pu) * inv), np.float32((qv - pv) * inv)
            col = j * n + k
            for i in range(SAMPLES):
                mapx[i, col] = np.float32(pu) + t[i, 0, k] * dx
                mapy[i, col] = np.float32(pv) + t[i, 0, k] * dy
            x0, x1, y0, y1 = mapx[0, col], mapx[SAMPLES - 1, col], mapy[0, col], mapy[SAMPLES - 1, col]
            inside[j, k] = (
                min(x0, x1) >= 0 and max(x0, x1) <= width - 1 and min(y0, y1) >= 0 and max(y0, y1) <= height - 1
            )
    return side_px, border, reach, nnx, nny, frac, along, kappa, inside, t, mapx, mapy, clockwise, xn


@kernel
def _side_lines(
    e: F32,
    s: F32,
    contrast: F32,
    rms: F32,
    inside: Any,
    reach: F64,
    frac: F64,
    side_px: F64,
    along: F64,
    kappa: F64,
    floor: float,
) -> tuple[F64, F64, NDArray[np.intp], F64, NDArray[np.intp]]:  # pragma: no cover - compiled
    """Each side's line through its clean edge points (J, S), and what ``_bloom`` needs of them.

    A profile is clean where the fit found an edge inside its reach with a sharp, well-fitting step; not much
    less contrast than the side's average (else a shadow or an occluder crosses it); and further from a
    corner than blur rounds it off. The line: across = alpha + beta along (normalised, side frame), Tukey-
    reweighted least squares, twice: points further than 4.7 robust sigmas (median absolute residual, at
    least ``floor``) from it get no weight. The points lie within a fraction of a pixel of the side's own
    frame, so least squares in it is total least squares. A side without clean profiles gives a degenerate
    line: its corners are NaN or infinite and fail ``_to_pixels``' checks.

    Returns per side (S,): alpha, beta, the number of points that kept a weight over 1/2, and the sum and
    number of the clean profiles' contrasts.
    """
    n_pts, n = e.shape
    alpha, beta = np.empty(n), np.empty(n)
    n_good, n_clean = np.empty(n, np.intp), np.empty(n, np.intp)
    contrast_sum = np.empty(n)
    good = np.empty(n_pts, np.bool_)
    across, wt, absr = np.empty(n_pts), np.empty(n_pts), np.empty(n_pts)
    for k in range(n):
        count, csum = 0, 0.0
        for j in range(n_pts):
            ok = inside[j, k] and abs(e[j, k]) < 0.8 * reach[k] and s[j, k] < reach[k]
            good[j] = ok and rms[j, k] < 0.15 * contrast[j, k]
            if good[j]:
                count += 1
                csum += contrast[j, k]
        n_side = count + 1e-9
        blur = 0.0
        for j in range(n_pts):
            good[j] = good[j] and contrast[j, k] > 0.5 * csum / n_side
            if good[j]:
                blur += s[j, k]
        blur /= n_side
        edge_gap = max(CORNER_SKIP_PX, CORNER_BLUR * blur)
        count, csum = 0, 0.0
        for j in range(n_pts):
            good[j] = good[j] and min(frac[j, k], 1.0 - frac[j, k]) * side_px[k] > edge_gap
            across[j] = e[j, k] * kappa[j, k] if good[j] else 0.0
            wt[j] = 1.0 if good[j] else 0.0
            if good[j]:
                count += 1
                csum += contrast[j, k]
        n_clean[k], contrast_sum[k] = count, csum
        mid = min(count // 2, n_pts - 1)
        for it in range(3):
            sw = sa = saa = sc = sac = 0.0
            for j in range(n_pts):
                a = along[j, k]
                sw += wt[j]
                sa += wt[j] * a
                saa += wt[j] * a * a
                sc += wt[j] * across[j]
                sac += wt[j] * a * across[j]
            det = sw * saa - sa * sa + 1e-300
            alpha[k] = (saa * sc - sa * sac) / det
            beta[k] = (sw * sac - sa * sc) / det
            if it == 2:
                break
            for j in range(n_pts):
                absr[j] = abs(across[j] - alpha[k] - beta[k] * along[j, k]) if good[j] else np.inf
            absr.sort()  # in place: absr is refilled before it is read again
            sigma = max(1.4826 * absr[mid], floor)
            for j in range(n_pts):
                u = (across[j] - alpha[k] - beta[k] * along[j, k]) / (4.685 * sigma)
                wt[j] = max(1.0 - u * u, 0.0) ** 2 if good[j] else 0.0
        n_good[k] = 0
        for j in range(n_pts):
            n_good[k] += wt[j] > 0.5
    return alpha, beta, n_good, contrast_sum, n_clean


@kernel
def _intersect(alpha: F64, beta: F64, xn: F64, nnx: F64, nny: F64) -> tuple[F64, F64]:  # pragma: no cover - compiled
    """Corner k (normalised) where the line of side k-1 meets the line of side k (``_side_lines``).

    Side k: X(a) = middle + a u / |u| + (alpha + beta a) n, written as lx X + ly Y = lc, with u from corner k
    to corner k + 1 and n = (``nnx``, ``nny``) its inward unit normal.
    """
    n = alpha.shape[0]
    lx, ly, lc = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        nxt = k - k % 4 + (k + 1) % 4
        ux, uy = xn[nxt, 0] - xn[k, 0], xn[nxt, 1] - xn[k, 1]
        ulen = np.hypot(ux, uy)
        dx, dy = ux / ulen + beta[k] * nnx[k], uy / ulen + beta[k] * nny[k]
        lx[k], ly[k] = -dy, dx
        lc[k] = lx[k] * (xn[k, 0] + 0.5 * ux + alpha[k] * nnx[k]) + ly[k] * (xn[k, 1] + 0.5 * uy + alpha[k] * nny[k])
    qx, qy = np.empty(n), np.empty(n)
    for k in range(n):
        prv = k - k % 4 + (k + 3) % 4
        den = lx[prv] * ly[k] - lx[k] * ly[prv]
        qx[k] = (lc[prv] * ly[k] - lc[k] * ly[prv]) / den
        qy[k] = (lx[prv] * lc[k] - lx[k] * lc[prv]) / den
    return qx, qy


@kernel
def _to_pixels(
    lens: F64, qx: F64, qy: F64, corners: F64, border: F64, n_good: NDArray[np.intp]
) -> tuple[F64, NDArray[np.bool_]]:  # pragma: no cover - compiled
    """The refined corners (M, 4, 2) in pixels and which markers keep them (M,); the others keep ``corners``.

    A marker keeps them when each side had ``MIN_GOOD`` good points and no corner moved further than
    ``MAX_SHIFT`` of its thinnest border width (at least 1.5 px) from OpenCV's; NaN fails both.
    """
    m = corners.shape[0] // 4
    out = np.empty((m, 4, 2))
    ok = np.empty(m, np.bool_)
    for i in range(m):
        limit = max(MAX_SHIFT * border[4 * i : 4 * i + 4].min(), 1.5)
        ok[i] = True
        for c in range(4):
            k = 4 * i + c
            u, v = distort(lens, qx[k], qy[k])
            out[i, c, 0], out[i, c, 1] = u, v
            ok[i] = ok[i] and n_good[k] >= MIN_GOOD and np.hypot(u - corners[k, 0], v - corners[k, 1]) < limit
        if not ok[i]:
            out[i] = corners[4 * i : 4 * i + 4]
    return out, ok


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


@inlined
def _square_to_quad(x: F64, y: F64, m: int) -> tuple[float, ...]:  # pragma: no cover - compiled
    """The homography (8,) from the unit square onto marker m's quad in x, y (4M,), closed form (Heckbert).

    Corners in ArUco order: TL, TR, BR, BL at (0, 0), (1, 0), (1, 1), (0, 1). ``_on_quad`` applies it.
    """
    x0, x1, x2, x3 = x[4 * m], x[4 * m + 1], x[4 * m + 2], x[4 * m + 3]
    y0, y1, y2, y3 = y[4 * m], y[4 * m + 1], y[4 * m + 2], y[4 * m + 3]
    sx, sy = x0 - x1 + x2 - x3, y0 - y1 + y2 - y3
    dx1, dx2, dy1, dy2 = x1 - x2, x3 - x2, y1 - y2, y3 - y2
    den = dx1 * dy2 - dx2 * dy1
    g, h = (sx * dy2 - dx2 * sy) / den, (dx1 * sy - sx * dy1) / den
    return x1 - x0 + g * x1, x3 - x0 + h * x3, x0, y1 - y0 + g * y1, y3 - y0 + h * y3, y0, g, h


@inlined
def _on_quad(hom: tuple[float, ...], u: float, v: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """The point (u, v) of the unit square through the homography ``hom`` (``_square_to_quad``)."""
    a, b, c, d, e, f, g, h = hom
    w = g * u + h * v + 1.0
    return (a * u + b * v + c) / w, (d * u + e * v + f) / w


@kernel
def _inner_profiles(
    gray: NDArray[np.uint8], lens: F64, xn: F64, clockwise: NDArray[np.bool_], reach: F64,
    clipped: NDArray[np.bool_], edge: F64, direction: F64, cell_side: NDArray[np.intp],
) -> tuple[Any, ...]:  # pragma: no cover - compiled  # fmt: skip
    """The profiles across the border's inner edge of the ``clipped`` markers, one per code cell along it.

    Each runs outward from the middle of the cell's edge, where the detected corners put it: across a white
    cell, the mirror of an outer profile (white to black); across a black cell, nothing (the fit's contrast
    drops it). Built like the outer ones: a straight normal in normalised coordinates, its direction in pixels
    one pixel-ish out, the outer side's reach. ``xn`` (4M, 2) the detected corners (normalised), ``reach``
    (4M,) the sides' profile reach; ``edge``, ``direction``, ``cell_side`` from ``_border_cells``.

    Returns, per profile (N,): its marker, its cell, anchor x, y and outward unit normal nx, ny (normalised),
    kappa (normalised distance per pixel along it), reach (float32); then t and the samples (T, N) and whether
    it lies on the image (N,).
    """
    height, width = gray.shape
    n_cells = edge.shape[0]
    n = int(clipped.sum()) * n_cells
    mk, cell = np.empty(n, np.intp), np.empty(n, np.intp)
    x, y, nx, ny, kappa = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    lim = np.empty(n, np.float32)
    t = np.empty((SAMPLES, n), np.float32)
    mapx, mapy = np.empty((SAMPLES, n), np.float32), np.empty((SAMPLES, n), np.float32)
    on_image = np.empty(n, np.bool_)
    xs, ys = xn[:, 0].copy(), xn[:, 1].copy()
    step = 1.0 / lens[0]
    q = 0
    for m in range(clipped.shape[0]):
        if not clipped[m]:
            continue
        hom = _square_to_quad(xs, ys, m)
        sign = -1.0 if clockwise[m] else 1.0
        for c in range(n_cells):
            mk[q], cell[q] = m, c
            # The edge's middle and a short step along it, through the detected corners' homography.
            x0, y0 = _on_quad(hom, edge[c, 0] + 0.0 * direction[c, 0], edge[c, 1] + 0.0 * direction[c, 1])
            x1, y1 = _on_quad(hom, edge[c, 0] + 1e-3 * direction[c, 0], edge[c, 1] + 1e-3 * direction[c, 1])
            dx, dy = x1 - x0, y1 - y0
            scale = sign / np.hypot(dx, dy)  # the outward normal, on the outer sides' outer side
            x[q], y[q], nx[q], ny[q] = x0, y0, -dy * scale, dx * scale
            pu, pv = distort(lens, x0, y0)
            qu, qv = distort(lens, x0 + step * nx[q], y0 + step * ny[q])
            dpx, dpy = qu - pu, qv - pv
            inv = 1.0 / np.hypot(dpx, dpy)
            kappa[q] = step * inv
            lim[q] = reach[4 * m + cell_side[c]]
            for i in range(SAMPLES):
                t[i, q] = lim[q] * _GRID[i]  # pixels, positive outward
                mapx[i, q] = pu + t[i, q] * (dpx * inv)
                mapy[i, q] = pv + t[i, q] * (dpy * inv)
            a, b = mapx[0, q], mapx[SAMPLES - 1, q]
            u, v = mapy[0, q], mapy[SAMPLES - 1, q]
            on_image[q] = min(a, b) >= 0 and max(a, b) <= width - 1 and min(u, v) >= 0 and max(u, v) <= height - 1
            q += 1
    return mk, cell, x, y, nx, ny, kappa, lim, t, _remap_linear(gray, mapx, mapy), on_image


@inlined
def _pairwise_sum(a: F64) -> float:  # pragma: no cover - compiled
    """numpy's sum of a row (its pairwise summation, for up to 128 values): the same number, bit for bit."""
    n = a.shape[0]
    if n < 8:
        total = 0.0
        for i in range(n):
            total += a[i]
        return total
    r = a[:8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += a[i]
        i += 1
    return float(total)


@kernel
def _bloom(
    inner: tuple[Any, ...], fit: F32, contrast_out: F64, qx: F64, qy: F64, clipped: NDArray[np.bool_], modules: int,
    edge: F64,
) -> F64:  # pragma: no cover - compiled  # fmt: skip
    """Per marker (M,): how far clipping put its fitted outer edges inside the true ones, px (0: not clipped).

    ``inner``: ``_inner_profiles``; ``fit`` (4, N) the inner profiles' edge, blur, contrast and RMS,
    ``contrast_out`` (M,) the markers' mean contrast on their outer edges, ``qx``, ``qy`` (4M,) the corners from
    the fitted outer edges (normalised). If those edges sit delta inside, the corners put the inner edge
    2 delta / modules too far in and the fit finds it delta too far out, so that it appears
    e = 2 delta (1 - 1 / modules) outward of where the corners put it, whatever the blur. A clipped marker with
    fewer than ``MIN_INNER`` white cells measured takes the median of the others, or 0.
    """
    mk, cell, x0, y0, nx, ny, kappa, lim, _, _, on_image = inner
    m = clipped.shape[0]
    # Each white cell's edge, outward of where the refined corners put it (px); a row per marker, NaN-padded.
    found = np.full((m, edge.shape[0]), np.nan)
    count = np.zeros(m, np.intp)
    for q in range(mk.shape[0]):
        e, s, contrast, rms = fit[0, q], fit[1, q], fit[2, q], fit[3, q]
        good = on_image[q] and abs(e) < np.float32(0.8) * lim[q] and s < lim[q] and rms < np.float32(0.15) * contrast
        good = good and contrast > 0.5 * contrast_out[mk[q]]  # a black cell, or a shadow: no edge
        if good:
            x, y = _on_quad(_square_to_quad(qx, qy, mk[q]), edge[cell[q], 0], edge[cell[q], 1])
            found[mk[q], cell[q]] = e + ((x0[q] - x) * nx[q] + (y0[q] - y) * ny[q]) / kappa[q]
            count[mk[q]] += 1
    # A mean (the spread is mostly noise), without the cells more than 3 robust sigmas off the median.
    delta = np.zeros(m)
    measured = np.zeros(m, np.bool_)
    for i in range(m):
        if not clipped[i]:
            continue
        half = min(count[i] // 2, found.shape[1] - 1)
        row = found[i]
        off = np.abs(row - np.sort(row)[half])  # NaN sorts last, and stays NaN
        spread = 3.0 * 1.4826 * np.sort(off)[half]
        spread = spread if not spread < 0.1 else 0.1
        keep = off <= spread  # NaN is not
        delta[i] = _pairwise_sum(np.where(keep, row, 0.0)) / keep.sum() / (2.0 * (1.0 - 1.0 / modules))
        measured[i] = count[i] >= MIN_INNER
    if not measured.any():
        return np.zeros(m)
    fallback = np.sort(delta[measured])[int(measured.sum()) // 2]
    for i in range(m):
        if clipped[i] and not measured[i]:
            delta[i] = fallback
    return delta


@kernel
def _fit_edges(t: Any, intensity: Any, w: Any, lim: Any) -> tuple[F32, F32, F32, F32]:  # noqa: PLR0915 # pragma: no cover - compiled
    """Fit I(t) = B + (D - B) Phi((t - e) / s) to every profile: edge e, blur sigma s, contrast B - D, RMS.

    ``intensity`` (samples, profiles, sides), any real dtype; ``t`` and the weights ``w`` (samples or 1,
    profiles or 1, sides) and ``lim`` (profiles or 1, sides) broadcast against it; the results are
    (profiles, sides). Variable projection: the levels B, D are the weighted linear least-squares solution for
    the current e and s, and each Gauss-Newton step on (e, s) uses the Jacobian projected off the levels
    (Kaufman), so it converges like a full four-parameter fit. Starts from the centroid and spread of the
    intensity drop; e stays within +-lim. After each step, the fit stops if the typical (median) edge moved less
    than ``CONVERGED_PX``: after the first, the start was close; after the second, a third would change the
    corners by far less than their noise (on 400 held-out frames the fused errors and their ratios to the
    Cramér–Rao bound were unchanged to the third digit without it, and a quarter of the frames were faster).
    """
    n_t, n_j, n_s = intensity.shape
    e, s, rms = np.empty((n_j, n_s), np.float32), np.empty((n_j, n_s), np.float32), np.empty((n_j, n_s), np.float32)
    a, b = np.empty((n_j, n_s)), np.empty((n_j, n_s))
    n, y1, yy, y2 = np.empty((n_j, n_s)), np.empty((n_j, n_s)), np.empty((n_j, n_s)), np.empty((n_j, n_s))
    moved = np.empty(n_j * n_s)
    for j in range(n_j):
        for k in range(n_s):
            jt, jw, jl = min(j, t.shape[1] - 1), min(j, w.shape[1] - 1), min(j, lim.shape[0] - 1)
            sw = s1 = s2 = mass = m1 = m2 = 0.0
            for i in range(n_t):
                wi = w[min(i, w.shape[0] - 1), jw, k] * 1.0
                v = float(intensity[i, j, k])
                sw += wi
                s1 += wi * v
                s2 += wi * v * v
                if i + 1 < n_t:
                    # The start: centroid and spread of the (positive) intensity drop going inwards.
                    drop = (
                        max(v - float(intensity[i + 1, j, k]), 0.0) * wi * (w[min(i + 1, w.shape[0] - 1), jw, k] * 1.0)
                    )
                    tm = 0.5 * (float(t[min(i, t.shape[0] - 1), jt, k]) + float(t[min(i + 1, t.shape[0] - 1), jt, k]))
                    mass += drop
                    m1 += drop * tm
                    m2 += drop * tm * tm
            n[j, k], y1[j, k], yy[j, k] = sw + 1e-6, s1, s2
            mass += 1e-6
            e0 = m1 / mass
            spread = m2 / mass - e0 * e0
            s0 = np.sqrt(spread) if spread > 0.0 else 0.0
            e[j, k], s[j, k] = e0, min(max(s0, 0.3), float(lim[jl, k]))
    for _step in range(MAX_STEPS):
        for j in range(n_j):
            for k in range(n_s):
                jt, jw, jl = min(j, t.shape[1] - 1), min(j, w.shape[1] - 1), min(j, lim.shape[0] - 1)
                ej, sj = float(e[j, k]), float(s[j, k])
                s1 = s2 = sy = cc0 = cc1 = dd0 = dd1 = g0 = g1 = h0 = h1 = h01 = 0.0
                for i in range(n_t):
                    wi = w[min(i, w.shape[0] - 1), jw, k] * 1.0
                    v = float(intensity[i, j, k])
                    z = (float(t[min(i, t.shape[0] - 1), jt, k]) - ej) / sj
                    z2 = z * z
                    # Logistic approximation of the normal CDF; its pdf not as ex cdf^2: ex may overflow to inf.
                    cdf = 1.0 / (1.0 + np.exp(z * (_C1N + _C3N * z2)))
                    pdf = cdf * (1.0 - cdf) * (_C1 + _C3X3 * z2)
                    wc, wd = wi * cdf, wi * pdf
                    s1 += wc
                    s2 += wc * cdf
                    sy += wc * v
                    cc0 += wd
                    cc1 += wd * z
                    dd0 += wd * cdf
                    dd1 += wd * z * cdf
                    g0 += wd * v
                    g1 += wd * z * v
                    h0 += wd * pdf
                    h01 += wd * z * pdf
                    h1 += wd * z * z * pdf
                # Levels: B = b, D - B = a (the basis is [1, Phi], its Gram matrix [[n, s1], [s1, s2]]).
                nn = n[j, k]
                ig = 1.0 / (nn * s2 - s1 * s1)
                aa = (nn * sy - s1 * y1[j, k]) * ig
                bb = (y1[j, k] - aa * s1) / nn
                a[j, k], b[j, k], y2[j, k] = aa, bb, sy
                # Gradient against [pdf, pdf z] of the residual I - b - a Phi, and their normal matrix projected
                # off the basis (Kaufman): A - C^T G^-1 C, with C the basis-derivative cross sums.
                gr0, gr1 = g0 - bb * cc0 - aa * dd0, g1 - bb * cc1 - aa * dd1
                p00, p01 = (s2 * cc0 - s1 * dd0) * ig, (s2 * cc1 - s1 * dd1) * ig
                p10, p11 = (nn * dd0 - s1 * cc0) * ig, (nn * dd1 - s1 * cc1) * ig
                d0 = h0 * 1.001 - (cc0 * p00 + dd0 * p10)
                d1 = h1 * 1.001 - (cc1 * p01 + dd1 * p11)
                off = h01 - (cc0 * p01 + dd0 * p11)
                # The model's derivatives are -(a/s) [pdf, pdf z]: the step on (e, s) scales back by -s/a.
                kk = sj / (aa * (d0 * d1 - off * off))
                move_e, move_s = kk * (d1 * gr0 - off * gr1), kk * (d0 * gr1 - off * gr0)
                moved[j * n_s + k] = move_e
                lj = float(lim[jl, k])
                e[j, k] = min(max(ej - move_e, -lj), lj)
                s[j, k] = min(max(sj - move_s, 0.2), lj)
        if abs(np.median(moved)) < CONVERGED_PX:
            break
    for j in range(n_j):
        for k in range(n_s):
            # At the least-squares levels the residual is orthogonal to them: sum r^2 = sum r I.
            rms[j, k] = np.sqrt(max(yy[j, k] - b[j, k] * y1[j, k] - a[j, k] * y2[j, k], 0.0) / n[j, k])
    return e, s, (-a).astype(np.float32), rms
