"""The Cramér–Rao lower bound on the DockPose (x, y, yaw) from marker corners, and what set-up changes buy.

With Gaussian corner noise of known covariance, no unbiased estimator of the DockPose beats the covariance
(JᵀWJ)⁻¹, J the Jacobian of the corner pixels w.r.t. (x, y, yaw) through the real lens and W the inverse
corner covariance. ``monodock.estimation.planar.solve_planar`` reaches it (tests/test_planar_crlb.py checks that by
Monte Carlo against the simulator's true corners).

Corner noise model for the what-if study (``CornerNoise``): a corner is where two fitted marker edges meet.
An edge of L pixels offers about L independent samples of the intensity step, so its fitted line's offset
has a standard deviation ∝ 1/√L, and so has the corner: σ = c·√((1/L₁ + 1/L₂)/2) for the corner's two
edges of L₁ and L₂ pixels (c/√L for a square), never below ``floor_px``. ``c`` (px^1.5) lumps image noise,
contrast, blur and the detector. OpenCV's SUBPIX refinement follows this law only on markers whose sides
exceed ~31 px; on smaller ones the corner often slides ~0.7 px along an edge (onto an inner cell's edge),
so corners whose harmonic-mean edge length is below ``small_side_px`` get at least ``small_sigma_px``.
The defaults are measured on the simulator's default frames with ``bench/crlb_whatif.py --measure-c``;
``small_sigma_px=0`` gives the pure edge-fit model. The model ignores the angle between the edges (near 90°
on our upright markers) and systematic corner bias (the bound is about random error only).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import ROLES, DockLayout, MarkerSpec
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.errors import ConfigError, InputError
from monodock.estimation.planar import planar_model

__all__ = [
    "DEFAULT_CORNER_C",
    "DEFAULT_SMALL_SIDE_PX",
    "DEFAULT_SMALL_SIGMA_PX",
    "CornerNoise",
    "Variant",
    "WhatIfResult",
    "corner_sides_px",
    "crlb",
    "default_variants",
    "pose_jacobian",
    "scaled_camera",
    "scaled_markers",
    "spaced_markers",
    "visible_roles",
    "what_if",
]

# CornerNoise for OpenCV's SUBPIX corners on the simulator's default frames (noise, blur, exposure, vignetting,
# clutter), measured with `python bench/crlb_whatif.py --measure-c --frames 200 --seed 3`: per-axis σ ≈ 0.6/√L
# from 31 to 180 px (band values of c 0.54-0.67), and 0.46 px on corners with edges under 31 px.
DEFAULT_CORNER_C = 0.6
DEFAULT_SMALL_SIDE_PX = 31.0
DEFAULT_SMALL_SIGMA_PX = 0.46


def visible_roles(
    pose: DockPose, camera: CameraModel, layout: DockLayout, robot: RobotConfig, margin_px: float = 0.0
) -> tuple[str, ...]:
    """The markers whose four corners all fall inside the image (``margin_px`` from its border) at a pose."""
    P = planar_model(camera, layout, robot).optical_points(pose, ROLES).reshape(len(ROLES), 4, 3)
    in_field = np.asarray(camera.in_view_field(P.reshape(-1, 3)).reshape(len(ROLES), 4).all(axis=1), dtype=bool)
    field: list[bool] = in_field.tolist()
    if not any(field):
        return ()
    px = camera.project(P.reshape(-1, 3)).reshape(len(ROLES), 4, 2)
    lo = -0.5 + margin_px
    inside: list[bool] = (
        (px[:, :, 0].min(axis=1) >= lo)
        & (px[:, :, 1].min(axis=1) >= lo)
        & (px[:, :, 0].max(axis=1) <= camera.width - 0.5 - margin_px)
        & (px[:, :, 1].max(axis=1) <= camera.height - 0.5 - margin_px)
    ).tolist()
    return tuple(r for r, f, i in zip(ROLES, field, inside, strict=True) if f and i)


def pose_jacobian(
    pose: DockPose, camera: CameraModel, layout: DockLayout, robot: RobotConfig, roles: Sequence[str]
) -> NDArray[np.float64]:
    """d(corner pixels)/d(x, y, yaw), shape (8R, 3): rows u, v of each corner, markers in ``roles`` order,
    corners in ArUco order; columns per metre, metre and radian.

    Raises:
        InputError: unknown role, no roles, or a corner behind the camera.
    """
    _, J = planar_model(camera, layout, robot).jacobian(pose, roles)
    return J


def _row_sigmas(corner_sigma_px: float | ArrayLike, n: int) -> NDArray[np.float64]:
    """Per-row (u, v of each corner) sigma, shape (2n,), from a number, (n,) or (n, 2)."""
    a = np.asarray(corner_sigma_px, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape == (n,):
        a = np.repeat(a, 2)
    elif a.shape == (n, 2):
        a = a.reshape(-1)
    else:
        raise InputError(f"corner sigma must be a number or have shape ({n},) or ({n}, 2), got {a.shape}")
    if not np.all(np.isfinite(a) & (a > 0)):
        raise InputError("corner sigmas must be positive and finite")
    return a


def crlb(
    pose: DockPose,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    corner_sigma_px: float | ArrayLike,
    roles: Sequence[str] | None = None,
    correlation: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """The Cramér–Rao bound: the 3x3 covariance of (x m, y m, yaw rad) no unbiased estimator beats.

    Args:
        pose: the true DockPose.
        camera, layout, robot: the set-up.
        corner_sigma_px: the corner noise in pixels: a number, one per corner (N,), or per corner and axis
            (N, 2); N = 4 × markers in ``roles`` order.
        roles: the markers observed; default: those fully in view at this pose.
        correlation: None for errors independent between corners and axes; else the 8x8 correlation of one
            marker's corner errors (u, v of its corners in ArUco order), the same for every marker, markers
            independent of each other.

    Returns:
        σ²(JᵀJ)⁻¹ for iid noise, (JᵀWJ)⁻¹ in general; infinite where the pose is unobservable.

    Raises:
        InputError: no marker in view, bad sigma or correlation, a corner behind the camera.
    """
    use = tuple(roles) if roles is not None else visible_roles(pose, camera, layout, robot)
    if not use:
        raise InputError(f"no dock marker fully in view at {pose}")
    J = pose_jacobian(pose, camera, layout, robot, use)
    Jw = J / _row_sigmas(corner_sigma_px, len(J) // 2)[:, None]
    if correlation is not None:
        C = np.asarray(correlation, dtype=np.float64)
        if C.shape != (8, 8) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T):
            raise InputError("a corner correlation must be a finite symmetric 8x8 matrix")
        try:
            L = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:
            raise InputError("a corner correlation must be positive definite") from None
        # Whitening per marker: L⁻¹ applied to its 8 sigma-scaled rows.
        Jw = np.linalg.solve(L, Jw.reshape(-1, 8, 3)).reshape(-1, 3)
    try:
        cov = np.linalg.inv(Jw.T @ Jw)
    except np.linalg.LinAlgError:
        return np.full((3, 3), np.inf)
    return np.asarray(cov, dtype=np.float64)


# --- corner noise ---------------------------------------------------------------------------------------


def corner_sides_px(corners: ArrayLike) -> NDArray[np.float64]:
    """Lengths in pixels of each corner's two edges, shape (N, 2), for markers' corners stacked (N, 2), ArUco
    order per marker (corner k's edges run to corners k−1 and k+1 of its marker)."""
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
    to_next = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2)
    to_prev = np.roll(to_next, 1, axis=1)
    return np.stack([to_prev, to_next], axis=2).reshape(-1, 2)


