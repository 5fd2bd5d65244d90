"""The edge offset from the code's run widths, against images whose offset is known.

Ground truth: the simulator's exact renders (no ink: the offset is 0, and the refined corners are already
unbiased, so applying the estimate must leave them so), and markers drawn here with every black cell grown
(or every white cell grown, for a thinner black) by a known number of pixels before the optics' blur and the
pixels' area: the estimate must find that number, and the corners it corrects must land on the undilated
marker's true corners.
"""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.errors import InputError
from monodock.perception.detect import Detection, MarkerDetector
from monodock.perception.edge_offset import (
    clipped_roles,
    detection_edge_offset,
    estimate_edge_offset,
    marker_runs,
    offset_corners,
    offset_detection,
)
from monodock.perception.refine import refine_detection
from monodock.sim import Simulator

SIM_FRAMES = 10
SS = 10  # sub-samples per pixel side of the drawn markers
BLUR_PX = 0.45  # the drawn markers' optical blur (Gaussian sigma), before the pixels' area
WHITE, BLACK = 205.0, 40.0


@pytest.fixture(scope="module", autouse=True)
def _one_thread() -> Iterator[None]:
    """Rendering with threaded BLAS on a shared 2-core machine is several times slower, not faster."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    with threadpool_limits(1):
        yield
    cv2.setNumThreads(threads)


def _radial(corners: NDArray[np.float64], truth: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed error along the true centre -> corner direction (+: outside the marker), px."""
    out = truth - truth.mean(axis=0)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return np.asarray(np.sum((corners - truth) * out, axis=1))


def _bias(detections: list[tuple[Detection, dict[str, NDArray[np.float64]]]], skip: list[set[str]]) -> float:
    """Mean radial error of the refined, unskipped markers' corners against the truth, px."""
    errors = [
        _radial(o.corners, truth[role])
        for (det, truth), left_out in zip(detections, skip, strict=True)
        for role, o in det.observations.items()
        if role not in det.unrefined and role not in left_out and np.isfinite(truth[role]).all()
    ]
    return float(np.mean(np.concatenate(errors)))


# --- the simulator: no offset -------------------------------------------------------------------


def test_no_offset_on_the_simulators_exact_renders() -> None:
    sim = Simulator(seed=3)
    detector = MarkerDetector(sim.layout)
    runs, frames, clipped = [], [], []
    for _ in range(SIM_FRAMES):
        pose = sim.sample_pose()
        img = sim.render(pose)
        det = refine_detection(img, detector.detect(img), sim.camera, modules=sim.layout.modules)
        runs += detection_edge_offset(img, det, sim.camera, sim.layout)
        frames.append((img, det, sim.true_corners(pose)))
        clipped.append(set(clipped_roles(img, det, modules=sim.layout.modules)))
    assert any(clipped), "the frames should include clipped markers, which are left out"
    estimate = estimate_edge_offset(runs)
    assert estimate.markers >= 15
    assert abs(estimate.offset_px) < 0.03
    assert estimate.sd_px < 0.02
    before = [(det, truth) for _, det, truth in frames]
    after = [
        (offset_detection(det, estimate.offset_px, skip=c), truth)
        for (_, det, truth), c in zip(frames, clipped, strict=True)
    ]
    assert abs(_bias(after, clipped) - _bias(before, clipped)) <= 0.02
    assert abs(_bias(after, clipped)) <= 0.03


# --- markers with a known dilation -----------------------------------------------------------------


def _homography(corners: NDArray[np.float64], modules: int) -> NDArray[np.float64]:
    square = np.array([[0, 0], [modules, 0], [modules, modules], [0, modules]], np.float32)
    return np.asarray(cv2.getPerspectiveTransform(square, corners.astype(np.float32)), np.float64)


