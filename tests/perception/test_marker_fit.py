"""The photometric marker fit against images whose corners and edge offset are known.

Ground truth: the simulator's exact renders (no ink: the offset is 0 but on markers whose white clips), and
markers drawn here with every black cell grown (or every white cell grown, for a thinner black) by a known
number of pixels, on a code grid of exactly side / M or 1.5 % larger (as a print rasterised into too few
pixels has it), before the optics' blur and the pixels' area. The fitted corners must land on the printed
outline, whatever the dilation and the grid.
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
from monodock.core.pose import DockPose
from monodock.errors import InputError
from monodock.perception.detect import MarkerDetector
from monodock.perception.edge_offset import clipped_roles
from monodock.perception.marker_fit import fit_detection, fit_marker
from monodock.perception.refine import refine_detection
from monodock.sim import Simulator

SIM_FRAMES = 12
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


# --- the simulator: exact renders, no offset -------------------------------------------------------


def test_corners_on_the_simulators_renders_are_unbiased() -> None:
    sim = Simulator(seed=4)
    detector = MarkerDetector(sim.layout)
    errors, radial, offsets, sides = [], [], [], []
    # Random poses, and a close one for the largest markers (~225 px).
    mount = sim.robot.camera_mount.x
    poses = [sim.sample_pose() for _ in range(SIM_FRAMES)] + [DockPose(mount + 0.27, -0.02, -0.05)]
    for pose in poses:
        img = sim.render(pose)
        truth = sim.true_corners(pose)
        det = refine_detection(img, detector.detect(img), sim.camera, modules=sim.layout.modules)
        # A clipped white moves the edges by the clipping's own offset (its clipped markers show -0.1 px):
        # the fit takes that as the offset, so only the unclipped ones must find none.
        clipped = set(clipped_roles(img, det, modules=sim.layout.modules))
        for role, o in det.observations.items():
            if not np.isfinite(truth[role]).all():
                continue
            fit = fit_marker(img, o.corners, sim.camera, sim.layout.marker_bits(o.marker_id))
            assert fit is not None, role
            errors.append(fit.corners - truth[role])
            radial.append(_radial(fit.corners, truth[role]))
            sides.append(float(np.mean(np.linalg.norm(np.diff(truth[role], axis=0), axis=1))))
            if role not in clipped:
                offsets.append(fit.offset_px)
    e = np.concatenate(errors)
    assert len(errors) >= 25
    assert min(sides) < 30.0  # far markers ...
    assert max(sides) > 200.0  # ... and near ones
    assert float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) < 0.05
    assert abs(float(np.mean(np.concatenate(radial)))) < 0.02
    assert len(offsets) >= 15
    assert abs(float(np.median(offsets))) < 0.01
    assert float(np.max(np.abs(offsets))) < 0.05


# --- markers with a known dilation, on an exact or a scaled code grid ------------------------------


def _homography(corners: NDArray[np.float64], modules: int) -> NDArray[np.float64]:
    square = np.array([[0, 0], [modules, 0], [modules, modules], [0, modules]], np.float32)
    return np.asarray(cv2.getPerspectiveTransform(square, corners.astype(np.float32)), np.float64)


def _line_distances(H: NDArray[np.float64], lines: NDArray[np.float64], modules: int, p: NDArray[np.float64]):
    """Signed pixel distances (N, L) of points p (N, 2) to the grid lines u = lines and v = lines (+: beyond).

    Without a lens the homography maps each grid line onto a straight line in pixels, so growing a cell by d
    px is moving its four lines outward by d, exactly.
    """

    def through(uv: NDArray[np.float64]) -> NDArray[np.float64]:
        h = np.c_[uv, np.ones(len(uv))] @ H.T
        return h[:, :2] / h[:, 2:]

    out = []
    for axis in (0, 1):
        dist = np.empty((len(p), len(lines)))
        for k, line in enumerate(lines):
            ends = np.array([[line, 0.0], [line, modules]]) if axis == 0 else np.array([[0.0, line], [modules, line]])
            a, b = through(ends)
            normal = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)
            beyond = np.array([[line + 0.5, modules / 2]]) if axis == 0 else np.array([[modules / 2, line + 0.5]])
            if np.dot(through(beyond)[0] - a, normal) < 0:
                normal = -normal
            dist[:, k] = (p - a) @ normal
        out.append(dist)
    return out[0], out[1]


def _black_coverage(
    black: NDArray[np.float64], H: NDArray[np.float64], p: NDArray[np.float64], d: float, grid_scale: float
) -> NDArray[np.bool_]:
    """Whether each point p (N, 2) is black on the printed marker dilated by d px (d < 0: eroded).

    The print: the outline exact (lines 0 and M), the interior lines at l * grid_scale modules from the top-left.
    d >= 0: the union of the black cells, each grown by d. d < 0: the outline shrunk by |d| less the union of
    the white code cells, each grown by |d| (eroding the black is dilating the white).
    """
    M = black.shape[0]
    lines = np.r_[np.arange(M) * grid_scale, float(M)]
    du, dv = _line_distances(H, lines, M, p)
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
    layout: DockLayout,
    markers: list[tuple[int, NDArray[np.float64]]],
    size: tuple[int, int],
    d: float,
    grid_scale: float = 1.0,
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
        coverage[ys.ravel(), xs.ravel()] = _black_coverage(black, H, p, d, grid_scale)
    light = WHITE - (WHITE - BLACK) * coverage
    light = cv2.GaussianBlur(light, (0, 0), BLUR_PX * SS)
    pixels = light.reshape(height, SS, width, SS).mean(axis=(1, 3))  # the pixels' area
    noise = np.random.default_rng(7).normal(0.0, 0.8, pixels.shape)
    return np.clip(np.rint(pixels + noise), 0, 255).astype(np.uint8)


def _scene(rng: np.random.Generator, layout: DockLayout) -> list[tuple[int, NDArray[np.float64]]]:
    """The layout's three markers, 30-40 px, turned and in mild perspective, side by side."""
    out = []
    for k, spec in enumerate(layout.markers):
        side = rng.uniform(30.0, 40.0)
        angle = rng.uniform(-0.6, 0.6) + 0.3
        square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * side / 2
        R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        quad = square @ R.T * (1.0 + rng.uniform(-0.06, 0.06, (4, 1)))
        out.append((spec.id, quad + np.array([60.0 + 80.0 * k, 60.0])))
    return out


