"""A plain synthetic camera view of the dock's face, for warming up the compiled per-frame kernels.

Not the simulator (``monodock.sim`` renders exactly, with nuisances, clutter, a room and a LiDAR): this draws
only the charger face with its markers, flat-shaded, through the real lens model, at a few pixel samples per
pixel. It is exact enough for the estimators to find the dock within a centimetre, cheap (tens of ms), and needs
nothing but the calibration, so that what runs on the robot does not load the simulator.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig

__all__ = ["synthetic_view"]

# Grey levels of the face, of the markers' black and of what lies around the face (no room is drawn).
_WHITE, _BLACK, _AROUND = 210.0, 15.0, 110.0
# Metres per texel of the face texture, and samples per pixel side (area-averaged).
_TEXEL_M = 0.0005
_SAMPLES = 2


def _face_texture(layout: DockLayout) -> tuple[NDArray[np.float32], float, float]:
    """The face as a grey texture (rows down from the top edge, columns from the robot's left), its half width
    and height in metres."""
    margin = 1.1 * layout.marker_size
    half_w = max(abs(m.y) + layout.side(m.role) / 2.0 for m in layout.markers) + margin
    height = max(m.z + layout.side(m.role) / 2.0 for m in layout.markers) + margin
    tex = np.full((round(height / _TEXEL_M), round(2 * half_w / _TEXEL_M)), _WHITE, dtype=np.float32)
    for m in layout.markers:
        side = round(layout.side(m.role) / _TEXEL_M)
        cells = layout.marker_bits(m.id).astype(np.float32)
        square = cv2.resize(_BLACK + cells * (_WHITE - _BLACK), (side, side), interpolation=cv2.INTER_NEAREST)
        col = round((half_w - m.y - layout.side(m.role) / 2.0) / _TEXEL_M)
        row = round((height - m.z - layout.side(m.role) / 2.0) / _TEXEL_M)
        tex[row : row + side, col : col + side] = square
    return tex, half_w, height


def synthetic_view(
    camera: CameraModel, layout: DockLayout, robot: RobotConfig, pose: DockPose, *, exposure: float = 1.0
) -> NDArray[np.uint8]:
    """The camera's mono8 image of the dock face at ``pose`` (the DockPose in base_link).

    ``exposure`` scales the grey levels before they clip at 255 (1.6 clips the white face).
    """
    tex, half_w, height = _face_texture(layout)
    w, h = camera.size
    n = _SAMPLES
    # Sample positions: n x n per pixel, pixel centres at integers (OpenCV's convention).
    offsets = (np.arange(n) + 0.5) / n - 0.5
    us = (np.arange(w)[:, None] + offsets[None, :]).reshape(-1)
    vs = (np.arange(h)[:, None] + offsets[None, :]).reshape(-1)
    uu, vv = np.meshgrid(us, vs)
    rays = camera.normalize(np.column_stack([uu.ravel(), vv.ravel()]))
    # Rays in the dock frame, from the camera centre, to the face plane x = 0.
    dock_T_optical = transforms.invert(pose.matrix()) @ robot.base_T_optical()
    d = np.column_stack([rays, np.ones(len(rays))]) @ dock_T_optical[:3, :3].T
    o = dock_T_optical[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[0] / d[:, 0]
    hit = o[None, :] + t[:, None] * d
    hit[~(t > 0)] = np.nan
    map_x = ((half_w - hit[:, 1]) / _TEXEL_M - 0.5).astype(np.float32).reshape(uu.shape)
    map_y = ((height - hit[:, 2]) / _TEXEL_M - 0.5).astype(np.float32).reshape(uu.shape)
    map_x[~np.isfinite(map_x)] = -1e6
    map_y[~np.isfinite(map_y)] = -1e6
    samples = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=_AROUND)
    grey = cv2.resize(samples, (w, h), interpolation=cv2.INTER_AREA)
    return np.asarray(np.clip(np.rint(grey * exposure), 0, 255), dtype=np.uint8)
