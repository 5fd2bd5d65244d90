"""The edge offset of printed markers (black looking thicker or thinner than printed) and its correction.

On real photos the black of a printed marker does not end where the print says: ink spread, the camera's
sharpening and its processing move every black/white edge towards the white by an offset ``delta`` (px; < 0:
black thinner, about -0.15 px on opencv_contrib's ChArUco photos). An edge-based refiner
(``monodock.perception.refine``) then finds the outline ``delta`` outside the true one, and the corners
``delta`` out along both sides.

Why the code's run widths measure it, and the border alone does not: a dilation by ``delta`` widens every black
run of cells by ``2 delta`` and narrows every white one by as much, while an error of the printed grid (cells
not exactly side / M: rasterised boards are ~1.5 % off) or of the module size taken from the corners changes
both in proportion to their length. So per run r of n_r modules, between two interior code edges measured by
the same step fit,

    w_r - w0_r = eps_marker w0_r + 2 s_r delta,     s_r = +1 black, -1 white,

with w0_r the width the corners imply and eps a per-marker scale error; pooled over all runs of all markers by
a Huber-weighted least squares. The outline never enters, so the estimate does not depend on the refined
corners' own offset. The border's inner edge alone reads the print's grid error as an offset and
over-corrects by 0.1-0.2 px (the corner study on opencv_contrib's photos).

Use: ``detection_edge_offset`` per frame (or ``marker_runs`` per marker), ``estimate_edge_offset`` over the
markers of recent frames (ten or so measure it to ~0.01 px on real photos), then ``offset_detection`` with
the estimate as it is: that moves the sides inward by it, which removes the bias. Markers with clipped pixels
(0 or 255) are left out of both: the refiner measures and corrects their edges' shift on its own, and that
shift changes from frame to frame.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.errors import InputError
from monodock.perception.checks import black_cells, check_corners, check_gray
from monodock.perception.detect import Detection, MarkerObservation
from monodock.perception.refine import MAX_REACH_PX, MIN_CLIPPED, MIN_REACH_PX, REACH

__all__ = [
    "EdgeOffset",
    "clipped_roles",
    "detection_edge_offset",
    "estimate_edge_offset",
    "marker_runs",
    "offset_corners",
    "offset_detection",
]

F64 = NDArray[np.float64]

PROFILE_REACH = 0.6  # a profile reaches this fraction of a module either side of the edge, as the refiner's do
SAMPLES = 15  # samples per profile
FIT_STEPS = 8  # Gauss-Newton steps of the step fit (the levels are re-solved at each, so a few more than usual)
MIN_CONTRAST = 40.0  # grey levels: a fitted step flatter than this found no edge
MAX_RESIDUAL = 0.2  # of the contrast: a profile that far from a blurred step holds something else
HUBER = 1.5  # Huber's threshold, in robust standard deviations (MAD) of the runs' residuals
IRLS_STEPS = 10
MIN_RUNS = 10  # runs needed beyond one per marker and one for the offset ...
MIN_PER_COLOUR = 2  # ... with at least this many of each colour: the offset is the black/white difference

# Abramowitz & Stegun 7.1.26: erf to 1.5e-7 (numpy has no erf, and the robot side does not load scipy).
_AS_P = 0.3275911
_AS_A = (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)


@dataclass(frozen=True)
class EdgeOffset:
    """A pooled edge offset: how far every black/white edge appears moved towards the white.

    Attributes:
        offset_px: the offset, px; > 0: black looks thicker than printed, < 0: thinner. Pass it as it is to
            ``offset_detection`` to remove its bias from refined corners.
        sd_px: its standard deviation (standard error), px, robust to the runs' outliers and to their
            correlation within a marker (a cluster-robust sandwich over the markers).
        markers: how many markers contributed runs.
        runs: how many runs were used.
    """

    offset_px: float
    sd_px: float
    markers: int
    runs: int


def marker_runs(
    gray: NDArray[np.uint8],
    corners: NDArray[np.float64],
    camera: CameraModel,
    bits: NDArray[np.integer] | NDArray[np.bool_],
) -> F64:
    """The black and white runs of one marker's code, measured in the image, for ``estimate_edge_offset``.

    A run is a stretch of cells of one colour along a row or a column of the code, between two interior
    edges; each edge is a blurred-step fit to a profile through the middle of its row (column), across the
    grid line where the colour changes. The corners say where the grid lines are (through the lens: the
    marker's homography holds in undistorted normalised coordinates); only the widths the corners imply are
    used, not where they put the edges.

    Args:
        gray: the image, 8-bit single channel, the camera's size.
        corners: the marker's corners (4, 2), pixels, ArUco order TL, TR, BR, BL; the refined ones
            (``monodock.perception.refine``), whose module size is the better.
        camera: the camera that took the image.
        bits: the marker's cells, border included, as ``DockLayout.marker_bits`` gives them: 0 black,
            1 white, shape (M, M), row 0 the side from corner 0 to corner 1.

    Returns:
        One row per run whose two edges were found, shape (R, 4): n modules, sign (+1 black, -1 white),
        measured width px, width the corners imply px.

    Raises:
        InputError: on an image, corners or cells of the wrong form.
    """
    img = check_gray(gray, "edge offset", camera)
    quad = check_corners(corners)
    black = black_cells(bits)
    M = black.shape[0]
    anchors, directions, runs = _code_edges(black)
    if not runs:
        return np.zeros((0, 4))
    G = _homography(np.array([[0.0, 0.0], [M, 0.0], [M, M], [0.0, M]]), camera.normalize(quad))

    def to_px(module_xy: F64) -> F64:
        h = np.c_[module_xy, np.ones(len(module_xy))] @ G.T
        return camera.project(np.c_[h[:, :2] / h[:, 2:], np.ones(len(h))])

    p = to_px(anchors)
    along = to_px(anchors + 0.05 * directions) - p  # the profile's pixel direction: across the grid line
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    module_px = np.linalg.norm(to_px(anchors + 0.5 * directions) - to_px(anchors - 0.5 * directions), axis=1)
    t = np.linspace(-1.0, 1.0, SAMPLES)[None, :] * (PROFILE_REACH * module_px)[:, None]
    x = p[:, None, :] + t[..., None] * along[:, None, :]
    profiles, on_image = _bilinear(img, x)
    e, contrast, rms, free = _fit_steps(t, profiles)
    # The step must go the way the cells say (a fit that found the neighbouring edge goes the other way half
    # the time), be clear of the noise, and not have run into the profile's end.
    up = _edge_polarity(black, anchors, directions)  # +1: white -> black along the profile
    good = on_image & free & (contrast * up > MIN_CONTRAST) & (rms < MAX_RESIDUAL * np.abs(contrast))
    edges = p + e[:, None] * along
    out = [
        [n, sign, float(np.linalg.norm(edges[b] - edges[a])), float(np.linalg.norm(p[b] - p[a]))]
        for a, b, n, sign in runs
        if good[a] and good[b]
    ]
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def estimate_edge_offset(runs_per_marker: Sequence[NDArray[np.float64]]) -> EdgeOffset:
    """The edge offset pooled over many markers' runs (``marker_runs``), by Huber-weighted least squares.

    Each marker gets its own scale error (a print or a module-size error changes its runs in proportion to
    their width), all share one offset; the scale errors are eliminated in closed form per marker
    (Frisch-Waugh-Lovell), so the cost grows with the runs, not with markers squared.

    Args:
        runs_per_marker: one (R, 4) array per marker; empty ones are skipped.

    Returns:
        The pooled offset, its standard deviation and what it was computed from.

    Raises:
        InputError: when the runs are too few to tell the offset from the markers' scale errors.
    """
    groups: list[NDArray[np.intp]] = []
    rows: list[F64] = []
    for runs in runs_per_marker:
        r = np.asarray(runs, dtype=np.float64)
        if r.size == 0:
            continue
        if r.ndim != 2 or r.shape[1] != 4 or not np.isfinite(r).all():
            raise InputError(f"runs must be finite rows of 4 (marker_runs), got an array of shape {r.shape}")
        groups.append(np.full(len(r), len(rows)))
        rows.append(r)
    n_runs = sum(len(r) for r in rows)
    table = np.concatenate(rows) if rows else np.zeros((0, 4))
    colours = min(int(np.sum(table[:, 1] > 0)), int(np.sum(table[:, 1] < 0)))
    if n_runs < len(rows) + 1 + MIN_RUNS or colours < MIN_PER_COLOUR:
        raise InputError(
            f"edge offset: {n_runs} runs from {len(rows)} markers are too few (need {MIN_RUNS} beyond one per "
            f"marker and one for the offset, {MIN_PER_COLOUR} of each colour)"
        )
    g = np.concatenate(groups)
    w0 = table[:, 3]
    y = table[:, 2] - w0
    s2 = 2.0 * table[:, 1]
    weights = np.ones(n_runs)
    for _ in range(IRLS_STEPS):
        offset, xt, residual = _partialled_fit(g, w0, y, s2, weights)
        scale = 1.4826 * float(np.median(np.abs(residual))) + 1e-9
        u = np.abs(residual) / (HUBER * scale)
        last, weights = weights, np.where(u <= 1.0, 1.0, 1.0 / np.maximum(u, 1e-12))
    # The offset above is the fit with the previous weights: its sandwich uses those, with each marker's runs
    # as one cluster (they share the marker's corner and print errors, so they are not independent).
    information = float(np.sum(last * xt * xt))
    score = np.bincount(g, last * xt * residual, minlength=len(rows))
    k = len(rows)
    correction = k / (k - 1) * (n_runs - 1) / (n_runs - k - 1) if k > 1 else n_runs / (n_runs - 2)
    if k > 1:
        variance = correction * float(np.sum(score**2)) / information**2
    else:  # one marker: one cluster says nothing about the spread; take the runs as independent
        variance = correction * float(np.sum((last * xt * residual) ** 2)) / information**2
    return EdgeOffset(offset, math.sqrt(variance), k, n_runs)


def offset_corners(corners: NDArray[np.float64], offset_px: float) -> F64:
    """The corners (4, 2) of the quad whose four sides are moved inward by ``offset_px`` px.

    The sign is that of the estimate (``EdgeOffset.offset_px``), so that passing it as it is removes its bias:
    a black that looks ``offset_px`` thicker put the fitted sides that far outside the true ones, and they
    move back in (``offset_px`` < 0: outward). To add an offset instead, pass its negative.

    Each corner moves along its two sides' normals so that both sides shift by the offset. The sides are
    taken straight in pixels: the lens bends them by well under a pixel over a marker, and the shift is a
    fraction of a pixel, so what that leaves out is of the order of 1e-3 px.

    Args:
        corners: the corners (4, 2), pixels, in order around the quad (either way round).
        offset_px: the edge offset, px.

    Raises:
        InputError: on corners that are not 4 finite points of a proper quad.
    """
    c = check_corners(corners)
    # Inward normals whatever the winding: the shoelace sign says which side of each edge the quad lies on.
    area2 = float(np.dot(c[:, 0], np.roll(c[:, 1], -1)) - np.dot(c[:, 1], np.roll(c[:, 0], -1)))
    side = np.roll(c, -1, axis=0) - c  # side k: corner k -> k + 1
    length = np.linalg.norm(side, axis=1)
    if area2 == 0.0 or not np.all(length > 0):
        raise InputError("offset_corners needs a proper quad, got a degenerate one")
    inward = np.sign(area2) * np.c_[-side[:, 1], side[:, 0]] / length[:, None]
    out = np.empty((4, 2))
    for k in range(4):
        # Corner k lies on sides k - 1 and k; on the moved lines n . (q - c_k) = offset for both normals.
        A = np.array([inward[k - 1], inward[k]])
        if abs(float(np.linalg.det(A))) < 1e-9:
            raise InputError("offset_corners needs a proper quad, got one with two adjacent sides in line")
        out[k] = c[k] + np.linalg.solve(A, np.array([offset_px, offset_px]))
    return out


def offset_detection(detection: Detection, offset_px: float, *, skip: Collection[str] = ()) -> Detection:
    """A new detection with each refined marker's corners moved by ``offset_corners``.

    Roles in ``detection.unrefined`` keep their corners: they are OpenCV's, whose error is not the edge
    offset. Pass ``skip=clipped_roles(gray, detection, modules=layout.modules)`` to leave the clipped markers
    too: the refiner's own correction of their edges already took the offset out.

    Args:
        detection: as ``refine_detection`` returned it.
        offset_px: the estimated edge offset (``EdgeOffset.offset_px``), px, as it is.
        skip: roles to leave as they are.
    """
    observations = dict(detection.observations)
    for role, o in detection.observations.items():
        if role in detection.unrefined or role in skip:
            continue
        observations[role] = MarkerObservation(o.role, o.marker_id, offset_corners(o.corners, offset_px))
    return replace(detection, observations=observations)


def clipped_roles(gray: NDArray[np.uint8], detection: Detection, *, modules: int = 6) -> tuple[str, ...]:
    """The roles whose markers have clipped pixels (0 or 255) near their outline.

    A marker that has them got its edges' clipping shift corrected by the refiner, and that shift is of the
    frame, not of the print. The test is the refiner's (``MIN_CLIPPED`` clipped samples on its profiles
    across the outline, which reach ``REACH`` of the border width either side), counted on the pixels of that
    band plus a pixel, corners included: it errs towards calling a marker clipped.

    Args:
        gray: the image the detection was made on.
        detection: the detection.
        modules: the marker's width in modules, border included (``DockLayout.modules``), as for the refiner.
    """
    img = check_gray(gray, "edge offset")
    out = []
    for role, o in detection.observations.items():
        c = np.asarray(o.corners, dtype=np.float64)
        if c.shape != (4, 2) or not np.isfinite(c).all():
            continue
        if _clipped_near_outline(img, c, modules):
            out.append(role)
    return tuple(out)


def detection_edge_offset(
    gray: NDArray[np.uint8], detection: Detection, camera: CameraModel, layout: DockLayout
) -> list[F64]:
    """The runs (``marker_runs``) of every refined, unclipped marker of a detection, one array per marker.

    Args:
        gray: the image the detection was made on.
        detection: as ``refine_detection`` returned it (its ``unrefined`` roles are left out).
        camera: the camera that took the image.
        layout: the dock layout, for each marker's cells.

    Returns:
        The markers' runs, for ``estimate_edge_offset`` (pooled with other frames' as they come).
    """
    clipped = set(clipped_roles(gray, detection, modules=layout.modules))
    out = []
    for role, o in detection.observations.items():
        if role in detection.unrefined or role in clipped:
            continue
        runs = marker_runs(gray, o.corners, camera, layout.marker_bits(o.marker_id))
        if len(runs):
            out.append(runs)
    return out


# --- helpers ---------------------------------------------------------------------------------------


def _code_edges(black: F64) -> tuple[F64, F64, list[tuple[int, int, int, float]]]:
    """The interior code edges and the runs between them.

    Returns the edges' anchors (E, 2) and profile directions (E, 2), module coordinates (u right, v down;
    the anchor on the grid line, in the middle of its row or column), and the runs as (edge a, edge b,
    n modules, sign +1 black / -1 white). The border's outer edge is not used: it is where the corners are.
    """
    M = black.shape[0]
    anchors: list[tuple[float, float]] = []
    directions: list[tuple[float, float]] = []
    runs: list[tuple[int, int, int, float]] = []
    for axis in (0, 1):  # 0: along u in row j, 1: along v in column j
        for j in range(1, M - 1):
            line = black[j, :] if axis == 0 else black[:, j]
            changes = [i for i in range(1, M) if line[i] != line[i - 1]]
            first = len(anchors)
            for i in changes:
                anchors.append((float(i), j + 0.5) if axis == 0 else (j + 0.5, float(i)))
                directions.append((1.0, 0.0) if axis == 0 else (0.0, 1.0))
            for k in range(len(changes) - 1):
                n = changes[k + 1] - changes[k]
                runs.append((first + k, first + k + 1, n, 1.0 if line[changes[k]] > 0.5 else -1.0))
    return np.array(anchors, dtype=np.float64).reshape(-1, 2), np.array(directions).reshape(-1, 2), runs


def _edge_polarity(black: F64, anchors: F64, directions: F64) -> F64:
    """+1 where the profile (along ``directions``) goes from white to black, -1 from black to white."""
    before = anchors - 0.5 * directions
    after = anchors + 0.5 * directions
    b = black[before[:, 1].astype(int), before[:, 0].astype(int)]
    a = black[after[:, 1].astype(int), after[:, 0].astype(int)]
    return np.asarray(a - b, dtype=np.float64)


def _homography(src: F64, dst: F64) -> F64:
    """The 3x3 H (h33 = 1) with H src_k ~ dst_k for 4 point pairs, in float64 (cv2's wants float32)."""
    A = np.zeros((8, 8))
    b = np.zeros(8)
    for k in range(4):
        x, y = src[k]
        u, v = dst[k]
        A[2 * k] = (x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y)
        A[2 * k + 1] = (0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y)
        b[2 * k], b[2 * k + 1] = u, v
    try:
        h = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        raise InputError("marker corners are degenerate (three in line)") from None
    return np.append(h, 1.0).reshape(3, 3)


def _bilinear(img: NDArray[np.uint8], x: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Bilinear samples (P, T) of the image at pixels x (P, T, 2), and which profiles lie wholly on it.

    In float64, not ``cv2.remap``: that rounds positions to 1/32 px, a bias of a few hundredths on a width
    that should be good to a few thousandths.
    """
    h, w = img.shape
    u, v = x[..., 0], x[..., 1]
    on = np.all((u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1), axis=1)
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    u0 = np.minimum(np.floor(u).astype(np.intp), w - 2)
    v0 = np.minimum(np.floor(v).astype(np.intp), h - 2)
    au, av = u - u0, v - v0
    f = img.astype(np.float64)
    top = f[v0, u0] + au * (f[v0, u0 + 1] - f[v0, u0])
    bottom = f[v0 + 1, u0] + au * (f[v0 + 1, u0 + 1] - f[v0 + 1, u0])
    return top + av * (bottom - top), np.asarray(on)


def _erf(x: F64) -> F64:
    s = np.sign(x)
    a = np.abs(x)
    k = 1.0 / (1.0 + _AS_P * a)
    poly = k * (_AS_A[0] + k * (_AS_A[1] + k * (_AS_A[2] + k * (_AS_A[3] + k * _AS_A[4]))))
    return np.asarray(s * (1.0 - poly * np.exp(-a * a)))


def _fit_steps(t: F64, profiles: F64) -> tuple[F64, F64, F64, NDArray[np.bool_]]:
    """Blurred-step fits I = B (1 - Phi((t - e) / s)) + D Phi((t - e) / s), one per row of ``profiles``.

    The levels B (towards t -> -inf) and D by linear least squares at each step, Gauss-Newton on the edge e
    and the blur s with the levels held. Up and down steps alike: the sign of B - D says which it was.

    Returns:
        e (px along t), contrast B - D, rms residual, and whether e stayed off its bounds, each (P,).
    """
    P = profiles.shape[0]
    # Start at the centroid of the absolute intensity change: the edge is where the profile changes most.
    change = np.abs(np.diff(profiles, axis=1))
    middle = 0.5 * (t[:, 1:] + t[:, :-1])
    e = (change * middle).sum(1) / np.maximum(change.sum(1), 1e-9)
    s = np.full(P, 0.5)
    limit = 0.8 * np.abs(t[:, -1] - t[:, 0]) / 2.0
    B = D = r = np.zeros(P)
    for _ in range(FIT_STEPS):
        z = (t - e[:, None]) / s[:, None]
        F = 0.5 * (1.0 + _erf(z / math.sqrt(2.0)))
        f = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
        a11, a12, a22 = ((1 - F) ** 2).sum(1), ((1 - F) * F).sum(1), (F**2).sum(1)
        b1, b2 = ((1 - F) * profiles).sum(1), (F * profiles).sum(1)
        det = a11 * a22 - a12**2 + 1e-12
        B = (a22 * b1 - a12 * b2) / det
        D = (a11 * b2 - a12 * b1) / det
        r = profiles - (B[:, None] * (1 - F) + D[:, None] * F)
        amp = (D - B)[:, None]
        je = -amp * f / s[:, None]  # d model / d e
        js = -amp * f * z / s[:, None]  # d model / d s
        h11, h12, h22 = (je * je).sum(1), (je * js).sum(1), (js * js).sum(1)
        g1, g2 = (je * r).sum(1), (js * r).sum(1)
        dt = h11 * h22 - h12**2 + 1e-12
        e = np.clip(e + (h22 * g1 - h12 * g2) / dt, -limit, limit)
        s = np.clip(s + (h11 * g2 - h12 * g1) / dt, 0.05, limit)
    rms = np.sqrt((r**2).mean(1))
    return e, B - D, rms, np.asarray(np.abs(e) < limit)


def _partialled_fit(g: NDArray[np.intp], w0: F64, y: F64, s2: F64, weights: F64) -> tuple[float, F64, F64]:
    """The weighted fit of y = eps_g w0 + offset s2: the offset, the regressor s2 with each marker's w0
    partialled out, and the residuals (which are the full fit's)."""
    sxx = np.bincount(g, weights * w0 * w0)
    ay = np.bincount(g, weights * w0 * y) / sxx
    a_s = np.bincount(g, weights * w0 * s2) / sxx
    yt = y - w0 * ay[g]
    xt = s2 - w0 * a_s[g]
    offset = float(np.sum(weights * xt * yt) / np.sum(weights * xt * xt))
    return offset, xt, yt - xt * offset


def _clipped_near_outline(img: NDArray[np.uint8], corners: F64, modules: int) -> bool:
    """Whether ``MIN_CLIPPED`` pixels at 0 or 255 lie within the refiner's profile reach (and a pixel, for the
    bilinear samples' neighbours) of the outline."""
    side = float(np.mean(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)))
    reach = 1.0 + min(max(REACH * side / modules, MIN_REACH_PX), MAX_REACH_PX)
    h, w = img.shape
    lo = np.maximum(np.floor(corners.min(axis=0) - reach).astype(int), 0)
    hi = np.minimum(np.ceil(corners.max(axis=0) + reach).astype(int), (w - 1, h - 1))
    if np.any(hi < lo):
        return False
    roi = img[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1]
    ys, xs = np.nonzero((roi == 0) | (roi == 255))
    if len(xs) < MIN_CLIPPED:
        return False
    q = np.c_[xs + lo[0], ys + lo[1]].astype(np.float64)
    a = corners
    d = np.roll(corners, -1, axis=0) - a
    # Distance of each clipped pixel to each side (a segment), the nearest of the four.
    rel = q[:, None, :] - a[None, :, :]
    tt = np.clip(np.sum(rel * d[None], axis=2) / np.sum(d * d, axis=1)[None], 0.0, 1.0)
    dist = np.linalg.norm(rel - tt[..., None] * d[None], axis=2).min(axis=1)
    return int(np.sum(dist <= reach)) >= MIN_CLIPPED