SIZE = (280, 120)
CAMERA = CameraModel.from_intrinsics(*SIZE, 300.0, 300.0, SIZE[0] / 2, SIZE[1] / 2)


@pytest.mark.parametrize("grid_scale", [1.0, 1.015])
@pytest.mark.parametrize("d", [-0.15, 0.2])
def test_a_known_dilation_is_found_and_kept_out_of_the_corners(d: float, grid_scale: float) -> None:
    layout = DockLayout.default()
    detector = MarkerDetector(layout)
    rng = np.random.default_rng(11)
    offsets, radial, fixed_radial = [], [], []
    for _ in range(2):
        markers = _scene(rng, layout)
        img = _draw(layout, markers, SIZE, d, grid_scale)
        det = detector.detect(img)
        assert len(det.observations) == 3
        truth = {layout.role_of(i): c for i, c in markers}
        for role, o in det.observations.items():
            bits = layout.marker_bits(o.marker_id)
            fit = fit_marker(img, o.corners, CAMERA, bits)
            assert fit is not None, role
            offsets.append(fit.offset_px)
            radial.append(_radial(fit.corners, truth[role]))
            # Held at the true offset (as when pooled over many markers), the corners stay where they belong.
            held = fit_marker(img, o.corners, CAMERA, bits, offset_px=d)
            assert held is not None
            assert held.offset_px == d
            fixed_radial.append(_radial(held.corners, truth[role]))
    assert float(np.max(np.abs(np.array(offsets) - d))) < 0.03
    assert abs(float(np.mean(np.concatenate(radial)))) < 0.03
    assert abs(float(np.mean(np.concatenate(fixed_radial)))) < 0.03


