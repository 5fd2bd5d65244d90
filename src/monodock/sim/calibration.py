"""Simulated calibration data: the LiDAR point / pixel pairs a person would click in simulated views."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.pose import DockPose
from monodock.core.projection import project_to_image
from monodock.sim.simulator import Simulator

__all__ = ["simulated_pairs"]


def simulated_pairs(
    sim: Simulator,
    poses: Sequence[DockPose],
    *,
    seed: int,
    pixel_noise_px: float = 0.5,
    per_view: int = 12,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The pairs a person would click in simulated views: charger-face returns and the pixels where they hit.

    For each pose the simulator's LiDAR scans the charger (with its range noise); returns whose beam truly
    hits the face (known from the pose and the true laser mount) keep their measured position in the laser
    frame, paired with the projection of the true hit point through the true camera, plus ``pixel_noise_px``
    of Gaussian noise (a careful click). Up to ``per_view`` evenly spread returns per pose.
    """
    rng = np.random.default_rng(seed)
    face = sim.world.surfaces[sim.world.surface_index("charger_face")]
    half_w = face.s_len / 2.0
    base_T_laser = sim.robot.base_T_laser()
    pts_out: list[NDArray[np.float64]] = []
    px_out: list[NDArray[np.float64]] = []
    for k, pose in enumerate(poses):
        scan = sim.scan(pose, rng=np.random.default_rng([seed, k]))
        dock_T_laser = transforms.invert(pose.matrix()) @ base_T_laser
        a = scan.angles()
        d = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1) @ dock_T_laser[:3, :3].T
        o = dock_T_laser[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[0] / d[:, 0]
        hit = o + t[:, None] * d
        r = scan.ranges.astype(np.float64)
        on_face = (
            np.isfinite(t)
            & (t > 0)
            & (np.abs(hit[:, 1]) < half_w - 0.01)
            & (hit[:, 2] > 0)
            & (hit[:, 2] < face.t_len)
            & np.isfinite(r)
            & (np.abs(r - t) < 0.05)
        )
        idx = np.flatnonzero(on_face)
        if len(idx) == 0:
            continue
        idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(per_view, len(idx))).round().astype(int))]
        measured = np.stack([r[idx] * np.cos(a[idx]), r[idx] * np.sin(a[idx])], axis=1)
        true_base = transforms.apply(pose.matrix(), hit[idx])
        px = project_to_image(true_base, sim.camera, sim.robot)
        px = px + rng.normal(0.0, pixel_noise_px, px.shape)
        w, h = sim.camera.size
        ok = np.all(np.isfinite(px), axis=1) & (px[:, 0] > 0) & (px[:, 0] < w - 1) & (px[:, 1] > 0) & (px[:, 1] < h - 1)
        pts_out.append(measured[ok])
        px_out.append(px[ok])
    if not pts_out:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.vstack(pts_out), np.vstack(px_out)
