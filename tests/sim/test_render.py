"""The renderer is exact: a black square on a white plane darkens exactly its projected area.

Ground truth is plain geometry: the square's corners (or densely sampled boundary) projected by a pinhole
written out here, or by ``cv2.projectPoints`` through the lens, and the shoelace area and centroid of the
resulting polygon. No detector is involved.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.sim.nuisance import Nuisances, apply_nuisances
from monodock.sim.reference import edge_pixels, pixel_means_by_rays
from monodock.sim.reference import render_radiance as reference_render
from monodock.sim.render import render_radiance
from monodock.sim.world import Patch, Surface, World, rectangle

WHITE = 0.85
BLACK = 0.06
SIDE = 0.5  # metres
S0, T0 = 9.7, 9.9  # the square's top-left in the plane's (s, t) coordinates


def _scene(side: float = SIDE) -> tuple[World, Surface]:
    """A 20 m x 20 m white plane at z = 3 carrying one black square patch."""
    plane = rectangle("plane", (-10.0, -10.0, 3.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), 20.0, 20.0, WHITE)
    plane = plane.with_patches(Patch(S0, T0, side, side, np.array([[BLACK]])))
    return World((plane,)), plane


def _square_corners(plane: Surface, side: float = SIDE) -> NDArray[np.float64]:
    st = [(S0, T0), (S0 + side, T0), (S0 + side, T0 + side), (S0, T0 + side)]
    return np.array([plane.origin + s * plane.s_axis + t * plane.t_axis for s, t in st])


def _square_boundary(plane: Surface, n: int = 2000, side: float = SIDE) -> NDArray[np.float64]:
    """n points on each of the square's four sides, in order around it, in 3D."""
    u = np.arange(n) / n
    s = np.concatenate([S0 + u * side, np.full(n, S0 + side), S0 + side - u * side, np.full(n, S0)])
    t = np.concatenate([np.full(n, T0), T0 + u * side, np.full(n, T0 + side), T0 + side - u * side])
    return plane.origin + s[:, None] * plane.s_axis + t[:, None] * plane.t_axis


Array = NDArray[np.float64]


