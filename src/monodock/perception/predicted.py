"""Markers where ArUco gives up: find a marker the detector missed where the dock track predicts it, and keep it
only when its code reads.

Once the dock has been seen, the mission knows where it is (the dock filter, carried forward by odometry), so it
knows where each marker must appear in the next image, within the prediction's uncertainty. Under heavy motion
blur, at long range or in glare, OpenCV's detector loses markers whose cells are still there to see: it needs a
clean contour and a binarised code, which a 6 px streak or a 3 px cell does not give it. Here, for each marker the
detector missed:

1. its corners are projected from the predicted pose (the DockPose in base_link), and the search radius from the
   pose's covariance (3 sigma of the corners' pixel spread, clipped to ``SEARCH_PX``);
2. a template of the expected marker (its cells and a quiet zone of white, warped into the predicted quad,
   blurred) is matched over the window (normalised cross-correlation): a translation, which the prediction's
   error mostly is;
3. from there ``monodock.perception.marker_fit.fit_marker`` fits the whole printed pattern to the pixels (the
   corners, the blur and the edge offset), falling back to the edge refiner (``perception.refine``);
4. the fit is verified: the cells are sampled through the homography of the fitted corners, the border must be
   black, the code must read as the expected id within ``MAX_HAMMING`` bits and be nearer it than any other id
   of the dictionary in any rotation, and the fit's corners must not have left the search window. A marker that
   is not there (covered, out of view, another id) fails this and is not returned.

The recovered markers are returned as ``MarkerObservation``s in the detection, exactly as the detector's, so every
geometric method uses them unchanged; the detector's own observations are never touched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.perception.detect import Detection, MarkerObservation
from monodock.perception.marker_fit import fit_marker
from monodock.perception.refine import refine_marker

__all__ = ["PredictedMarkers", "Prior", "predict_corners"]

F64 = NDArray[np.float64]

SEARCH_PX = (4.0, 30.0)  # the search radius's floor and ceiling, px
SIGMAS = 3.0  # the radius is this many sigmas of the predicted corners' spread
MIN_MODULE_PX = 1.8  # a marker whose cells are smaller than this in the prediction is not searched for
EDGE_MARGIN_PX = 3.0  # ... nor one whose predicted corners lie nearer the image's border than this
TEMPLATE_BLUR_PX = 1.5  # sigma of the template's blur (the detector misses blurred markers: match them blurred)
MIN_MATCH = 0.55  # normalised cross-correlation the template must reach
MAX_HAMMING = 1  # code bits that may read wrong
MIN_OTHER_MARGIN = 2  # ... and every other id (any rotation) must read at least this many bits further off
MIN_CONTRAST = 20.0  # grey levels between the border's black and the code's white
CELL_SAMPLES = 3  # samples a side in each cell's centre ...
CELL_CORE = 0.4  # ... spread over this fraction of the cell
DEFAULT_SIGMA = (0.03, 0.03, math.radians(2.0))  # prior's sigma when no covariance is given: x, y (m), yaw (rad)


@dataclass(frozen=True)
class Prior:
    """A predicted pose of the dock at a frame's exposure: the DockPose in base_link and its 3x3 covariance
    (x m, y m, yaw rad), or None for ``DEFAULT_SIGMA``."""

    pose: DockPose
    covariance: F64 | None = None


def predict_corners(camera: CameraModel, layout: DockLayout, robot: RobotConfig, pose: DockPose) -> dict[str, F64]:
    """Each marker's corners (4, 2) in pixels for the dock at ``pose`` (ArUco order); NaN behind the camera."""
    optical_T_dock = transforms.invert(robot.base_T_optical()) @ pose.matrix()
    out = {}
    for role in layout.roles:
        p = transforms.apply(optical_T_dock, layout.corners_in_dock(role))
        px = camera.project(p)
        px[p[:, 2] <= 1e-3] = np.nan
        out[role] = px
    return out


