"""Intrinsic camera calibration from checkerboard views: fx, fy, cx, cy and plumb_bob distortion.

The papers (§4.1) calibrate with an 8x6 checkerboard. Board sizes follow OpenCV's pattern-size convention:
"8x6" means 8 inner corners along a row and 6 down a column (9 x 7 squares). Each view is checked (board
found, sharp, wholly in the image) before ``cv2.calibrateCamera`` sees it, views whose reprojection error
stands far out are dropped once and the rest recalibrated, and the result says how well the corners covered
the image: a calibration from views that never reach the image corners extrapolates the distortion there.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.errors import InputError

__all__ = [
    "DEFAULT_MAX_BLUR_PX",
    "IntrinsicsResult",
    "ViewResult",
    "calibrate_intrinsics",
    "find_board",
    "parse_board",
    "select_frames",
    "summary",
]

DEFAULT_MAX_BLUR_PX = 4.0  # 10-90 % edge width; OpenCV calls < ~3 px sharp, a cheap webcam's views sit near 2.5
COVERAGE_GRID = (8, 6)  # cells across and down the image
_MIN_COVERAGE = 0.7
_FEW_VIEWS = 10
_OUTLIER_FACTOR = 3.0  # a view is an outlier above this many times the median per-view RMS ...
_OUTLIER_FLOOR_PX = 0.5  # ... and above this absolute error
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
_CALIB_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-12)
_BORDER_PX = 2.0  # corners closer than this to the image border are not trusted


@dataclass(frozen=True)
class ViewResult:
    """What became of one image: used, or why not, and its reprojection error.

    Attributes:
        name: the image's name (file name, or file and frame index).
        used: whether the calibration used it.
        reason: why it was not used ("" when used).
        rms_px: its RMS reprojection error with the final calibration, pixels (NaN when the board was not found).
        corners: the detected inner corners, shape (N, 2), or None.
        sharpness_px: the board's edge width (10-90 %), pixels (NaN when not measured).
    """

    name: str
    used: bool
    reason: str = ""
    rms_px: float = math.nan
    corners: NDArray[np.float64] | None = field(default=None, repr=False, compare=False)
    sharpness_px: float = math.nan


@dataclass(frozen=True)
class IntrinsicsResult:
    """A calibrated camera and the evidence of how good it is.

    Attributes:
        camera: the calibrated camera (plumb_bob, 5 coefficients k1 k2 p1 p2 k3).
        rms_px: overall RMS reprojection error over the used views, pixels.
        views: one entry per input image, in input order.
        coverage: corners per cell of a grid over the image, shape (rows, cols) of ``COVERAGE_GRID``.
        coverage_fraction: share of the grid's cells with at least one corner.
        warnings: things the user should fix (poor coverage, few views, outliers), one line each.
        board: (cols, rows) inner corners.
        square: square side, metres.
    """

    camera: CameraModel
    rms_px: float
    views: tuple[ViewResult, ...]
    coverage: NDArray[np.int64] = field(repr=False, compare=False)
    coverage_fraction: float
    warnings: tuple[str, ...]
    board: tuple[int, int]
    square: float

    @property
    def used(self) -> int:
        """Number of views the calibration used."""
        return sum(1 for v in self.views if v.used)


def parse_board(text: str) -> tuple[int, int]:
    """The (cols, rows) inner corners of a "COLSxROWS" board spec such as "8x6"; InputError when malformed."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise InputError(f"--board must be COLSxROWS inner corners, e.g. 8x6, got '{text}'")
    cols, rows = int(parts[0]), int(parts[1])
    if cols < 3 or rows < 3:
        raise InputError(f"--board needs at least 3x3 inner corners, got '{text}'")
    return cols, rows


