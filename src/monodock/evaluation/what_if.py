"""What set-up changes buy: the Cramér–Rao bound of variants of a dock layout, camera and mount, by depth band.

Bigger markers, markers further apart, a sharper camera with more pixels: each variant's bound against the
set-up's own, on the same poses, with the corner noise of ``estimation.corner_noise.CornerNoise``
(``bench/crlb_whatif.py`` prints the table; the evaluation report's physical-limit section shows it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.errors import ConfigError, InputError
from monodock.estimation.corner_noise import CornerNoise
from monodock.estimation.crlb import visible_roles
from monodock.estimation.planar import planar_model

__all__ = [
    "Variant",
    "WhatIfResult",
    "default_variants",
    "scaled_camera",
    "scaled_markers",
    "spaced_markers",
    "what_if",
]


def scaled_markers(layout: DockLayout, factor: float) -> DockLayout:
    """The layout with every marker's side × factor (centres unchanged)."""
    return replace(layout, marker_size=layout.marker_size * factor)


def spaced_markers(layout: DockLayout, factor: float) -> DockLayout:
    """The layout with the markers' lateral offsets (y) from the centre marker's × factor."""
    yc = layout.marker("center").y
    return replace(layout, markers=tuple(replace(m, y=yc + (m.y - yc) * factor) for m in layout.markers))


def scaled_camera(camera: CameraModel, factor: float) -> CameraModel:
    """The same lens on a sensor with ``factor`` × the pixels each way: field of view and distortion kept,
    focal lengths × factor, principal point scaled about the image's corner (pixel centres at integers)."""
    return CameraModel.from_intrinsics(
        round(camera.width * factor),
        round(camera.height * factor),
        camera.fx * factor,
        camera.fy * factor,
        (camera.cx + 0.5) * factor - 0.5,
        (camera.cy + 0.5) * factor - 0.5,
        camera.dist,
        name=f"{camera.name}_x{factor:g}",
    )


@dataclass(frozen=True)
class Variant:
    """One set-up to bound: a name, a camera, a layout and a robot."""

    name: str
    camera: CameraModel
    layout: DockLayout
    robot: RobotConfig