@dataclass(frozen=True)
class CornerNoise:
    """Corner noise in pixels: σ = max(c·√((1/L₁ + 1/L₂)/2), floor_px), and at least ``small_sigma_px`` when
    the corner's edges (harmonic mean) are shorter than ``small_side_px`` (module doc).

    Attributes:
        c: px^1.5; σ of a corner of a square marker L px on a side is c/√L.
        floor_px: the smallest σ any corner gets (quantisation, calibration residue).
        small_side_px: edge length below which the detector's small-marker behaviour sets in.
        small_sigma_px: σ of corners on such small markers (0: the pure edge-fit model).
    """

    c: float = DEFAULT_CORNER_C
    floor_px: float = 0.02
    small_side_px: float = DEFAULT_SMALL_SIDE_PX
    small_sigma_px: float = DEFAULT_SMALL_SIGMA_PX

    def __post_init__(self) -> None:
        ok = self.c > 0 and math.isfinite(self.c) and self.floor_px >= 0
        if not (ok and self.small_side_px >= 0 and self.small_sigma_px >= 0):
            raise InputError(f"corner noise needs c > 0 and non-negative floor and small-marker terms, got {self}")

    def sigma(self, corners: ArrayLike) -> NDArray[np.float64]:
        """Per-corner σ in pixels, shape (N,), of markers' corners stacked (N, 2), ArUco order per marker."""
        sides = np.maximum(corner_sides_px(corners), 1e-9)
        inverse = 0.5 * (1.0 / sides[:, 0] + 1.0 / sides[:, 1])
        s = np.maximum(self.c * np.sqrt(inverse), self.floor_px)
        small = inverse > 1.0 / self.small_side_px if self.small_side_px > 0 else np.zeros(len(s), dtype=bool)
        return np.asarray(np.where(small, np.maximum(s, self.small_sigma_px), s), dtype=np.float64)


# --- what if ----------------------------------------------------------------------------------------------


def scaled_markers(layout: DockLayout, factor: float) -> DockLayout:
    """The layout with every marker's side × factor (centres unchanged)."""
    return replace(layout, marker_size=layout.marker_size * factor)


def spaced_markers(layout: DockLayout, factor: float) -> DockLayout:
    """The layout with the markers' lateral offsets (y) from the centre marker's × factor."""
    yc = layout.marker("center").y
    markers = tuple(MarkerSpec(m.role, m.id, yc + (m.y - yc) * factor, m.z) for m in layout.markers)
    return replace(layout, markers=(markers[0], markers[1], markers[2]))


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