def _gray(image: NDArray[np.generic]) -> NDArray[np.uint8]:
    """An 8-bit single-channel copy of a mono, BGR or BGRA image of any depth."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        lo, hi = float(f.min()), float(f.max())
        img = np.rint((f - lo) * (255.0 / max(hi - lo, 1e-12))).astype(np.uint8)
    return np.ascontiguousarray(img, dtype=np.uint8)


def _min_spacing(corners: NDArray[np.float64], board: tuple[int, int]) -> float:
    """The smallest distance between neighbouring corners along rows and columns, pixels."""
    cols, rows = board
    g = corners.reshape(rows, cols, 2)
    d_row = np.linalg.norm(np.diff(g, axis=1), axis=2)
    d_col = np.linalg.norm(np.diff(g, axis=0), axis=2)
    return float(min(d_row.min(), d_col.min()))


def find_board(
    image: NDArray[np.generic],
    board: tuple[int, int],
    *,
    max_blur_px: float = DEFAULT_MAX_BLUR_PX,
) -> tuple[NDArray[np.float64] | None, str]:
    """Sub-pixel inner corners of a checkerboard in an image, or None and why not.

    The classic detector with ``cornerSubPix`` (window sized to the corner spacing) is tried first: on sharp
    views its corners are about twice as accurate as ``findChessboardCornersSB``'s, which is the fallback for
    hard views. A found board is then checked for sharpness (``cv2.estimateChessboardSharpness``: the 10-90 %
    width of the edges) and for corners on the image border.

    Args:
        image: mono, BGR or BGRA pixels.
        board: (cols, rows) inner corners.
        max_blur_px: views whose edges are wider than this are rejected as blurred.

    Returns:
        Corners, shape (cols * rows, 2), row by row, and "" ; or None and the reason ("board not found",
        "partial view: ...", "blurred: ...").
    """
    gray = _gray(image)
    n = board[0] * board[1]
    corners: NDArray[np.float64] | None = None
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    ok, found = cv2.findChessboardCorners(gray, board, flags=flags)
    if ok and found is not None and len(found) == n:
        c0 = np.asarray(found, dtype=np.float32).reshape(-1, 1, 2)
        half = int(np.clip(0.3 * _min_spacing(c0.reshape(-1, 2).astype(np.float64), board), 2, 11))
        refined = cv2.cornerSubPix(gray, c0.copy(), (half, half), (-1, -1), _SUBPIX_CRITERIA)
        moved = np.linalg.norm(np.asarray(refined, dtype=np.float64).reshape(-1, 2) - c0.reshape(-1, 2), axis=1)
        # A corner that wandered off towards a neighbour means the window caught another edge: not trusted.
        if float(moved.max()) < max(1.5, 0.5 * half):
            corners = np.asarray(refined, dtype=np.float64).reshape(-1, 2)
    if corners is None:
        sb_flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, found = cv2.findChessboardCornersSB(gray, board, flags=sb_flags)
        if ok and found is not None and len(found) == n:
            corners = np.asarray(found, dtype=np.float64).reshape(-1, 2)
    if corners is None:
        # Part of a board (any 3x3 inner corners or more) means the view is cut, not that there is no board.
        ok, part = cv2.findChessboardCornersSB(gray, (3, 3), flags=cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok and part is not None and 0 < len(part) < n:
            pts = np.asarray(part, dtype=np.float64).reshape(-1, 2)
            step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
            h, w = gray.shape
            to_border = float(min(pts[:, 0].min(), pts[:, 1].min(), w - 1 - pts[:, 0].max(), h - 1 - pts[:, 1].max()))
            if to_border < 3.0 * step:
                return None, f"partial view: only {len(part)} of {n} corners inside the image"
            return None, f"board not found: only {len(part)} of {n} corners detected"
        return None, "board not found"
    h, w = gray.shape
    if np.any((corners < _BORDER_PX) | (corners > np.array([w - 1, h - 1]) - _BORDER_PX)):
        return None, "partial view: corners on the image border"
    sharp = _sharpness(gray, board, corners)
    if sharp > max_blur_px:
        return None, f"blurred: sharpness {sharp:.1f} px > limit {max_blur_px:g} px"
    return corners, ""


def _sharpness(gray: NDArray[np.uint8], board: tuple[int, int], corners: NDArray[np.float64]) -> float:
    """The board's mean 10-90 % edge width, pixels (0 when OpenCV cannot measure it)."""
    try:
        value = cv2.estimateChessboardSharpness(gray, board, corners.astype(np.float32).reshape(-1, 1, 2))
    except cv2.error:
        return 0.0
    s = float(np.asarray(value[0], dtype=np.float64).ravel()[0])
    return s if math.isfinite(s) else 0.0


def _object_points(board: tuple[int, int], square: float) -> NDArray[np.float32]:
    """Inner corners in the board's frame, row by row, shape (cols * rows, 3)."""
    cols, rows = board
    i, j = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.stack([i.ravel() * square, j.ravel() * square, np.zeros(cols * rows)], axis=1).astype(np.float32)


