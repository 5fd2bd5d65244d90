"""Camera nuisances applied to a rendered radiance image: optics first, then the sensor.

Order of a real camera: vignetting and blur happen in the optics on linear light, then exposure, shot and
read noise on the sensor, then the gamma curve and 8-bit quantisation. Every random draw comes from the
generator passed in.
"""

from __future__ import annotations

import functools
import math
import statistics
from dataclasses import dataclass, fields, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.compiled import kernel

__all__ = ["Nuisances", "add_glare", "apply_nuisances"]


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
        glare_probability: chance per frame of a specular highlight (a lamp's reflection on a glossy print) over
            part of one dock marker in view: a Gaussian spot of added light that saturates at its centre.
        supersample: S of the renderer's S x S samples on the pixels where three surfaces meet or painted
            patches overlap; every other edge pixel is integrated exactly (``monodock.sim.render``).
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
    glare_probability: float = 0.0
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


@functools.lru_cache(maxsize=4)
def _vignetting_gain(height: int, width: int, vignetting: float) -> NDArray[np.float32]:
    """1 - v r^2, r the distance from the image centre over the half diagonal (cached: the same every frame)."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    r2 = ((xx - (width - 1) / 2) ** 2 + (yy - (height - 1) / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
    gain: NDArray[np.float32] = (1.0 - vignetting * r2).astype(np.float32)
    gain.flags.writeable = False
    return gain


_NO_VIGNETTING = np.ones((1, 1), dtype=np.float32)


@functools.lru_cache(maxsize=1)
def _normal_quantiles() -> NDArray[np.float64]:
    """The standard normal's quantiles at the centres of 65536 equal-probability bins, scaled to unit variance.

    Why: a uniform 16-bit draw and a table lookup give a normal deviate at a tenth of the cost of numpy's
    normal generator, which was a third of a frame's nuisances. The table reaches +-4.2 sigma; a sensor's read
    and shot noise rounded to 8 bits cannot tell the difference.
    """
    inv_cdf = statistics.NormalDist().inv_cdf
    q = np.array([inv_cdf((i + 0.5) / 65536) for i in range(65536)])
    return q / float(np.sqrt(np.mean(q**2)))


@kernel
def _expose(
    img: NDArray[np.float32], vignette: NDArray[np.float32], gain: float, read_noise: float, shot_noise: float,
    gamma: float, draws: NDArray[np.uint16], quantiles: NDArray[np.float64],
) -> NDArray[np.uint8]:  # fmt: skip
    """The sensor in one pass: vignetting and exposure gain, clipping, shot and read noise, clipping, gamma,
    8-bit rounding. ``vignette`` of shape (1, 1) is no vignetting."""
    h, w = img.shape
    vignetted = vignette.shape[0] == h
    out = np.empty((h, w), dtype=np.uint8)
    noisy = read_noise > 0.0 or shot_noise > 0.0
    for i in range(h):
        for j in range(w):
            v = img[i, j] * vignette[i, j] if vignetted else img[i, j]
            dn = min(max(v * gain, 0.0), 1.0) * 255.0
            if noisy:
                dn += quantiles[draws[i, j]] * np.sqrt(read_noise * read_noise + shot_noise * dn)
                dn = min(max(dn, 0.0), 255.0)
            if gamma != 1.0:
                dn = 255.0 * (dn / 255.0) ** (1.0 / gamma)
            out[i, j] = np.uint8(np.rint(dn))
    return out


def add_glare(
    radiance: NDArray[np.float32], quads: list[NDArray[np.float64]], rng: np.random.Generator
) -> NDArray[np.float32]:
    """A specular highlight over one of ``quads`` (image corners, 4x2, of the markers in view), drawn at random: a
    Gaussian spot centred inside the quad, its sigma 15-35 % of the marker's side, its peak 1-2.5 times white paper's
    radiance added (the sensor clips it: a washed-out patch with a soft rim)."""
    if not quads:
        return radiance
    quad = quads[int(rng.integers(len(quads)))]
    a, b = rng.uniform(0.1, 0.9, size=2)
    top, bottom = quad[0] + a * (quad[1] - quad[0]), quad[3] + a * (quad[2] - quad[3])
    cx, cy = top + b * (bottom - top)
    side = float(np.mean(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1)))
    sigma = max(1.0, float(rng.uniform(0.15, 0.35)) * side)
    peak = float(rng.uniform(1.0, 2.5))
    h, w = radiance.shape
    r = int(math.ceil(4 * sigma))
    x0, x1, y0, y1 = max(0, int(cx) - r), min(w, int(cx) + r + 1), max(0, int(cy) - r), min(h, int(cy) + r + 1)
    if x0 >= x1 or y0 >= y1:
        return radiance
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    out = radiance.copy()
    out[y0:y1, x0:x1] += peak * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sigma * sigma))
    return out


def apply_nuisances(radiance: NDArray[np.float32], nuisances: Nuisances, rng: np.random.Generator) -> NDArray[np.uint8]:
    """The 8-bit image a camera would record of a radiance (albedo) image."""
    img = np.asarray(radiance, dtype=np.float32)
    h, w = img.shape
    # Vignetting is applied by _expose, after the blur: the gain changes by under 0.1 % across a blur kernel.
    vignette = _vignetting_gain(h, w, nuisances.vignetting) if nuisances.vignetting > 0 else _NO_VIGNETTING
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
    if nuisances.shot_noise > 0 or nuisances.read_noise > 0:
        draws = rng.integers(0, 65536, size=(h, w), dtype=np.uint16)
    else:
        draws = np.zeros((1, 1), dtype=np.uint16)
    return _expose(
        np.ascontiguousarray(img, dtype=np.float32),
        vignette,
        float(gain),
        float(nuisances.read_noise),
        float(nuisances.shot_noise),
        float(nuisances.gamma),
        draws,
        _normal_quantiles(),
    )