def default_variants(camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> list[Variant]:
    """The current set-up and the changes worth pricing.

    - markers ×1.5 and ×2 (same centres; at ×2 the default markers touch);
    - side markers' spacing ×1.5;
    - camera resolution ×2 (same lens, twice the pixels each way: 640x480 → 1280x960, focal ×2);
    - a combination that fits the default 60 cm charger face: markers ×1.5 with the side markers moved out
      until their outer edges meet the face's edges (y ±0.225 m for the default layout) and the ×2 camera.
    """
    half_face = 0.30
    yc = layout.marker("center").y
    reach = max(abs(m.y - yc) for m in layout.markers if m.role != "center")

    def combo() -> DockLayout:
        big = scaled_markers(layout, 1.5)
        fit = (half_face - big.marker_size / 2) / reach if reach > 0 else 1.0
        return spaced_markers(big, max(fit, 1.0))

    makers: list[tuple[str, Callable[[], tuple[CameraModel, DockLayout]]]] = [
        ("current", lambda: (camera, layout)),
        ("marker x1.5", lambda: (camera, scaled_markers(layout, 1.5))),
        ("marker x2", lambda: (camera, scaled_markers(layout, 2.0))),
        ("spacing x1.5", lambda: (camera, spaced_markers(layout, 1.5))),
        ("resolution x2", lambda: (scaled_camera(camera, 2.0), layout)),
        ("combination", lambda: (scaled_camera(camera, 2.0), combo())),
    ]
    out = []
    for name, make in makers:
        try:
            cam, lay = make()
        except ConfigError:
            continue  # e.g. markers x2 would overlap on a tightly spaced layout
        out.append(Variant(name, cam, lay, robot))
    return out


@dataclass(frozen=True)
class WhatIfResult:
    """Bound standard deviations per variant and depth band.

    Attributes:
        variants: the variants' names; the first is the reference for ratios.
        bands: (low, high) depth from the camera, metres (the papers' depth: DockPose.x − camera_mount.x).
        sd: shape (variants, bands, 3): the root-mean-square over the band's poses of the bound's standard
            deviation of x (m), y (m) and yaw (rad), i.e. √(mean variance): the error a bound-reaching
            estimator has on average over the band. NaN where no pose counted.
        poses: shape (variants, bands): poses counted (the variant saw at least one marker fully).
        overall: shape (variants, 3): the same over every counted pose.
    """

    variants: tuple[str, ...]
    bands: tuple[tuple[float, float], ...]
    sd: NDArray[np.float64]
    poses: NDArray[np.int64]
    overall: NDArray[np.float64]

    def ratio(self) -> NDArray[np.float64]:
        """sd / the first variant's sd, shape (variants, bands, 3): below 1 is better."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(self.sd / self.sd[:1], dtype=np.float64)

    def overall_ratio(self) -> NDArray[np.float64]:
        """overall / the first variant's overall, shape (variants, 3)."""
        return np.asarray(self.overall / self.overall[:1], dtype=np.float64)


def _band_poses(
    lo: float,
    hi: float,
    camera_x: float,
    lateral: tuple[float, float],
    yaw_deg: tuple[float, float],
    grid: tuple[int, int, int],
    samples: int | None,
    rng: np.random.Generator | None,
) -> list[DockPose]:
    """Poses in one depth band: a grid (band-cell centres in depth, end points in lateral and yaw) or a
    uniform sample, as ``sim.PoseDistribution`` draws them."""
    if samples is not None:
        g = rng or np.random.default_rng(0)
        return [
            DockPose(float(g.uniform(lo, hi)) + camera_x, float(g.uniform(*lateral)), math.radians(g.uniform(*yaw_deg)))
            for _ in range(samples)
        ]
    nd, ny, na = grid
    depths = lo + (np.arange(nd) + 0.5) / nd * (hi - lo)
    ys = np.linspace(*lateral, ny)
    yaws = np.radians(np.linspace(*yaw_deg, na))
    return [DockPose(float(d) + camera_x, float(y), float(a)) for d in depths for y in ys for a in yaws]


def what_if(
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    *,
    variants: Sequence[Variant] | None = None,
    noise: CornerNoise | None = None,
    depth_range: tuple[float, float] = (0.25, 2.50),
    band_width: float = 0.25,
    lateral: tuple[float, float] = (-0.40, 0.40),
    yaw_deg: tuple[float, float] = (-30.0, 30.0),
    grid: tuple[int, int, int] = (5, 9, 7),
    samples_per_band: int | None = None,
    rng: np.random.Generator | None = None,
    margin_px: float = 3.0,
) -> WhatIfResult:
    """How the Cramér–Rao bound changes with the set-up, by depth band: "which change buys how much".

    Poses: per band, a grid of ``grid`` = (depths, lateral offsets, yaws) over the band, ``lateral`` and
    ``yaw_deg``, or ``samples_per_band`` uniform draws from ``rng``; a pose counts when the first
    variant (the reference) sees the centre marker fully in view ``margin_px`` from the border (the
    simulator's default PoseDistribution rule). Each variant is bounded at those poses with the markers
    it sees fully (same margin), each corner's σ from ``noise`` (default ``CornerNoise()``) at that
    variant's pixel size; a pose where a variant sees none is left out of its count.

    Returns:
        The per-band RMS of the bound's standard deviations, the pose counts and the overall figures.
    """
    noise = noise or CornerNoise()
    vs = list(variants) if variants is not None else default_variants(camera, layout, robot)
    if not vs:
        raise InputError("what_if needs at least one variant")
    if not (0 < depth_range[0] < depth_range[1]) or not band_width > 0:
        raise InputError(f"bad depth range {depth_range} or band width {band_width}")
    n_bands = max(1, round((depth_range[1] - depth_range[0]) / band_width))
    edges = depth_range[0] + band_width * np.arange(n_bands + 1)
    bands = tuple((float(edges[i]), float(edges[i + 1])) for i in range(n_bands))
    var_sum = np.zeros((len(vs), n_bands, 3))
    counts = np.zeros((len(vs), n_bands), dtype=np.int64)
    ref = vs[0]
    for b, (lo, hi) in enumerate(bands):
        for pose in _band_poses(lo, hi, robot.camera_mount.x, lateral, yaw_deg, grid, samples_per_band, rng):
            if "center" not in visible_roles(pose, ref.camera, ref.layout, ref.robot, margin_px):
                continue
            for k, v in enumerate(vs):
                roles = visible_roles(pose, v.camera, v.layout, v.robot, margin_px)
                if not roles:
                    continue
                px, J = planar_model(v.camera, v.layout, v.robot).jacobian(pose, roles)
                Jw = J / np.repeat(noise.sigma(px), 2)[:, None]
                try:
                    cov = np.linalg.inv(Jw.T @ Jw)
                except np.linalg.LinAlgError:
                    continue
                var_sum[k, b] += np.diag(cov)
                counts[k, b] += 1
    with np.errstate(divide="ignore", invalid="ignore"):
        sd = np.sqrt(var_sum / counts[:, :, None])
        overall = np.sqrt(var_sum.sum(axis=1) / counts.sum(axis=1)[:, None])
    return WhatIfResult(tuple(v.name for v in vs), bands, sd, counts, overall)