def _grid_distances(H: NDArray[np.float64], modules: int, p: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Signed pixel distances (N, M+1) of points p (N, 2) to the grid lines u = l and v = l (+: beyond l).

    Without a lens the homography maps each grid line onto a straight line in pixels, so growing a cell by d
    px is moving its four lines outward by d, exactly.
    """

    def through(uv: NDArray[np.float64]) -> NDArray[np.float64]:
        h = np.c_[uv, np.ones(len(uv))] @ H.T
        return h[:, :2] / h[:, 2:]

    out = []
    for axis in (0, 1):
        dist = np.empty((len(p), modules + 1))
        for line in range(modules + 1):
            ends = np.array([[line, 0.0], [line, modules]]) if axis == 0 else np.array([[0.0, line], [modules, line]])
            a, b = through(ends)
            normal = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)
            beyond = np.array([[line + 0.5, modules / 2]]) if axis == 0 else np.array([[modules / 2, line + 0.5]])
            if np.dot(through(beyond)[0] - a, normal) < 0:
                normal = -normal
            dist[:, line] = (p - a) @ normal
        out.append(dist)
    return out[0], out[1]


def _black_coverage(black: NDArray[np.float64], H: NDArray[np.float64], p: NDArray[np.float64], d: float) -> NDArray:
    """Whether each point p (N, 2) is black on the marker dilated by d px (d < 0: eroded).

    d >= 0: the union of the black cells, each grown by d. d < 0: the outline shrunk by |d| less the union of
    the white code cells, each grown by |d| (eroding the black is dilating the white).
    """
    M = black.shape[0]
    du, dv = _grid_distances(H, M, p)
    g = abs(d)

    def in_grown_cells(cells: NDArray[np.float64]) -> NDArray[np.bool_]:
        cols = ((du[:, :-1] > -g) & (du[:, 1:] < g)).astype(np.float64)  # (N, M): inside column i grown
        rows = ((dv[:, :-1] > -g) & (dv[:, 1:] < g)).astype(np.float64)
        return np.asarray(np.sum((rows @ cells) * cols, axis=1) > 0)

    if d >= 0:
        return in_grown_cells(black)
    inside = (du[:, 0] > g) & (du[:, M] < -g) & (dv[:, 0] > g) & (dv[:, M] < -g)
    white_code = np.zeros_like(black)
    white_code[1:-1, 1:-1] = 1.0 - black[1:-1, 1:-1]
    return np.asarray(inside & ~in_grown_cells(white_code))


def _draw(
    layout: DockLayout, markers: list[tuple[int, NDArray[np.float64]]], size: tuple[int, int], d: float
) -> NDArray[np.uint8]:
    """The image (mono8) of markers (id, true corners (4, 2) px) on white, every black edge moved out by d px."""
    width, height = size
    coverage = np.zeros((height * SS, width * SS), np.float32)
    for marker_id, corners in markers:
        black = 1.0 - layout.marker_bits(marker_id).astype(np.float64)
        H = _homography(corners, layout.modules)
        lo = np.floor(corners.min(axis=0) - 3).astype(int) * SS
        hi = np.ceil(corners.max(axis=0) + 3).astype(int) * SS
        ys, xs = np.mgrid[lo[1] : hi[1], lo[0] : hi[0]]
        # Sub-sample centres in pixels: pixel (0, 0) covers [-0.5, 0.5] (OpenCV's convention).
        p = np.c_[(xs.ravel() + 0.5) / SS - 0.5, (ys.ravel() + 0.5) / SS - 0.5]
        coverage[ys.ravel(), xs.ravel()] = _black_coverage(black, H, p, d)
    light = WHITE - (WHITE - BLACK) * coverage
    light = cv2.GaussianBlur(light, (0, 0), BLUR_PX * SS)
    pixels = light.reshape(height, SS, width, SS).mean(axis=(1, 3))  # the pixels' area
    noise = np.random.default_rng(7).normal(0.0, 0.8, pixels.shape)
    return np.clip(np.rint(pixels + noise), 0, 255).astype(np.uint8)


def _scene(rng: np.random.Generator, layout: DockLayout) -> list[tuple[int, NDArray[np.float64]]]:
    """The layout's three markers, 30-36 px, turned and in mild perspective, side by side."""
    out = []
    for k, spec in enumerate(layout.markers):
        side = rng.uniform(30.0, 36.0)
        angle = rng.uniform(-0.6, 0.6) + 0.3
        square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * side / 2
        R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        quad = square @ R.T * (1.0 + rng.uniform(-0.06, 0.06, (4, 1)))
        out.append((spec.id, quad + np.array([60.0 + 80.0 * k, 60.0])))
    return out


@pytest.mark.parametrize("d", [-0.15, 0.2])
def test_a_known_dilation_is_found_and_taken_out_of_the_corners(d: float) -> None:
    layout = DockLayout.default()
    size = (280, 120)
    camera = CameraModel.from_intrinsics(*size, 300.0, 300.0, size[0] / 2, size[1] / 2)
    detector = MarkerDetector(layout)
    rng = np.random.default_rng(11)
    runs, frames = [], []
    for _ in range(2):
        markers = _scene(rng, layout)
        img = _draw(layout, markers, size, d)
        det = refine_detection(img, detector.detect(img), camera, modules=layout.modules)
        assert not det.unrefined
        assert len(det.observations) == 3
        truth = {layout.role_of(i): c for i, c in markers}
        runs += detection_edge_offset(img, det, camera, layout)
        frames.append((det, truth))
    estimate = estimate_edge_offset(runs)
    assert estimate.markers == 6
    assert abs(estimate.offset_px - d) < 0.03
    none: list[set[str]] = [set(), set()]
    # The dilation moves the refined corners out by about d sqrt 2; the estimate moves them back.
    assert abs(_bias(frames, none) - d * np.sqrt(2)) < 0.1
    corrected = [(offset_detection(det, estimate.offset_px), truth) for det, truth in frames]
    assert abs(_bias(corrected, none)) < 0.04


# --- the pieces, against known answers -------------------------------------------------------------


def test_offset_corners_moves_each_side_inward_by_the_offset() -> None:
    square = np.array([[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0]])
    np.testing.assert_allclose(offset_corners(square, 0.5), [[10.5, 10.5], [29.5, 10.5], [29.5, 29.5], [10.5, 29.5]])
    np.testing.assert_allclose(offset_corners(square[::-1], -0.5), [[9.5, 30.5], [30.5, 30.5], [30.5, 9.5], [9.5, 9.5]])
    # A rhombus: the sides' distance to the centre shrinks by the offset.
    rhombus = np.array([[0.0, -10.0], [20.0, 0.0], [0.0, 10.0], [-20.0, 0.0]])
    moved = offset_corners(rhombus, 0.3)
    side, to_centre = moved[1] - moved[0], -moved[0]
    distance = abs(side[0] * to_centre[1] - side[1] * to_centre[0]) / np.linalg.norm(side)
    assert distance == pytest.approx(200.0 / np.hypot(10.0, 20.0) - 0.3, abs=1e-12)


def test_marker_runs_of_a_sharp_marker_are_their_printed_widths() -> None:
    layout = DockLayout.default()
    size = (120, 120)
    camera = CameraModel.from_intrinsics(*size, 300.0, 300.0, 60.0, 60.0)
    corners = np.array([[30.0, 30.0], [90.0, 30.0], [90.0, 90.0], [30.0, 90.0]]) - 0.5
    img = _draw(layout, [(2, corners)], size, 0.0)
    runs = marker_runs(img, corners, camera, layout.marker_bits(2))
    assert len(runs) >= 10
    assert set(np.unique(runs[:, 1])) == {-1.0, 1.0}
    np.testing.assert_allclose(runs[:, 3], 10.0 * runs[:, 0], atol=1e-9)  # a module is 10 px
    np.testing.assert_allclose(runs[:, 2], runs[:, 3], atol=0.05)


def test_too_few_runs_are_refused() -> None:
    with pytest.raises(InputError, match="too few"):
        estimate_edge_offset([])
    few = np.array([[1, 1, 5.1, 5.0], [2, -1, 9.8, 10.0], [1, 1, 5.2, 5.0], [1, -1, 4.8, 5.0]], np.float64)
    with pytest.raises(InputError, match="too few"):
        estimate_edge_offset([few, few])
    one_colour = np.tile([[1.0, 1.0, 5.1, 5.0]], (40, 1))
    with pytest.raises(InputError, match="too few"):
        estimate_edge_offset([one_colour])


def test_cells_in_the_wrong_convention_are_refused() -> None:
    layout = DockLayout.default()
    camera = CameraModel.from_intrinsics(120, 120, 300.0, 300.0, 60.0, 60.0)
    img = np.full((120, 120), 200, np.uint8)
    corners = np.array([[30.0, 30.0], [90.0, 30.0], [90.0, 90.0], [30.0, 90.0]])
    with pytest.raises(InputError, match="black border"):
        marker_runs(img, corners, camera, 1 - layout.marker_bits(2))  # 1 = black: the border reads white