class PredictedMarkers:
    """Fills a detection's missed markers from a predicted dock pose (the module's docstring says how).

    Args:
        camera, layout, robot: the calibration the estimator uses.
    """

    def __init__(self, camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> None:
        self.camera, self.layout, self.robot = camera, layout, robot
        self.modules = layout.modules
        self._bits = {r: layout.marker_bits(layout.marker(r).id) for r in layout.roles}
        self._codes = _dictionary_codes(layout)

    def radius_px(self, prior: Prior) -> dict[str, float]:
        """Each marker's search radius, px: ``SIGMAS`` times its corners' largest spread under the prior's
        covariance (by finite differences), clipped to ``SEARCH_PX``."""
        cov = prior.covariance
        if cov is None or np.shape(cov) != (3, 3) or not np.all(np.isfinite(cov)):
            cov = np.diag(np.square(DEFAULT_SIGMA))
        base = predict_corners(self.camera, self.layout, self.robot, prior.pose)
        steps = (1e-3, 1e-3, 1e-3)
        jac = {r: np.zeros((8, 3)) for r in base}
        for k, h in enumerate(steps):
            d = [0.0, 0.0, 0.0]
            d[k] = h
            p = prior.pose
            moved = predict_corners(
                self.camera, self.layout, self.robot, DockPose(p.x + d[0], p.y + d[1], p.yaw + d[2])
            )
            for r in base:
                jac[r][:, k] = (moved[r] - base[r]).ravel() / h
        out = {}
        for r, J in jac.items():
            spread = J @ np.asarray(cov, dtype=np.float64) @ J.T
            worst = max(
                math.sqrt(max(float(spread[2 * i, 2 * i] + spread[2 * i + 1, 2 * i + 1]), 0.0)) for i in range(4)
            )
            out[r] = float(np.clip(SIGMAS * worst, *SEARCH_PX)) if math.isfinite(worst) else SEARCH_PX[1]
        return out

    def fill(self, gray: NDArray[np.uint8], detection: Detection, prior: Prior) -> Detection:
        """The detection with the missed markers found where ``prior`` predicts them added (the detector's own
        observations unchanged); ``recovered`` names them."""
        predicted = predict_corners(self.camera, self.layout, self.robot, prior.pose)
        missing = [r for r in self.layout.roles if r not in detection.observations]
        if not missing:
            return detection
        radius = self.radius_px(prior)
        observations = dict(detection.observations)
        recovered = []
        for role in missing:
            corners = self.find(gray, role, predicted[role], radius[role])
            if corners is not None:
                observations[role] = MarkerObservation(role, self.layout.marker(role).id, corners)
                recovered.append(role)
        if not recovered:
            return detection
        ordered = {r: observations[r] for r in self.layout.roles if r in observations}
        return replace(detection, observations=ordered, recovered=tuple(recovered))

    def find(self, gray: NDArray[np.uint8], role: str, guess: F64, radius: float) -> F64 | None:
        """The marker's corners near ``guess`` (4, 2) within ``radius`` px, verified; None when not found."""
        h, w = gray.shape
        if not np.all(np.isfinite(guess)):
            return None
        lo, hi = guess.min(axis=0), guess.max(axis=0)
        if (
            lo[0] < EDGE_MARGIN_PX
            or lo[1] < EDGE_MARGIN_PX
            or hi[0] > w - 1 - EDGE_MARGIN_PX
            or hi[1] > h - 1 - EDGE_MARGIN_PX
        ):
            return None
        if math.sqrt(_area(guess)) / self.modules < MIN_MODULE_PX:
            return None
        bits = self._bits[role]
        shift = self._match(gray, guess, radius, bits)
        if shift is None:
            return None
        start = guess + shift
        fit = fit_marker(gray, start, self.camera, bits)
        corners = fit.corners if fit is not None else refine_marker(gray, start, self.camera, modules=self.modules)
        if corners is None or not np.all(np.isfinite(corners)):
            return None
        if float(np.max(np.linalg.norm(corners - guess, axis=1))) > radius + 2.0:
            return None
        return corners if self.verify(gray, role, corners) else None

    def _match(self, gray: NDArray[np.uint8], guess: F64, radius: float, bits: NDArray[np.uint8]) -> F64 | None:
        """The translation (2,) that best lays the expected marker's template on the image, or None."""
        h, w = gray.shape
        m = self.modules
        pad = 1.0  # quiet zone, modules
        # The template: the marker's cells and a white quiet zone, warped into the predicted quad.
        lo = np.floor(guess.min(axis=0) - pad * math.sqrt(_area(guess)) / m).astype(int) - 2
        hi = np.ceil(guess.max(axis=0) + pad * math.sqrt(_area(guess)) / m).astype(int) + 2
        r = math.ceil(radius)
        x0, y0 = max(lo[0] - r, 0), max(lo[1] - r, 0)
        x1, y1 = min(hi[0] + r, w - 1), min(hi[1] + r, h - 1)
        tx0, ty0 = max(lo[0], 0), max(lo[1], 0)
        tx1, ty1 = min(hi[0], w - 1), min(hi[1], h - 1)
        if tx1 - tx0 < 6 or ty1 - ty0 < 6:
            return None
        scale = 8  # texels a module
        cells = np.pad(bits, 1, constant_values=1).astype(np.float32)
        tex = cv2.resize(cells, ((m + 2) * scale, (m + 2) * scale), interpolation=cv2.INTER_NEAREST)
        src = np.array(
            [[scale, scale], [(m + 1) * scale, scale], [(m + 1) * scale, (m + 1) * scale], [scale, (m + 1) * scale]],
            np.float32,
        )
        dst = (guess - np.array([tx0, ty0])).astype(np.float32)
        H = cv2.getPerspectiveTransform(src, dst)
        tpl = cv2.warpPerspective(tex, H, (tx1 - tx0 + 1, ty1 - ty0 + 1), flags=cv2.INTER_AREA, borderValue=0.5)
        tpl = cv2.GaussianBlur(tpl, (0, 0), TEMPLATE_BLUR_PX)
        win = gray[y0 : y1 + 1, x0 : x1 + 1].astype(np.float32)
        if win.shape[0] < tpl.shape[0] or win.shape[1] < tpl.shape[1]:
            return None
        score = cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED)
        # Offsets of the template's placement relative to the predicted one, within the radius.
        ys, xs = np.mgrid[0 : score.shape[0], 0 : score.shape[1]]
        dx, dy = xs + x0 - tx0, ys + y0 - ty0
        score = np.where(dx * dx + dy * dy <= radius * radius, score, -1.0)
        j = int(np.argmax(score))
        iy, ix = divmod(j, score.shape[1])
        if not score[iy, ix] >= MIN_MATCH:
            return None
        sx, sy = _subpixel(score, ix, iy)
        return np.array([sx + x0 - tx0, sy + y0 - ty0], dtype=np.float64)

    def verify(self, gray: NDArray[np.uint8], role: str, corners: F64) -> bool:
        """Whether the marker at ``corners`` reads as ``role``'s: a black border, enough contrast, the code within
        ``MAX_HAMMING`` of the expected id and ``MIN_OTHER_MARGIN`` bits nearer it than any other id/rotation."""
        values = _cell_values(gray, corners, self.modules)
        if values is None:
            return False
        m = self.modules
        border = np.ones((m, m), dtype=bool)
        border[1:-1, 1:-1] = False
        inner = values[1:-1, 1:-1]
        black = float(np.median(values[border]))
        white = float(np.percentile(inner, 90))
        if white - black < MIN_CONTRAST:
            return False
        thr = 0.5 * (black + white)
        if np.any(values[border] >= thr):
            return False
        read = (inner >= thr).astype(np.uint8).ravel()
        want = self._bits[role][1:-1, 1:-1].ravel()
        mine = int(np.count_nonzero(read != want))
        if mine > MAX_HAMMING:
            return False
        others = np.count_nonzero(self._codes != read[None, :], axis=1)
        own = self._own_rows[role]
        others[own] = 10**6
        return bool(others.min() >= mine + MIN_OTHER_MARGIN)

    @property
    def _own_rows(self) -> dict[str, int]:
        return {r: 4 * self.layout.marker(r).id for r in self.layout.roles}


