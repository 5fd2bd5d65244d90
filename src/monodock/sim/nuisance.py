"""Camera nuisances applied to a rendered radiance image: optics first, then the sensor.

Order of a real camera: vignetting and blur happen in the optics on linear light, then exposure, shot and
read noise on the sensor, then the gamma curve and 8-bit quantisation. Every random draw comes from the
generator passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["Nuisances", "apply_nuisances"]


@dataclass(frozen=True)
class Nuisances:
    """Knobs of the camera and scene nuisances, with defaults of a cheap indoor webcam.

    Attributes:
        exposure: gain from albedo to the sensor's full scale (1.0: white paper near 85 % of full scale).
        exposure_jitter: per-frame log-normal spread of the gain (auto-exposure, lighting changes).
        gamma: display gamma; the output is ``linear ** (1 / gamma)`` (1.0 keeps it linear).
        vignetting: relative light fall-off at the image corners (cos^4-like, quadratic in radius).
        defocus_px: Gaussian sigma of the lens blur, pixels.
        motion_blur_px: length of a straight motion streak, pixels (0: none).
        motion_blur_angle_deg: its direction; None draws one per frame.
        read_noise: sensor read noise, digital numbers (0..255 scale), standard deviation.
        shot_noise: photon noise variance per digital number of signal.
        clutter: posters, floor marks and ArUco markers of other ids around the charger.
        occluder_probability: chance per frame that an object hides part of one dock marker.
        supersample: S of the renderer's S x S samples on edge pixels.
    """

    exposure: float = 1.0
    exposure_jitter: float = 0.15
    gamma: float = 1.0
    vignetting: float = 0.25
    defocus_px: float = 0.6
    motion_blur_px: float = 0.0
    motion_blur_angle_deg: float | None = None
    read_noise: float = 1.5
    shot_noise: float = 0.08
    clutter: bool = True
    occluder_probability: float = 0.0
    supersample: int = 16

    @classmethod
    def clean(cls) -> Nuisances:
        """No nuisance at all: the exact render, quantised to 8 bits."""
        return cls(
            exposure_jitter=0.0,
            vignetting=0.0,
            defocus_px=0.0,
            read_noise=0.0,
            shot_noise=0.0,
            clutter=False,
        )

    def updated(self, **changes: object) -> Nuisances:
        """A copy with some knobs changed (unknown names raise TypeError)."""
        known = {f.name for f in fields(self)}
        bad = sorted(set(changes) - known)
        if bad:
            raise TypeError(f"unknown nuisance knob(s): {', '.join(bad)}")
        return replace(self, **changes)  # type: ignore[arg-type]


def _motion_kernel(length: float, angle: float) -> NDArray[np.float32]:
    """A normalised line kernel of the given length (pixels) and direction (radians), anti-aliased."""
    half = int(math.ceil(length / 2.0)) + 1
    size = 2 * half + 1
    k = np.zeros((size, size), np.float32)
    n = max(8, int(length * 8))
    for s in np.linspace(-length / 2.0, length / 2.0, n):
        x, y = half + s * math.cos(angle), half + s * math.sin(angle)
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        k[y0, x0] += (1 - fx) * (1 - fy)
        k[y0, x0 + 1] += fx * (1 - fy)
        k[y0 + 1, x0] += (1 - fx) * fy
        k[y0 + 1, x0 + 1] += fx * fy
    return np.asarray(k / k.sum(), dtype=np.float32)


def apply_nuisances(radiance: NDArray[np.float32], nuisances: Nuisances, rng: np.random.Generator) -> NDArray[np.uint8]:
    """The 8-bit image a camera would record of a radiance (albedo) image."""
    img = radiance.astype(np.float32, copy=True)
    h, w = img.shape
    if nuisances.vignetting > 0:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        img *= 1.0 - nuisances.vignetting * r2
    if nuisances.defocus_px > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), nuisances.defocus_px, borderType=cv2.BORDER_REFLECT))
    if nuisances.motion_blur_px > 0:
        angle = nuisances.motion_blur_angle_deg
        theta = math.radians(angle) if angle is not None else float(rng.uniform(0, math.pi))
        kernel = _motion_kernel(nuisances.motion_blur_px, theta)
        img = np.asarray(cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT))
    gain = nuisances.exposure
    if nuisances.exposure_jitter > 0:
        gain *= float(np.exp(rng.normal(0.0, nuisances.exposure_jitter)))
    dn = np.clip(img * gain, 0.0, 1.0) * 255.0
    if nuisances.shot_noise > 0 or nuisances.read_noise > 0:
        sigma = np.sqrt(nuisances.read_noise**2 + nuisances.shot_noise * dn)
        dn = dn + rng.standard_normal(dn.shape).astype(np.float32) * sigma
    dn = np.clip(dn, 0.0, 255.0)
    if nuisances.gamma != 1.0:
        dn = 255.0 * (dn / 255.0) ** (1.0 / nuisances.gamma)
    return np.asarray(np.rint(dn), dtype=np.uint8)
