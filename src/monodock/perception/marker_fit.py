"""Accurate marker corners by a photometric fit of the whole printed marker: the dock survey's refiner.

Not the per-frame path (``monodock.perception.refine`` is, at a fraction of a millisecond): this fits every
black/white edge of the marker, its code included, to the pixels, for ~10 ms per marker (the 25-40 px
ones; a 200 px marker ~20 ms: the cost follows the edges' length), and measures the print's edge offset on
the way. It is the corner study's "photometric fit with grid lines free"
(``/work/corner_study``): on opencv_contrib's ChArUco photos (26 px markers, JPEG) its corners' radial bias
against the board's X-junctions was within 0.04 px on every view, with the lowest view-specific noise of the
methods tried; on exact renders 0.025 px rms.

The model of the image over the marker and a margin of quiet zone around it:

    I(p) = W(p) (1 - C(p)) + D C(p),        W(p) = w0 + w1 dx + w2 dy   (the white may slope: vignetting)

C(p) in [0, 1] is pixel p's black coverage: the marker's square (its outer border) less its white code cells,

    C = Square(u, v) - sum_IJ R[J, I] A_I(u) B_J(v)

where u, v in [0, M] are module coordinates (M modules a side, border included) through a homography of the
undistorted normalised coordinates (the marker is flat; only the lens bends its lines in pixels). Every
black/white boundary is moved towards the white by the offset ``delta`` px (> 0: black looks thicker than
printed; ink spread, sharpening), and blurred by an isotropic Gaussian of sigma ``s`` px (optics, pixel area,
demosaicing, JPEG in one number). Why it is exact along the edges, without rendering or supersampling:

* Near a pixel, homography and lens are affine, so a Gaussian of s px is, in module coordinates, one of
  s |grad u| along u and s |grad v| along v (dropping the covariance's off-diagonal term, which only pixels at
  cell corners see): the blur is separable, each axis a difference of normal CDFs.
* The dilated (or eroded) white cells are a union of axis-aligned rectangles on a refined grid: each grid line
  l becomes a strip [l - d, l + d] (d = |delta| |grad u|), each cell a core between strips; a core keeps its
  cell's colour, a strip is white where any adjacent cell is (white grown, delta < 0) or where all are (white
  shrunk, delta > 0). A_I(u), B_J(v) are the blurred indicators of the refined cells, R the refined pattern.

Why the grid lines are free (each interior line l = 1..M-1 has its own offset in u and in v, in modules): the
offset moves every edge towards the white, so it is told apart from the geometry only by edges of both
polarities on one line. With the grid tied to the outline, the fit would also assume that each cell is exactly
side / M, and printed boards are not (a rasterised print's code grid is often ~1.5 % larger, its last border
cell thinner): that error would leak into the offset and the outline (+0.1 px radial bias in the study). Free,
the lines absorb the print's cell placement, the offset comes from the interior lines, and the outline from
the outer edges corrected by it.

The levels w0, w1, w2, D enter linearly and are solved by linear least squares at each evaluation (variable
projection); Levenberg-Marquardt sees only the corners (8 numbers, normalised coordinates times the focal
lengths: ~px), the blur, the offset (unless given) and the 2 (M - 1) grid lines, with Kaufman's projected
Jacobian. The Jacobian leaves out how the blur's scale (|grad u|, |grad v|) follows the geometry, as the
study's prototype does, so that both stop at the same point (on the photos the corners agree with the
prototype's to 0.003 px typically, 0.013 px at most). The residual itself is exact. The pixels fitted are
those within ``BAND_PX`` of a black/white boundary (and inside the marker plus ``MARGIN`` modules), chosen
once from the starting corners, so that the cost is a fixed sum.

The coverage and its Jacobian, and the choice of pixels (with each pixel's undistortion by Newton's method on
``monodock.core.lens.project``, whose Jacobian the blur's scale needs anyway), are compiled kernels
(``monodock.core.compiled``); the 20-30 parameter solve is numpy. The model (its parameters, the coverage and its
Jacobian) is ``perception.marker_model``'s; this module chooses the pixels, runs the solver and checks the result.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.compiled import inlined, kernel
from monodock.core.layout import DockLayout
from monodock.core.lens import lens_of, project
from monodock.errors import InputError
from monodock.perception.checks import black_cells, check_corners, check_gray
from monodock.perception.detect import Detection, MarkerObservation
from monodock.perception.marker_model import _homography, _Model, _Pixels, _State

__all__ = ["MarkerFit", "fit_detection", "fit_marker"]

F64 = NDArray[np.float64]

ROI_PAD_PX = 10  # the pixels considered reach this far beyond the starting corners' bounding box ...
MARGIN = 1.5  # ... and this many modules beyond the marker (the quiet zone's white pins the white level)
BAND_PX = 3.0  # fitted: the pixels within this distance of a black/white boundary (the flat insides of big
# cells only pin the levels, which the band's plateaus do as well; on 3-px modules the band keeps ~all)
MAX_EVALUATIONS = 40  # of the model and its Jacobian; the photos' markers take 5-20, the simulator's ~5
STEP_TOL = 1e-3  # converged: no corner, nor the blur or offset, moves more than this (px) ...
COST_TOL = 1e-9  # ... or the cost falls by less than this fraction
MIN_MODULE_PX = 1.5  # a smaller marker is not fitted: its cells' edges blur into each other
MIN_PIXELS_PER_PARAMETER = 4
# The study's sanity checks: a blur that is no blur or a smear, or corners that ran away from the start.
BLUR_RANGE_PX = (0.03, 5.0)
MAX_MOVE_PX = 3.0
# And two of its own, for patches with no marker on them: too little contrast, or a fit that explains little.
MIN_CONTRAST = 12.0  # grey levels, white minus black
MAX_RMS_FRACTION = 0.25  # of the contrast
MAX_OFFSET_MODULES = 0.45  # the refined grid's strips of two lines must not meet
DT_SAMPLES = 16  # the edge-distance map's samples per module ...
DT_PAD = 3  # ... and its quiet zone, modules


@dataclass(frozen=True)
class MarkerFit:
    """One marker's photometric fit.

    Attributes:
        corners: the outer border's corners as printed (the edge offset taken out), shape (4, 2), pixels,
            ArUco order TL, TR, BR, BL.
        offset_px: the edge offset, px: how far every black/white edge appears moved towards the white (> 0:
            black looks thicker than printed); fitted, or the one given.
        blur_px: the edges' blur, the sigma of a Gaussian, px.
        rms: the intensity residual, grey levels.
        converged: whether the solver met its tolerances; False when it ran out of evaluations with the fit
            still improving (kept, as the study kept it: Levenberg-Marquardt only ever lowers the cost).
    """

    corners: F64
    offset_px: float
    blur_px: float
    rms: float
    converged: bool


def fit_marker(
    gray: NDArray[np.uint8],
    corners: NDArray[np.float64],
    camera: CameraModel,
    bits: NDArray[np.integer[Any]] | NDArray[np.bool_],
    *,
    offset_px: float | None = None,
) -> MarkerFit | None:
    """Fit one marker's printed pattern to the image, from its detected (or refined) corners.

    Args:
        gray: the image, 8-bit single channel (``monodock.perception.detect.as_gray``), the camera's size.
        corners: the starting corners (4, 2), pixels, ArUco order TL, TR, BR, BL; within a pixel or so of the
            truth (OpenCV's or ``monodock.perception.refine``'s).
        camera: the camera that took the image (its lens maps the pixels to where the marker is flat).
        bits: the marker's cells, border included, as ``DockLayout.marker_bits`` gives them: 0 black,
            1 white, shape (M, M), row 0 the side from corner 0 to corner 1.
        offset_px: the edge offset to hold fixed (px, > 0: black thicker), e.g. pooled over many markers;
            None fits it per marker.

    Returns:
        The fit, or None when the marker cannot be fitted: too small, a corner off the image, too few pixels,
        a singular or non-finite solve, or a result that fails the sanity checks (blur outside
        ``BLUR_RANGE_PX``, a corner moved more than ``MAX_MOVE_PX``, too little contrast, a poor fit).

    Raises:
        InputError: on an image, corners, cells or offset of the wrong form.
    """
    img = check_gray(gray, "marker fit", camera)
    start = check_corners(corners)
    black = black_cells(bits)
    if offset_px is not None and not math.isfinite(offset_px):
        raise InputError(f"offset_px must be a finite number of pixels or None, got {offset_px}")
    return _fit(img, start, camera, black, offset_px)


def fit_detection(
    gray: NDArray[np.uint8],
    detection: Detection,
    camera: CameraModel,
    layout: DockLayout,
    *,
    offset_px: float | None = None,
) -> Detection:
    """The detection with each marker's corners from ``fit_marker``; the roles that could not be fitted keep
    their corners and are listed in ``unrefined``.

    Args:
        gray: the image the detection was made on.
        detection: the markers, with OpenCV's or refined corners as the start.
        camera: the camera that took the image.
        layout: the dock layout, for each marker's cells.
        offset_px: the edge offset to hold fixed for every marker, or None to fit it per marker.

    Raises:
        InputError: on an image or offset of the wrong form.
    """
    img = check_gray(gray, "marker fit", camera)
    if offset_px is not None and not math.isfinite(offset_px):
        raise InputError(f"offset_px must be a finite number of pixels or None, got {offset_px}")
    observations = dict(detection.observations)
    failed = []
    for role, o in detection.observations.items():
        c = np.asarray(o.corners, dtype=np.float64)
        fit = None
        if c.shape == (4, 2) and np.isfinite(c).all():  # as refine_detection: a bad quad is not fitted, no error
            fit = _fit(img, c, camera, black_cells(layout.marker_bits(o.marker_id)), offset_px)
        if fit is None:
            failed.append(role)
        else:
            observations[role] = MarkerObservation(o.role, o.marker_id, fit.corners)
    return replace(detection, observations=observations, unrefined=tuple(failed))


# --- the fit ---------------------------------------------------------------------------------------


def _fit(
    gray: NDArray[np.uint8], start: F64, camera: CameraModel, black: F64, offset_px: float | None
) -> MarkerFit | None:
    M = black.shape[0]
    height, width = gray.shape
    module_px = float(np.mean(np.linalg.norm(start - np.roll(start, -1, axis=0), axis=1))) / M
    if module_px < MIN_MODULE_PX:
        return None
    if np.any(start < -0.5) or np.any(start[:, 0] > width - 0.5) or np.any(start[:, 1] > height - 0.5):
        return None  # the corner's neighbourhood is not in the picture
    if offset_px is not None and abs(offset_px) > MAX_OFFSET_MODULES * module_px:
        return None
    start_n = camera.normalize(start)
    try:
        pixels = _pixels(gray, start, start_n, camera, black, module_px)
    except np.linalg.LinAlgError:
        return None
    model = _Model(pixels, start_n, np.array([camera.fx, camera.fy]), black, offset_px)
    if pixels.obs.size < MIN_PIXELS_PER_PARAMETER * (model.free.size + 4):
        return None
    try:
        result = _levenberg_marquardt(model)
    except np.linalg.LinAlgError:
        return None
    if result is None:
        return None
    q, state, converged = result
    corners = camera.project(np.column_stack([model.corners_n(q), np.ones(4)]))
    blur, offset = float(q[8]), float(q[9])
    contrast = float(state.levels[0] - state.levels[3])  # white minus black at the pixels' centre
    ok = (
        bool(np.all(np.isfinite(corners)))
        and BLUR_RANGE_PX[0] < blur < BLUR_RANGE_PX[1]
        and float(np.max(np.linalg.norm(corners - start, axis=1))) < MAX_MOVE_PX
        and contrast > MIN_CONTRAST
        and state.rms < MAX_RMS_FRACTION * contrast
        and abs(offset) < MAX_OFFSET_MODULES * module_px
    )
    return MarkerFit(corners, offset, blur, state.rms, converged) if ok else None


def _levenberg_marquardt(model: _Model) -> tuple[F64, _State, bool] | None:
    """Minimise the model's cost from ``model.q0``: the parameters, their state and whether it converged;
    None if the start cannot be evaluated.

    Marquardt's scaling by the largest diagonal of the normal matrix seen so far (MINPACK's, which the study's
    scipy fit ran), Nielsen's update of the damping, each step damped further until it is within
    ``model.max_step``. Converged when a step moves no corner and the offset by more than ``STEP_TOL`` px, or
    lowers the cost by less than ``COST_TOL`` of it: the grid lines may still creep (a line with few edges
    along it is loosely held), but the corners have stopped.
    """
    q = model.q0.copy()
    state = model.evaluate(q)
    if state is None:
        return None
    scale = np.diag(state.normal).copy()
    lam, nu = 1e-3, 2.0
    watched = np.flatnonzero(model.free <= 9)  # the corners, the blur and the offset
    for _ in range(MAX_EVALUATIONS - 1):
        scale = np.maximum(scale, np.diag(state.normal))
        # A parameter that moves no pixel (a grid line with no edge along it) keeps a tiny damping: no step.
        damping = np.diag(np.maximum(scale, 1e-9 * max(float(scale.max()), 1e-300)))
        for _ in range(12):
            step = np.linalg.solve(state.normal + lam * damping, state.gradient)
            if np.all(np.abs(step) <= model.max_step):
                break
            lam *= 4.0
        trial_q = q.copy()
        trial_q[model.free] += step
        small = float(np.max(np.abs(step[watched]))) < STEP_TOL
        trial = model.evaluate(trial_q)
        if trial is not None and trial.cost < state.cost:
            predicted = float(step @ state.gradient - 0.5 * step @ state.normal @ step)
            gain = (state.cost - trial.cost) / max(predicted, 1e-300)
            done = small or state.cost - trial.cost < COST_TOL * state.cost
            q, state = trial_q, trial
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * min(gain, 1.0) - 1.0) ** 3)
            nu = 2.0
            if done:
                return q, state, True
        else:
            if small:  # at the minimum: even a tiny step does not lower the cost
                return q, state, True
            lam *= nu
            nu *= 2.0
    return q, state, False


def _pixels(
    gray: NDArray[np.uint8], start: F64, start_n: F64, camera: CameraModel, black: F64, module_px: float
) -> _Pixels:
    """The pixels to fit: within ``BAND_PX`` of a black/white boundary of the marker where the starting
    corners put it, inside the marker plus ``MARGIN`` modules and the corners' box plus ``ROI_PAD_PX``.

    The undistortion is per pixel and costs the most, so a cheap first cut (the corners' homography in pixels,
    ignoring the lens, with a slack of twice what the lens bends the marker's lines) keeps it to the band.
    """
    M = black.shape[0]
    height, width = gray.shape
    lo = np.maximum(np.floor(start.min(axis=0) - ROI_PAD_PX).astype(int), 0)
    hi = np.minimum(np.ceil(start.max(axis=0) + ROI_PAD_PX).astype(int), (width - 1, height - 1))
    square = np.array([[0.0, 0.0], [M, 0.0], [M, M], [0.0, M]])
    G0 = _homography(start_n, square)
    H_px = _homography(start, square)
    # How far the lens moves module points off the pixel homography's, over the marker and its margin.
    t = np.linspace(-MARGIN, M + MARGIN, 7)
    grid = np.array([(a, b) for a in t for b in t])
    h = np.column_stack([grid, np.ones(len(grid))]) @ np.linalg.inv(G0).T
    px = camera.project(np.column_stack([h[:, :2] / h[:, 2:], np.ones(len(h))]))
    hp = np.column_stack([px, np.ones(len(px))]) @ H_px.T
    bend = float(np.max(np.linalg.norm(hp[:, :2] / hp[:, 2:] - grid, axis=1))) * module_px
    roi = np.array(gray[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1], dtype=np.uint8)  # a writable copy: one compilation
    xy, xn, jn, obs = _select_pixels(
        roi, float(lo[0]), float(lo[1]), lens_of(camera), H_px, G0, _edge_distance_map(black.tobytes(), M),
        module_px, 0.5 + 2.0 * bend, float(M),
    )  # fmt: skip
    if len(obs) == 0:
        return _Pixels(xn, jn, xy, obs)
    spread = max(float(np.ptp(xy, axis=0).max()) / 2.0, 1.0)
    return _Pixels(xn, jn, (xy - xy.mean(axis=0)) / spread, obs)


# --- geometry --------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def _edge_distance_map(black_bytes: bytes, M: int) -> NDArray[np.float32]:
    """Distance (modules) to the nearest black/white boundary of the marker (outline included), sampled at
    ``DT_SAMPLES`` per module over the marker and ``DT_PAD`` modules around it, sample (i, j) at module
    (j + 0.5) / S - pad, (i + 0.5) / S - pad."""
    black = np.frombuffer(black_bytes, dtype=np.float64).reshape(M, M)
    S = DT_SAMPLES
    big = np.zeros(((M + 2 * DT_PAD) * S,) * 2, np.uint8)
    big[DT_PAD * S : (DT_PAD + M) * S, DT_PAD * S : (DT_PAD + M) * S] = np.kron(black, np.ones((S, S)))
    dist = cv2.distanceTransform(big, cv2.DIST_L2, 5) + cv2.distanceTransform(1 - big, cv2.DIST_L2, 5)
    out = np.asarray(dist / S, dtype=np.float32)
    out.flags.writeable = False
    return out


# --- kernels ---------------------------------------------------------------------------------------


@inlined
def _apply(H: F64, x: float, y: float) -> tuple[float, float]:  # pragma: no cover - compiled
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    return (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w


@inlined
def _distance_at(dist: NDArray[np.float32], u: float, v: float) -> float:  # pragma: no cover - compiled
    """``_edge_distance_map`` at module (u, v), bilinear (as ``cv2.remap``); 99 off the map."""
    n = dist.shape[0]
    x, y = (u + DT_PAD) * DT_SAMPLES - 0.5, (v + DT_PAD) * DT_SAMPLES - 0.5
    if not (x >= 0.0 and y >= 0.0 and x <= n - 1 and y <= n - 1):
        return 99.0
    i, j = min(int(y), n - 2), min(int(x), n - 2)
    ay, ax = y - i, x - j
    top = dist[i, j] + ax * (dist[i, j + 1] - dist[i, j])
    bottom = dist[i + 1, j] + ax * (dist[i + 1, j + 1] - dist[i + 1, j])
    return float(top + ay * (bottom - top))


@kernel
def _select_pixels(
    roi: NDArray[np.uint8], x0: float, y0: float, lens: F64, H_px: F64, G0: F64, dist: NDArray[np.float32],
    module_px: float, slack_px: float, M: float,
) -> tuple[F64, F64, F64, F64]:  # pragma: no cover - compiled  # fmt: skip
    """The fitted pixels of a region of interest whose top-left pixel is (x0, y0): their pixel coordinates
    (N, 2), normalised coordinates (N, 2), d(normalised)/d(pixel) (N, 2, 2), [normalised axis, pixel axis],
    and grey levels (N,).

    A pixel is kept when its module coordinates through ``G0`` (normalised -> modules) lie within ``MARGIN`` of
    the marker and its edge distance (``dist``, modules) times ``module_px`` is under ``BAND_PX``; the same
    test through ``H_px`` (pixels -> modules, no lens) with ``slack_px`` to spare comes first, so that only
    candidates are undistorted. Undistortion: Newton's method on the lens (``project``), from the previous
    pixel's solution; a pixel where it does not converge is left out.
    """
    h, w = roi.shape
    n_max = h * w
    xy, xn, obs = np.empty((n_max, 2)), np.empty((n_max, 2)), np.empty(n_max)
    jn = np.empty((n_max, 2, 2))
    lo, hi = -MARGIN, M + MARGIN
    slack = slack_px / module_px
    fx, skew, cx, fy, cy = lens[0], lens[1], lens[2], lens[3], lens[4]
    n = 0
    have, xs, ys, pu, pv, ia, ib, ic, id_ = False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(h):
        for j in range(w):
            px, py = x0 + j, y0 + i
            ua, va = _apply(H_px, px, py)
            if not (lo - slack < ua < hi + slack and lo - slack < va < hi + slack):
                continue
            if _distance_at(dist, ua, va) * module_px >= BAND_PX + slack_px:
                continue
            # Newton from the last undistorted pixel moved by its inverse Jacobian (one or two steps), or from
            # the pinhole's inverse.
            if have:
                dx, dy = px - pu, py - pv
                x, y = xs + ia * dx + ib * dy, ys + ic * dx + id_ * dy
            else:
                y = (py - cy) / fy
                x = (px - cx - skew * y) / fx
            found = False
            for _ in range(30):
                u, v, a, b, _z0, c, d, _z1 = project(lens, x, y, 1.0)
                ru, rv = u - px, v - py
                det = a * d - b * c
                if not abs(det) > 1e-12:
                    break
                ia, ib, ic, id_ = d / det, -b / det, -c / det, a / det
                if abs(ru) + abs(rv) < 1e-9:
                    found = True
                    break
                x -= ia * ru + ib * rv
                y -= ic * ru + id_ * rv
            have = found
            if not found:
                continue
            xs, ys, pu, pv = x, y, px, py
            u, v = _apply(G0, x, y)
            if not (lo < u < hi and lo < v < hi) or _distance_at(dist, u, v) * module_px >= BAND_PX:
                continue
            xy[n, 0], xy[n, 1], xn[n, 0], xn[n, 1], obs[n] = px, py, x, y, roi[i, j]
            jn[n, 0, 0], jn[n, 0, 1], jn[n, 1, 0], jn[n, 1, 1] = ia, ib, ic, id_
            n += 1
    return xy[:n].copy(), xn[:n].copy(), jn[:n].copy(), obs[:n].copy()