def _coverage(corner_sets: Iterable[NDArray[np.float64]], size: tuple[int, int]) -> NDArray[np.int64]:
    """Corners per cell of the ``COVERAGE_GRID`` over an image of ``size`` (width, height), shape (rows, cols)."""
    gc, gr = COVERAGE_GRID
    w, h = size
    grid = np.zeros((gr, gc), dtype=np.int64)
    for c in corner_sets:
        col = np.clip((c[:, 0] / w * gc).astype(np.intp), 0, gc - 1)
        row = np.clip((c[:, 1] / h * gr).astype(np.intp), 0, gr - 1)
        np.add.at(grid, (row, col), 1)
    return grid


def _reason_summary(views: Iterable[ViewResult]) -> str:
    """Rejection reasons counted by kind, e.g. "board not found x5, blurred x1"."""
    counts = Counter(v.reason.split(":")[0] for v in views if not v.used)
    return ", ".join(f"{k} x{n}" for k, n in counts.most_common())


def _calibrate(
    obj: NDArray[np.float32], corner_sets: list[NDArray[np.float64]], size: tuple[int, int]
) -> tuple[float, NDArray[np.float64], NDArray[np.float64], list[float]]:
    """calibrateCamera over the views: overall RMS, K, D (5) and each view's RMS reprojection error."""
    img_pts = [c.astype(np.float32).reshape(-1, 1, 2) for c in corner_sets]
    obj_pts = [obj.reshape(-1, 1, 3)] * len(img_pts)
    rms, K, D, rvecs, tvecs = cv2.calibrateCamera(obj_pts, img_pts, size, None, None, criteria=_CALIB_CRITERIA)
    D = np.asarray(D, dtype=np.float64).ravel()[:5]
    per_view = []
    for c, r, t in zip(corner_sets, rvecs, tvecs, strict=True):
        px, _ = cv2.projectPoints(obj, r, t, K, D)
        per_view.append(float(np.sqrt(np.mean(np.sum((px.reshape(-1, 2) - c) ** 2, axis=1)))))
    return float(rms), np.asarray(K, dtype=np.float64), D, per_view


def _detect_views(
    views: Iterable[tuple[str, NDArray[np.generic]]],
    board: tuple[int, int],
    size: tuple[int, int] | None,
    max_blur_px: float,
) -> tuple[list[ViewResult], tuple[int, int] | None]:
    """Find the board in each view, checking every image has ``size`` (default: the first image's)."""
    results: list[ViewResult] = []
    for view_name, image in views:
        h, w = np.asarray(image).shape[:2]
        if size is None:
            size = (int(w), int(h))
        elif (w, h) != size:
            raise InputError(f"{view_name}: image size {w}x{h} differs from {size[0]}x{size[1]} of the other images")
        corners, reason = find_board(image, board, max_blur_px=max_blur_px)
        results.append(ViewResult(view_name, corners is not None, reason, corners=corners))
    return results, size


def _usable_views(results: list[ViewResult], board: tuple[int, int], min_views: int) -> list[int]:
    """Indices of the views where the board was found; refused when fewer than ``min_views``."""
    cols, rows = board
    n_images = len(results)
    usable = [k for k, r in enumerate(results) if r.corners is not None]
    if not usable:
        raise InputError(f"checkerboard {cols}x{rows} never found in {n_images} images: {_reason_summary(results)}")
    if len(usable) < min_views:
        raise InputError(
            f"only {len(usable)} usable checkerboard {cols}x{rows} views in {n_images} images, need at least "
            f"{min_views}: {_reason_summary(results)}"
        )
    return usable


def _calibrate_without_outliers(
    obj: NDArray[np.float32], sets: dict[int, NDArray[np.float64]], size: tuple[int, int], min_views: int
) -> tuple[float, NDArray[np.float64], NDArray[np.float64], set[int], float]:
    """Calibrate, then again without the views far above the median error: RMS, K, D, outliers and the limit."""
    rms, K, D, per_view = _calibrate(obj, list(sets.values()), size)
    limit = max(_OUTLIER_FACTOR * float(np.median(per_view)), _OUTLIER_FLOOR_PX)
    outliers = {k for k, e in zip(sets, per_view, strict=True) if e > limit}
    # Leaving the outliers out must still leave enough views; otherwise keep them all.
    if outliers and len(sets) - len(outliers) >= min_views:
        rms, K, D, _ = _calibrate(obj, [c for k, c in sets.items() if k not in outliers], size)
    else:
        outliers = set()
    return rms, K, D, outliers, limit


