"""Pictures of a calibration: where the checkerboard's corners covered the image, and LiDAR points on a frame."""

from __future__ import annotations

from io import BytesIO
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.calibrate.intrinsics import IntrinsicsResult
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.overlay import draw_overlay
from monodock.perception.detect import Detection
from monodock.report.plotting import plt

__all__ = ["coverage_png", "overlay_png"]


def coverage_png(result: IntrinsicsResult) -> bytes:
    """A PNG heat map of where the used views' corners fell in the image, with every corner dotted on top."""
    cam = result.camera
    w, h = cam.width, cam.height
    fig, ax = plt.subplots(figsize=(7.5, 7.5 * h / w + 0.9), dpi=100)
    try:
        im = ax.imshow(
            result.coverage,
            extent=(0, w, h, 0),
            cmap="viridis",
            interpolation="nearest",
            vmin=0,
            vmax=max(1, int(result.coverage.max())),
        )
        gr, gc = result.coverage.shape
        for r in range(gr):
            for c in range(gc):
                n = int(result.coverage[r, c])
                colour = "red" if n == 0 else "white"
                ax.text((c + 0.5) * w / gc, (r + 0.5) * h / gr, str(n), ha="center", va="center", color=colour)
        for v in result.views:
            if v.used and v.corners is not None:
                ax.plot(v.corners[:, 0], v.corners[:, 1], ".", ms=1.5, color="orange", alpha=0.6)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
        ax.set_title(
            f"corner coverage {result.coverage_fraction:.0%} of {gc}x{gr} cells - "
            f"{result.used} views, RMS {result.rms_px:.3f} px"
        )
        fig.colorbar(im, ax=ax, label="corners per cell", fraction=0.035, pad=0.02)
        fig.tight_layout()
        buf = BytesIO()
        fig.savefig(buf, format="png")
        return buf.getvalue()
    finally:
        plt.close(fig)


def overlay_png(
    image: NDArray[np.uint8],
    pixels: NDArray[np.float64],
    selected: NDArray[np.bool_],
    camera: CameraModel,
    robot: RobotConfig,
    layout: DockLayout | None = None,
    detection: Any = None,
) -> bytes:
    """PNG bytes of LiDAR points (pixels, e.g. from label.project_to_image) drawn on a camera frame (Fig. 8c)."""
    det = detection if detection is not None else Detection({}, (), (image.shape[1], image.shape[0]))
    pic = draw_overlay(
        image, det, layout or DockLayout.default(), camera, robot, lidar_px=pixels, lidar_selected=selected
    )
    ok, buf = cv2.imencode(".png", pic)
    if not ok:
        raise InputError("cannot encode the overlay PNG")
    return bytes(buf.tobytes())
