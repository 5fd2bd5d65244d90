"""Simulated checkerboard views with their true corner pixels, for testing and benchmarking calibration.

The board's own frame is the world frame: OpenCV's object frame of a chessboard, origin on the first inner
corner, x along a row of inner corners, y down the columns, z into the board (away from a camera facing it).
Inner corner (i, j) (column i, row j) sits at ``(i * square, j * square, 0)``, and the true corners are listed
row by row, which is the order in which ``cv2.findChessboardCorners*`` reports them (up to the 180 degree
turn of a board whose squares are odd by odd, which a detector cannot tell apart).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.transforms import invert, rotation_from_rpy, transform
from monodock.sim.nuisance import Nuisances, apply_nuisances
from monodock.sim.render import render_radiance
from monodock.sim.world import INK_BLACK, PAPER_WHITE, Patch, World, rectangle

__all__ = ["BoardView", "board_points", "checkerboard_world", "draw_board_pose", "render_board_views"]

_WALL_DISTANCE = 3.0  # metres behind the board: a plain grey wall
_WALL_ALBEDO = 0.5


@dataclass(frozen=True)
class BoardView:
    """One rendered checkerboard view and its ground truth.

    Attributes:
        image: the 8-bit grey image, shape (height, width).
        corners: true pixels of the inner corners through the lens, shape (cols * rows, 2), row by row.
        optical_T_board: the board's pose in the camera's optical frame, 4x4.
        complete: whether every inner corner lies inside the image.
        kind: "normal", "blurred" or "partial".
    """

    image: NDArray[np.uint8]
    corners: NDArray[np.float64]
    optical_T_board: NDArray[np.float64]
    complete: bool
    kind: str = "normal"


def board_points(board: tuple[int, int], square: float) -> NDArray[np.float64]:
    """The inner corners of a ``(cols, rows)`` board in its own frame, shape (cols * rows, 3), row by row."""
    cols, rows = board
    i, j = np.meshgrid(np.arange(cols, dtype=np.float64), np.arange(rows, dtype=np.float64))
    return np.stack([i.ravel() * square, j.ravel() * square, np.zeros(cols * rows)], axis=1)


def checkerboard_world(board: tuple[int, int], square: float, *, margin: float | None = None) -> World:
    """A checkerboard of ``(cols, rows)`` inner corners on white card, with a grey wall far behind it.

    Args:
        board: inner corners per row and per column (OpenCV's pattern size), e.g. (8, 6) for 9 x 7 squares.
        square: side of one square, metres.
        margin: white border around the squares, metres (default: one square).
    """
    cols, rows = board
    m = square if margin is None else margin
    n_s, n_t = cols + 1, rows + 1  # squares along x and y
    r, c = np.meshgrid(np.arange(n_t), np.arange(n_s), indexing="ij")
    values = np.where((r + c) % 2 == 0, INK_BLACK, PAPER_WHITE).astype(np.float64)
    w, h = n_s * square, n_t * square
    card = rectangle("board", (-square - m, -square - m, 0.0), (1, 0, 0), (0, 1, 0), w + 2 * m, h + 2 * m, PAPER_WHITE)
    card = card.with_patches(Patch(m, m, w, h, values))
    big = 50.0
    wall = rectangle("wall", (-big, -big, _WALL_DISTANCE), (1, 0, 0), (0, 1, 0), 2 * big, 2 * big, _WALL_ALBEDO)
    return World((card, wall))


def _outline(board: tuple[int, int], square: float, border: float) -> NDArray[np.float64]:
    """Points along the outline of the squares widened by ``border`` metres, in the board frame, shape (N, 3)."""
    cols, rows = board
    x0, y0 = -square - border, -square - border
    x1, y1 = cols * square + border, rows * square + border
    u = np.linspace(0.0, 1.0, 12)
    xs, ys = x0 + u * (x1 - x0), y0 + u * (y1 - y0)
    sides = [
        np.c_[xs, np.full_like(xs, y0)],
        np.c_[xs, np.full_like(xs, y1)],
        np.c_[np.full_like(ys, x0), ys],
        np.c_[np.full_like(ys, x1), ys],
    ]
    xy = np.concatenate(sides)
    return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float64)


def _corners_inside(px: NDArray[np.float64], camera: CameraModel, pad: float) -> bool:
    return bool(
        np.all((px[:, 0] >= pad) & (px[:, 0] <= camera.width - 1 - pad))
        and np.all((px[:, 1] >= pad) & (px[:, 1] <= camera.height - 1 - pad))
    )


def draw_board_pose(
    camera: CameraModel,
    board: tuple[int, int],
    square: float,
    rng: np.random.Generator,
    *,
    target: tuple[float, float] | None = None,
    distance: tuple[float, float] = (0.3, 1.0),
    max_tilt_deg: float = 45.0,
    max_roll_deg: float = 30.0,
    partial: bool = False,
    attempts: int = 500,
) -> NDArray[np.float64]:
    """A random pose ``optical_T_board`` of a board in front of the camera.

    The board's centre is put on the ray of a pixel (``target``, fractions of the width and height; default
    uniform over the image), at a distance drawn from ``distance`` (metres, scaled by ``square / 0.025``), tilted
    about an axis in its plane up to ``max_tilt_deg`` and turned in its plane up to ``max_roll_deg``. Poses are
    redrawn until the squares and half of the white margin around them are inside the image (at least 2 px
    from its border, and in the lens's field of view), as a calibration needs them, or with ``partial`` until
    about half of the inner corners are outside.
    """
    cols, rows = board
    pts = board_points(board, square)
    centre = pts.mean(axis=0)
    outline = _outline(board, square, 0.5 * square)
    scale = square / 0.025
    for _ in range(attempts):
        if target is None:
            fu, fv = rng.uniform(0.0, 1.0, 2)
        else:
            fu = float(np.clip(target[0] + rng.normal(0.0, 0.06), 0.0, 1.0))
            fv = float(np.clip(target[1] + rng.normal(0.0, 0.06), 0.0, 1.0))
        if partial:
            fu = 1.0 if rng.uniform() < 0.5 else 0.0
            fv = rng.uniform(0.3, 0.7)
        ray = camera.normalize([[fu * (camera.width - 1), fv * (camera.height - 1)]])[0]
        d = rng.uniform(*distance) * scale
        # The tilt: about an axis in the board's plane in a uniformly drawn direction, by up to max_tilt_deg.
        tilt = math.radians(max_tilt_deg) * math.sqrt(rng.uniform())
        direction = rng.uniform(0.0, 2.0 * math.pi)
        R = rotation_from_rpy(tilt * math.cos(direction), tilt * math.sin(direction), 0.0)
        R = R @ rotation_from_rpy(0.0, 0.0, math.radians(rng.uniform(-max_roll_deg, max_roll_deg)))
        c_cam = np.array([ray[0], ray[1], 1.0]) / math.hypot(ray[0], ray[1], 1.0) * d
        T = transform(R, c_cam - R @ centre)
        p_cam = pts @ T[:3, :3].T + T[:3, 3]
        if not partial:
            o_cam = outline @ T[:3, :3].T + T[:3, 3]
            if np.all(camera.in_view_field(o_cam, margin=0.0)) and _corners_inside(camera.project(o_cam), camera, 2.0):
                return T
            continue
        px = camera.project(p_cam)
        visible = camera.in_view_field(p_cam, margin=0.0) & (
            (px[:, 0] >= 0) & (px[:, 0] <= camera.width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= camera.height - 1)
        )
        if 0.3 <= visible.mean() <= 0.7 and np.all(p_cam[:, 2] > 0.05):
            return T
    raise RuntimeError(f"no board pose found in {attempts} attempts for board {cols}x{rows}")


def _render(
    world: World,
    camera: CameraModel,
    optical_T_board: NDArray[np.float64],
    nuisances: Nuisances,
    rng: np.random.Generator,
) -> NDArray[np.uint8]:
    radiance = render_radiance(world, camera, invert(optical_T_board), supersample=nuisances.supersample)
    return apply_nuisances(radiance, nuisances, rng)


def render_board_views(
    camera: CameraModel,
    board: tuple[int, int],
    square: float,
    n: int,
    *,
    seed: int = 0,
    nuisances: Nuisances | None = None,
    blurred: int = 0,
    partial: int = 0,
    blur_px: float = 3.0,
) -> list[BoardView]:
    """Seeded checkerboard views spread so that their corners cover the whole image, corners included.

    The board centres cycle over a 3 x 3 grid of targets (image corners, edge middles, centre) with jitter,
    so any ~9 consecutive views reach every part of the image where the lens distorts most.

    Args:
        camera: the true camera (intrinsics and distortion).
        board: inner corners per row and per column, e.g. (8, 6).
        square: side of a square, metres.
        n: number of normal views (all corners inside the image).
        seed: seed of every random draw.
        nuisances: camera nuisances (default: ``Nuisances()``, a cheap webcam's noise and slight defocus).
        blurred: extra views blurred by a Gaussian of ``blur_px`` sigma (too blurred to calibrate from).
        partial: extra views with about half of the board outside the image.
        blur_px: defocus sigma of the blurred views, pixels.

    Returns:
        The normal views, then the blurred ones, then the partial ones.
    """
    rng = np.random.default_rng(seed)
    nz = nuisances or Nuisances()
    world = checkerboard_world(board, square)
    pts = board_points(board, square)
    anchors = [(u, v) for v in (0.2, 0.5, 0.8) for u in (0.16, 0.5, 0.84)]
    order = [0, 8, 2, 6, 4, 1, 7, 3, 5]
    plans: list[tuple[str, tuple[float, float] | None]] = [("normal", anchors[order[k % 9]]) for k in range(n)]
    plans += [("blurred", None)] * blurred + [("partial", None)] * partial
    views = []
    for kind, target in plans:
        near = (0.3, 0.6) if kind != "normal" else (0.3, 1.0)
        T = draw_board_pose(camera, board, square, rng, target=target, distance=near, partial=kind == "partial")
        p_cam = pts @ T[:3, :3].T + T[:3, 3]
        px = camera.project(p_cam)
        complete = bool(np.all(camera.in_view_field(p_cam, margin=0.0))) and _corners_inside(px, camera, 0.0)
        nz_view = nz.updated(defocus_px=blur_px) if kind == "blurred" else nz
        views.append(BoardView(_render(world, camera, T, nz_view, rng), px, T, complete, kind))
    return views