def _look_at(eye: tuple[float, float, float], target: Array, roll: float) -> Array:
    """world_T_optical of a camera at ``eye`` whose optical axis points at ``target``, rolled about it."""
    c = np.asarray(eye, dtype=np.float64)
    z = target - c
    z /= np.linalg.norm(z)
    x = np.cross(np.array([0.0, -1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    cr, sr = np.cos(roll), np.sin(roll)
    R = np.column_stack([x, y, z]) @ np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c
    return T


def _pinhole(camera: CameraModel, world_T_optical: Array, pts: Array) -> Array:
    """Ideal pinhole projection, written out: q = R^T (p - c); u = fx qx/qz + cx; v = fy qy/qz + cy."""
    R, c = world_T_optical[:3, :3], world_T_optical[:3, 3]
    q = (pts - c) @ R
    u = camera.fx * q[:, 0] / q[:, 2] + camera.cx
    v = camera.fy * q[:, 1] / q[:, 2] + camera.cy
    return np.column_stack([u, v])


def _through_lens(camera: CameraModel, world_T_optical: Array, pts: Array) -> Array:
    """Projection with OpenCV's own plumb_bob model."""
    R, c = world_T_optical[:3, :3], world_T_optical[:3, 3]
    rvec, _ = cv2.Rodrigues(R.T)
    px, _ = cv2.projectPoints(pts, rvec, -R.T @ c, camera.matrix, camera.dist)
    return np.asarray(px, dtype=np.float64).reshape(-1, 2)


def _shoelace(poly: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Area and area centroid of a simple polygon."""
    x, y = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    a = cross.sum() / 2.0
    centroid = np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (6.0 * a)
    return abs(float(a)), centroid


def _darkness_moments(image: NDArray[np.generic], white: float, black: float) -> tuple[float, NDArray[np.float64]]:
    """Sum and centroid (x = column, y = row, pixel centres at integers) of (white - I) / (white - black)."""
    d = (white - image.astype(np.float64)) / (white - black)
    rows, cols = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    total = float(d.sum())
    return total, np.array([(d * cols).sum(), (d * rows).sum()]) / total


def _assert_inside(camera: CameraModel, px: NDArray[np.float64], margin: float = 5.0) -> None:
    assert np.all(px > margin)
    assert np.all(px[:, 0] < camera.width - 1 - margin)
    assert np.all(px[:, 1] < camera.height - 1 - margin)


# A small camera with a principal point well off the image centre and unequal focal lengths.
PINHOLE = CameraModel.from_intrinsics(200, 150, 180.0, 186.0, 88.0, 81.5)

# (eye, offset of the aim point from the square's centre, roll about the optical axis)
PINHOLE_VIEWS = {
    "frontal": ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0),
    "oblique": ((1.9, -1.2, 0.4), (0.15, 0.05, 0.0), 0.4),
    "oblique_off_axis": ((-2.2, 0.6, 0.8), (-0.35, 0.3, 0.0), -0.7),
}


@pytest.mark.parametrize("view", list(PINHOLE_VIEWS))
def test_pinhole_darkness_equals_projected_square(view: str) -> None:
    """Zero distortion: darkness sum = shoelace area of the projected corners, centroid = area centroid."""
    world, plane = _scene()
    eye, offset, roll = PINHOLE_VIEWS[view]
    centre = plane.origin + (S0 + SIDE / 2) * plane.s_axis + (T0 + SIDE / 2) * plane.t_axis
    T = _look_at(eye, centre + np.asarray(offset), roll)
    if view != "frontal":
        tilt = np.degrees(np.arccos(abs(T[:3, 2] @ plane.normal)))
        assert tilt > 30.0  # really oblique: the projected square is far from a square
    corners_px = _pinhole(PINHOLE, T, _square_corners(plane))
    _assert_inside(PINHOLE, corners_px)
    area, centroid = _shoelace(corners_px)
    assert area > 400.0

    image = render_radiance(world, PINHOLE, T)

    dark, dark_centroid = _darkness_moments(image, WHITE, BLACK)
    np.testing.assert_allclose(dark, area, rtol=0.005)
    np.testing.assert_allclose(dark_centroid, centroid, atol=0.05)


LENS_VIEWS = {
    "right_edge": ((0.3, 0.2, 0.0), (0.9, 0.6, 0.0), 0.2),
    "oblique_top_left": ((1.5, -0.8, 0.5), (-0.5, -0.3, 0.0), 0.4),
}


@pytest.mark.parametrize("view", list(LENS_VIEWS))
def test_distorted_darkness_equals_projected_boundary(view: str) -> None:
    """plumb_bob lens: darkness sum and centroid = shoelace of the boundary sampled densely through the lens."""
    camera = CameraModel.default()
    assert np.any(camera.dist != 0.0)
    world, plane = _scene(0.4)
    eye, offset, roll = LENS_VIEWS[view]
    centre = plane.origin + (S0 + 0.2) * plane.s_axis + (T0 + 0.2) * plane.t_axis
    T = _look_at(eye, centre + np.asarray(offset), roll)
    boundary_px = _through_lens(camera, T, _square_boundary(plane, 2000, 0.4))
    _assert_inside(camera, boundary_px)
    area, centroid = _shoelace(boundary_px)
    # The lens matters here: an ideal pinhole would put the square elsewhere by more than the tolerance.
    pin_area, pin_centroid = _shoelace(_pinhole(camera, T, _square_corners(plane, 0.4)))
    assert abs(pin_area / area - 1.0) > 0.005
    assert np.linalg.norm(pin_centroid - centroid) > 0.4

    image = render_radiance(world, camera, T)

    dark, dark_centroid = _darkness_moments(image, WHITE, BLACK)
    np.testing.assert_allclose(dark, area, rtol=0.005)
    np.testing.assert_allclose(dark_centroid, centroid, atol=0.05)


def test_clean_8bit_image_keeps_area() -> None:
    """Nuisances.clean(): the uint8 image, read against the albedos' 8-bit levels, keeps area and centroid."""
    world, plane = _scene()
    centre = plane.origin + (S0 + SIDE / 2) * plane.s_axis + (T0 + SIDE / 2) * plane.t_axis
    T = _look_at((1.9, -1.2, 0.4), centre + np.array([0.15, 0.05, 0.0]), 0.4)
    area, centroid = _shoelace(_pinhole(PINHOLE, T, _square_corners(plane)))
    radiance = render_radiance(world, PINHOLE, T)

    image = apply_nuisances(radiance, Nuisances.clean(), np.random.default_rng(7))

    assert image.dtype == np.uint8
    white, black = float(np.rint(WHITE * 255)), float(np.rint(BLACK * 255))
    np.testing.assert_array_equal(image[:5, :5], white)  # far from the square: plain white, no noise
    dark, dark_centroid = _darkness_moments(image, white, black)
    np.testing.assert_allclose(dark, area, rtol=0.005)
    np.testing.assert_allclose(dark_centroid, centroid, atol=0.05)


# --- the compiled renderer against the numpy reference and against dense sampling ---------------------------------


WIDE = Path(__file__).parents[2] / "bench" / "setups" / "wide"
# A strong rational_polynomial lens (the one tests/core/test_lens.py checks against OpenCV).
RATIONAL = CameraModel(
    1280,
    720,
    (700.0, 0.0, 645.0, 0.0, 698.0, 355.0, 0.0, 0.0, 1.0),
    (0.6, -0.05, 5e-4, -8e-4, 0.01, 0.95, 0.02, 0.015),
    "rational_polynomial",
)


def _setup(name: str, seed: int) -> Any:
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.sim.simulator import Simulator

    if name == "wide":  # 1280x720 barrel lens, DICT_5X5 markers 12 cm and 22 cm apart, a pitched camera
        return Simulator(
            layout=DockLayout.load(WIDE / "layout.yaml"),
            camera=CameraModel.load(WIDE / "camera.yaml"),
            robot=RobotConfig.load(WIDE / "robot.yaml"),
            seed=seed,
        )
    if name == "rational":
        return Simulator(camera=RATIONAL, seed=seed)
    if name == "odd":  # neither side a multiple of the renderer's 16-px tile: its last tiles take the remainder
        base = CameraModel.default()
        w, h = 648, 486
        K = (base.fx * w / 640, 0.0, w / 2 - 0.3, 0.0, base.fy * w / 640, h / 2 + 0.2, 0.0, 0.0, 1.0)
        return Simulator(camera=CameraModel(w, h, K, base.D), seed=seed)
    return Simulator(seed=seed)


@pytest.mark.parametrize(
    ("setup", "seed"), [("default", 3), ("default", 11), ("wide", 5), ("rational", 7), ("odd", 13)]
)
def test_compiled_renderer_matches_the_reference_and_dense_sampling(setup: str, seed: int) -> None:
    """A cluttered dock scene with an occluder, on the default set-up and on three it was not built on (another
    layout, camera and mounts behind a wide barrel lens; a rational_polynomial lens; a 648x486 image, whose last
    tiles are part tiles): off the edges the compiled
    image is the reference's to 1/255; on them both are compared with 16384 rays per pixel, and the compiled one
    is the closer."""
    from monodock.sim.scene import occluder_for

    sim = _setup(setup, seed)
    pose = sim.sample_pose()
    T = sim.world_T_optical(pose)
    world = sim.world.with_surfaces(occluder_for(sim.layout, T[:3, 3], np.random.default_rng(seed)))

    image = render_radiance(world, sim.camera, T)
    reference = reference_render(world, sim.camera, T)

    edges = edge_pixels(world, sim.camera, T)
    assert edges.sum() > 2000  # markers, clutter, the charger's outline and the occluder
    np.testing.assert_array_less(np.abs(image - reference)[~edges], 1.0 / 255)
    pick = np.random.default_rng(seed).choice(np.argwhere(edges), 150, replace=False)
    truth = pixel_means_by_rays(world, sim.camera, T, pick, rng=np.random.default_rng(seed))
    compiled_err = np.abs(image[pick[:, 0], pick[:, 1]] - truth)
    reference_err = np.abs(reference[pick[:, 0], pick[:, 1]] - truth)
    # 16384 jittered rays resolve a pixel to ~0.01/255 on average; the compiled renderer's exact areas sit at that,
    # the reference's 16 x 16 n-rooks samples ~10x off it (0.08-0.16/255 measured).
    assert compiled_err.mean() < 0.04 / 255
    assert compiled_err.mean() < reference_err.mean() / 3
