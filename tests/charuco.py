"""The reference for marker corners on the real ChArUco photos (tests/data/opencv_contrib): the chessboard's corners.

ChArUco's chessboard corners are X-junctions of two black squares: where they are does not depend on how black
the ink prints, nor on how a camera renders an edge, only on the geometry. Each marker sits in a white square
whose neighbouring X-junctions a local homography maps (in undistorted normalised coordinates, where the board's
plane is a homography away; then back through the lens): its true corners, following the paper's local bends.
The board: 5 x 7 squares of 40 mm, 20 mm DICT_6X6_250 markers (opencv_contrib's tutorial), printed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout, MarkerSpec

DATA = Path(__file__).resolve().parent / "data" / "opencv_contrib"
PHOTOS = ("img_00", "img_01", "img_02", "img_03")
HELD_OUT = "chocclusion_original"
CAMERA = DATA / "tutorial_camera_charuco.yml"
DICTIONARY = cv2.aruco.DICT_6X6_250


def board() -> cv2.aruco.CharucoBoard:
    b = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, cv2.aruco.getPredefinedDictionary(DICTIONARY))
    b.setLegacyPattern(False)
    return b


def one_marker_dock(marker_id: int) -> DockLayout:
    """A dock whose centre marker is the board's ``marker_id``: monodock refines any board marker as a dock's."""
    return DockLayout(
        "DICT_6X6_250",
        0.02,
        (
            MarkerSpec("left", (marker_id + 1) % 250, 0.08, 0.30),
            MarkerSpec("center", marker_id, 0.0, 0.30),
            MarkerSpec("right", (marker_id + 2) % 250, -0.08, 0.30),
        ),
    )


def image(name: str) -> NDArray[np.uint8]:
    return np.asarray(cv2.imread(str(DATA / f"{name}.jpg"), cv2.IMREAD_GRAYSCALE), dtype=np.uint8)


@dataclass(frozen=True)
class Reference:
    """One photo's X-junction reference: each interior marker's true corners (4, 2), px, by id; its local
    homography (the board's plane, m, to undistorted normalised coordinates) and its printed square (4, 2), m,
    in the board's plane."""

    corners: dict[int, NDArray[np.float64]]
    fit_rms_px: float  # how well the local homographies fit their own X-junctions
    homographies: dict[int, NDArray[np.float64]]
    squares: dict[int, NDArray[np.float64]]

    def corners_at(self, camera: CameraModel, marker_id: int, shift: NDArray[np.float64]) -> NDArray[np.float64]:
        """The marker's corners (4, 2), px, with it moved by ``shift`` (2,) m in the board's plane: where the
        print placed it, when that is known from other photos."""
        square = (self.squares[marker_id] + shift).reshape(-1, 1, 2)
        true = cv2.perspectiveTransform(square, self.homographies[marker_id]).reshape(-1, 2)
        return camera.project(np.c_[true, np.ones(4)])


def reference(gray: NDArray[np.uint8], camera: CameraModel) -> Reference:
    """The true corners of every marker with four X-junctions within a square of its centre."""
    b = board()
    junctions, ids, _, _ = cv2.aruco.CharucoDetector(b).detectBoard(gray)
    px = junctions.reshape(-1, 2).astype(np.float64)
    board_xy = b.getChessboardCorners()[ids.ravel(), :2].astype(np.float64)
    normalised = camera.normalize(px)
    out: dict[int, NDArray[np.float64]] = {}
    homographies: dict[int, NDArray[np.float64]] = {}
    squares: dict[int, NDArray[np.float64]] = {}
    fits = []
    for marker_id, obj in zip(b.getIds().ravel(), b.getObjPoints(), strict=True):
        square = np.asarray(obj, dtype=np.float64)[:, :2]
        d = np.linalg.norm(board_xy - square.mean(axis=0), axis=1)
        near = np.argsort(d)[:6]
        if d[near[3]] > 0.04:  # not four junctions around it: a marker at the board's edge
            continue
        H, _ = cv2.findHomography(board_xy[near], normalised[near], 0)
        back = cv2.perspectiveTransform(board_xy[near].reshape(-1, 1, 2), H).reshape(-1, 2)
        fits.append(np.linalg.norm(camera.project(np.c_[back, np.ones(len(back))]) - px[near], axis=1))
        true = cv2.perspectiveTransform(square.reshape(-1, 1, 2), H).reshape(-1, 2)
        out[int(marker_id)] = camera.project(np.c_[true, np.ones(4)])
        homographies[int(marker_id)] = H
        squares[int(marker_id)] = square
    return Reference(out, float(np.sqrt(np.mean(np.concatenate(fits) ** 2))), homographies, squares)


def radial_errors(corners: NDArray[np.float64], true: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Each corner's error (4, 2) and the mean of its part along the marker's diagonal (outward positive)."""
    e = corners - true
    out = true - true.mean(axis=0)
    out /= np.linalg.norm(out, axis=1)[:, None]
    return e, float(np.mean(np.sum(e * out, axis=1)))