def _dictionary_codes(layout: DockLayout) -> NDArray[np.uint8]:
    """Every id's code bits in all four rotations, row ``4 id + k`` (k = 0: as printed), shape (4 N, n n)."""
    d = layout.aruco_dictionary()
    n = int(d.markerSize)
    rows = []
    for i in range(int(d.bytesList.shape[0])):
        bits = cv2.aruco.Dictionary.getBitsFromByteList(d.bytesList[i : i + 1], n).astype(np.uint8)
        for k in range(4):
            rows.append(np.rot90(bits, -k).ravel())
    return np.asarray(rows, dtype=np.uint8)


def _cell_values(gray: NDArray[np.uint8], corners: F64, m: int) -> NDArray[np.float64] | None:
    """The mean grey level at the centre of each of the marker's m x m cells (row 0 along corners 0-1)."""
    src = np.array([[0, 0], [m, 0], [m, m], [0, m]], dtype=np.float32)
    H = cv2.getPerspectiveTransform(src, corners.astype(np.float32))
    off = (np.arange(CELL_SAMPLES) + 0.5) / CELL_SAMPLES - 0.5
    off = off * CELL_CORE
    cu, cv = np.meshgrid(np.arange(m) + 0.5, np.arange(m) + 0.5)
    su = (cu[:, :, None, None] + off[None, None, None, :]).repeat(CELL_SAMPLES, axis=2)
    sv = (cv[:, :, None, None] + off[None, None, :, None]).repeat(CELL_SAMPLES, axis=3)
    pts = np.stack([su.ravel(), sv.ravel()], axis=1).reshape(-1, 1, 2).astype(np.float64)
    px = cv2.perspectiveTransform(pts, H).reshape(-1, 2)
    h, w = gray.shape
    if not (np.all(px >= 0) and np.all(px[:, 0] <= w - 1) and np.all(px[:, 1] <= h - 1)):
        return None
    vals = cv2.remap(
        gray.astype(np.float32),
        px[:, 0].astype(np.float32).reshape(1, -1),
        px[:, 1].astype(np.float32).reshape(1, -1),
        cv2.INTER_LINEAR,
    ).reshape(m, m, CELL_SAMPLES * CELL_SAMPLES)
    return np.asarray(vals.mean(axis=2), dtype=np.float64)


def _subpixel(score: NDArray[Any], ix: int, iy: int) -> tuple[float, float]:
    """The peak's position refined by a parabola through its neighbours on each axis."""

    def vertex(a: float, b: float, c: float) -> float:
        den = a - 2 * b + c
        return 0.0 if den >= 0 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))

    sx, sy = float(ix), float(iy)
    if 0 < ix < score.shape[1] - 1:
        sx += vertex(score[iy, ix - 1], score[iy, ix], score[iy, ix + 1])
    if 0 < iy < score.shape[0] - 1:
        sy += vertex(score[iy - 1, ix], score[iy, ix], score[iy + 1, ix])
    return sx, sy


def _area(c: F64) -> float:
    x, y = c[:, 0], c[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