def _final_views(
    results: list[ViewResult],
    obj: NDArray[np.float32],
    K: NDArray[np.float64],
    D: NDArray[np.float64],
    outliers: set[int],
    limit: float,
) -> list[ViewResult]:
    """The views with their reprojection errors under the final camera, outliers marked as not used."""
    final: list[ViewResult] = []
    for k, r in enumerate(results):
        if r.corners is None:
            final.append(r)
            continue
        # Every view's error with the final camera (outliers included), from its own best pose.
        _, rvec, tvec = cv2.solvePnP(obj, r.corners.astype(np.float32), K, D)
        px, _ = cv2.projectPoints(obj, rvec, tvec, K, D)
        e = float(np.sqrt(np.mean(np.sum((px.reshape(-1, 2) - r.corners) ** 2, axis=1))))
        if k in outliers:
            final.append(ViewResult(r.name, False, f"outlier: reprojection {e:.2f} px > {limit:.2f} px", e, r.corners))
        else:
            final.append(ViewResult(r.name, True, "", e, r.corners))
    return final


def _calibration_warnings(fraction: float, n_used: int, results: list[ViewResult], outliers: set[int]) -> list[str]:
    """Warnings on a weak calibration: poor corner coverage, few views used, views left out as outliers."""
    warnings: list[str] = []
    if fraction < _MIN_COVERAGE:
        warnings.append(
            f"corners cover only {fraction:.0%} of the image ({COVERAGE_GRID[0]}x{COVERAGE_GRID[1]} grid); "
            "add views with the board near the image edges and corners, where the distortion is strongest"
        )
    if n_used < _FEW_VIEWS:
        warnings.append(f"only {n_used} views used; 15-25 views at varied tilts give a stable calibration")
    for k in sorted(outliers):
        warnings.append(
            f"{results[k].name}: left out, reprojection error far above the others (board moved, bent or misdetected?)"
        )
    return warnings


def calibrate_intrinsics(
    views: Iterable[tuple[str, NDArray[np.generic]]],
    board: tuple[int, int],
    square: float,
    *,
    image_size: tuple[int, int] | None = None,
    max_blur_px: float = DEFAULT_MAX_BLUR_PX,
    min_views: int = 5,
    name: str = "camera",
) -> IntrinsicsResult:
    """Calibrate a camera's intrinsics from named checkerboard images.

    Args:
        views: (name, image) pairs; images are consumed one at a time, only their corners are kept.
        board: (cols, rows) inner corners, e.g. (8, 6).
        square: side of a square, metres (scales nothing in the intrinsics, but the poses and errors are metric).
        image_size: (width, height) every image must have (default: the first image's).
        max_blur_px: views with wider edges are rejected as blurred.
        min_views: fewest usable views to calibrate from.
        name: the camera_name written in the camera_info file.

    Returns:
        The calibrated camera with per-view results, corner coverage and warnings.

    Raises:
        InputError: images of different sizes, no view with the board, fewer than ``min_views`` usable views.
    """
    if not square > 0:
        raise InputError(f"--square must be a positive length in metres, got {square}")
    results, size = _detect_views(views, board, image_size, max_blur_px)
    if size is None or len(results) == 0:
        raise InputError("no images to calibrate from")
    usable = _usable_views(results, board, min_views)
    obj = _object_points(board, square)
    sets = {k: c for k in usable if (c := results[k].corners) is not None}
    rms, K, D, outliers, limit = _calibrate_without_outliers(obj, sets, size, min_views)
    final = _final_views(results, obj, K, D, outliers, limit)
    used_sets = [r.corners for r in final if r.used and r.corners is not None]
    coverage = _coverage(used_sets, size)
    fraction = float(np.count_nonzero(coverage)) / coverage.size
    warnings = _calibration_warnings(fraction, len(used_sets), results, outliers)
    camera = CameraModel.from_intrinsics(size[0], size[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2], D, name=name)
    return IntrinsicsResult(camera, rms, tuple(final), coverage, fraction, tuple(warnings), board, float(square))