def test_a_marker_that_cannot_be_fitted_keeps_its_corners_in_the_detection() -> None:
    layout = DockLayout.default()
    img = _draw(layout, _scene(np.random.default_rng(3), layout), SIZE, 0.0)
    det = MarkerDetector(layout).detect(img)
    assert len(det.observations) == 3
    img[:, 185:] = int(WHITE)  # the right marker is gone, its detection stays: nothing to fit there
    fitted = fit_detection(img, det, CAMERA, layout)
    assert fitted.unrefined == ("right",)
    np.testing.assert_array_equal(fitted.observations["right"].corners, det.observations["right"].corners)
    for role in ("left", "center"):
        o = det.observations[role]
        alone = fit_marker(img, o.corners, CAMERA, layout.marker_bits(o.marker_id))
        assert alone is not None
        np.testing.assert_array_equal(fitted.observations[role].corners, alone.corners)


# --- no fit, and refusals ---------------------------------------------------------------------------


def test_no_marker_no_fit() -> None:
    layout = DockLayout.default()
    bits = layout.marker_bits(2)
    quad = np.array([[30.0, 30.0], [70.0, 32.0], [68.0, 72.0], [28.0, 70.0]])
    flat = np.random.default_rng(0).normal(150.0, 2.0, (SIZE[1], SIZE[0]))
    blank = np.clip(np.rint(flat), 0, 255).astype(np.uint8)
    assert fit_marker(blank, quad, CAMERA, bits) is None
    assert fit_marker(np.full((SIZE[1], SIZE[0]), 128, np.uint8), quad, CAMERA, bits) is None
    img = _draw(layout, [(2, quad)], SIZE, 0.0)
    assert fit_marker(img, quad, CAMERA, bits) is not None
    assert fit_marker(img, quad + np.array([250.0, 0.0]), CAMERA, bits) is None  # off the image's right side
    assert fit_marker(img, quad - np.array([0.0, 60.0]), CAMERA, bits) is None  # two corners above it
    assert fit_marker(img, (quad - quad.mean(axis=0)) * 0.15 + quad.mean(axis=0), CAMERA, bits) is None  # 6 px


def _one_line(excinfo: pytest.ExceptionInfo[InputError]) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    return message


def test_bad_inputs_are_refused_in_one_line() -> None:
    layout = DockLayout.default()
    bits = layout.marker_bits(2)
    quad = np.array([[30.0, 30.0], [70.0, 32.0], [68.0, 72.0], [28.0, 70.0]])
    img = _draw(layout, [(2, quad)], SIZE, 0.0)
    with pytest.raises(InputError, match="8-bit") as e:
        fit_marker(img.astype(np.float32), quad, CAMERA, bits)  # type: ignore[arg-type]
    _one_line(e)
    with pytest.raises(InputError, match="camera") as e:
        fit_marker(img[:, :200], quad, CAMERA, bits)
    _one_line(e)
    with pytest.raises(InputError, match="corners") as e:
        fit_marker(img, quad[:3], CAMERA, bits)
    _one_line(e)
    with pytest.raises(InputError, match="black border") as e:
        fit_marker(img, quad, CAMERA, 1 - bits)  # 1 = black, as OpenCV's images: the border reads white
    _one_line(e)
    with pytest.raises(InputError, match="square array") as e:
        fit_marker(img, quad, CAMERA, bits * 255)
    _one_line(e)
    with pytest.raises(InputError, match="offset_px") as e:
        fit_marker(img, quad, CAMERA, bits, offset_px=float("nan"))
    _one_line(e)
    with pytest.raises(InputError, match="offset_px") as e:
        fit_detection(img, MarkerDetector(layout).detect(img), CAMERA, layout, offset_px=float("inf"))
    _one_line(e)