def _descriptor(corners: NDArray[np.float64], board: tuple[int, int], size: tuple[int, int]) -> NDArray[np.float64]:
    """Where, how big and how tilted a board appears: centre (fractions), scale, and two side-length ratios."""
    cols, rows = board
    w, h = size
    g = corners.reshape(rows, cols, 2)
    centre = corners.mean(axis=0) / np.array([w, h])
    top, bottom = float(np.linalg.norm(g[0, -1] - g[0, 0])), float(np.linalg.norm(g[-1, -1] - g[-1, 0]))
    left, right = float(np.linalg.norm(g[-1, 0] - g[0, 0])), float(np.linalg.norm(g[-1, -1] - g[0, -1]))
    scale = math.sqrt(float(cv2.contourArea(np.array([g[0, 0], g[0, -1], g[-1, -1], g[-1, 0]], np.float32)))) / w
    tilt_x = math.log(max(top, 1e-6) / max(bottom, 1e-6))
    tilt_y = math.log(max(left, 1e-6) / max(right, 1e-6))
    return np.array([centre[0], centre[1], 2.0 * scale, abs(tilt_x), abs(tilt_y)])


def select_frames(
    frames: Iterable[tuple[str, NDArray[np.generic]]],
    board: tuple[int, int],
    *,
    max_views: int = 25,
    max_blur_px: float = DEFAULT_MAX_BLUR_PX,
    novelty: float = 0.08,
    pool: int = 200,
) -> list[tuple[str, NDArray[np.generic]]]:
    """Pick up to ``max_views`` views of a video or recording that suit calibration, in their original order.

    Keeps frames where the board is found and sharp and whose pose differs from every frame kept so far (board
    centre, scale and tilt, by ``novelty``; at most ``pool`` candidates), then picks greedily the one that adds
    the most new coverage cells, with ties going to the most distinct pose.
    """
    cands: list[tuple[int, str, NDArray[np.generic], NDArray[np.float64], NDArray[np.int64]]] = []
    for index, (name, image) in enumerate(frames):
        if len(cands) >= pool:
            break
        corners, _ = find_board(image, board, max_blur_px=max_blur_px)
        if corners is None:
            continue
        h, w = np.asarray(image).shape[:2]
        d = _descriptor(corners, board, (int(w), int(h)))
        if cands and min(float(np.linalg.norm(d - c[3])) for c in cands) < novelty:
            continue
        cells = (_coverage([corners], (int(w), int(h))) > 0).astype(np.int64)
        cands.append((index, name, image, d, cells))
    chosen: list[int] = []
    covered = np.zeros((COVERAGE_GRID[1], COVERAGE_GRID[0]), dtype=np.int64)
    while cands and len(chosen) < min(max_views, len(cands)):
        best, best_score = -1, -math.inf
        for k, (_, _, _, d, cells) in enumerate(cands):
            if k in chosen:
                continue
            gain = int(np.count_nonzero(cells & (covered == 0)))
            distinct = min((float(np.linalg.norm(d - cands[j][3])) for j in chosen), default=1.0)
            score = gain + distinct
            if score > best_score:
                best, best_score = k, score
        chosen.append(best)
        covered |= cands[best][4]
    return [(cands[k][1], cands[k][2]) for k in sorted(chosen, key=lambda k: cands[k][0])]


def summary(result: IntrinsicsResult) -> str:
    """A few lines for the terminal: RMS, intrinsics, distortion, views used and rejected, coverage."""
    c = result.camera
    k1, k2, p1, p2, k3 = c.D
    rejected = [v for v in result.views if not v.used]
    lines = [
        f"checkerboard {result.board[0]}x{result.board[1]}, square {result.square:g} m: "
        f"{result.used}/{len(result.views)} views used, RMS {result.rms_px:.3f} px",
        f"fx {c.fx:.2f}  fy {c.fy:.2f}  cx {c.cx:.2f}  cy {c.cy:.2f}  ({c.width}x{c.height})",
        f"k1 {k1:.5f}  k2 {k2:.5f}  k3 {k3:.5f}  p1 {p1:.6f}  p2 {p2:.6f}",
        f"coverage {result.coverage_fraction:.0%} of the image",
    ]
    lines += [f"  rejected {v.name}: {v.reason}" for v in rejected[:10]]
    if len(rejected) > 10:
        lines.append(f"  ... and {len(rejected) - 10} more rejected ({_reason_summary(rejected)})")
    return "\n".join(lines)
