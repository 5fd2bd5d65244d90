"""The physical limit: every method's error as a ratio to the Cramér–Rao bound, on a held-out dataset with truth.

The corner noise is measured on the same rows: the refined corners (``monodock.perception.refine``) against the exact
projection of the markers at the true pose, fitted to the model of ``crlb.CornerNoise`` (σ = c·√((1/L₁ + 1/L₂)/2)
px for a corner between edges of L₁ and L₂ px). Each row's bound is then (JᵀWJ)⁻¹ at its true pose with the
markers the refiner measured, and a band's bound is the root of its rows' mean variance: the RMS error an
efficient, unbiased estimator would have there. A ratio near 1 means better code cannot help; only better
markers or a better camera can (``crlb.what_if`` prices them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.layout import ROLES
from monodock.core.pose import DockPose
from monodock.errors import InputError
from monodock.estimation.corner_noise import CornerNoise, corner_sides_px
from monodock.estimation.crlb import crlb
from monodock.estimation.planar import planar_model
from monodock.evaluation.what_if import WhatIfResult, what_if
from monodock.learning.dataset import Dataset
from monodock.perception.features import refined_detection_from_row

__all__ = [
    "BANDS_M",
    "SIDE_BINS_PX",
    "CornerNoiseFit",
    "LimitRow",
    "PhysicalLimit",
    "bounds_by_row",
    "limit_rows",
    "measure_corner_noise",
    "physical_limit",
]

BANDS_M = tuple((0.25 + 0.25 * k, 0.5 + 0.25 * k) for k in range(9))


# Bins of a corner's edge length (harmonic mean of its two edges, px) for the measured noise.
SIDE_BINS_PX = (0.0, 25.0, 35.0, 50.0, 70.0, 100.0, 140.0, 200.0, math.inf)


@dataclass(frozen=True)
class CornerNoiseFit:
    """Refined corners against the truth.

    Attributes:
        sigma_px: per bin of SIDE_BINS_PX, the per-axis standard deviation of the corner error (its mean
            removed: the bound is about noise, a bias shows in the estimators' errors instead), NaN if empty.
        counts: corners per bin.
        c, floor_px: the least-squares fit sigma^2 = c^2 (1/L1 + 1/L2)/2 + floor^2, for the what-if study.
        outward_mean_px: mean error along the true centre-to-corner direction (negative: inside).
        rms_px: RMS of the 2D corner error.
        correlation: the 8x8 correlation of one marker's corner errors (u, v per corner, ArUco order), each
            scaled by its corner's sigma, pooled over every fully measured marker; None with fewer than 40.
            Corners share their marker's fitted sides, so their errors are not independent.
    """

    sigma_px: tuple[float, ...]
    counts: tuple[int, ...]
    c: float
    floor_px: float
    outward_mean_px: float
    rms_px: float
    correlation: NDArray[np.float64] | None = None

    @property
    def corners(self) -> int:
        return sum(self.counts)

    @property
    def noise(self) -> CornerNoise:
        """The fitted c/sqrt(L) model (no small-marker term: the refiner has none of SUBPIX's slides)."""
        return CornerNoise(c=self.c, floor_px=self.floor_px, small_sigma_px=0.0)

    def sigma(self, corners: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per-corner sigma (px) of stacked corners from the measured bins (the fit where a bin is empty)."""
        sides = np.maximum(corner_sides_px(corners), 1e-9)
        length = 2.0 / (1.0 / sides[:, 0] + 1.0 / sides[:, 1])
        k = np.clip(np.searchsorted(SIDE_BINS_PX, length, side="right") - 1, 0, len(self.sigma_px) - 1)
        binned = np.asarray(self.sigma_px)[k]
        return np.where(np.isfinite(binned), binned, self.noise.sigma(corners))


def _refined_rows(dataset: Dataset) -> list[tuple[int, dict[str, NDArray[np.float64]]]]:
    """Per row with truth: the refined corners of the markers the refiner measured."""
    camera, layout = dataset.camera(), dataset.layout()
    raw, refined = dataset.raw_features(), dataset.refined_corners()
    truth_ok = np.isfinite(np.asarray(dataset["truth_x_m"], dtype=np.float64))
    out = []
    for i in np.flatnonzero(truth_ok):
        det = refined_detection_from_row(raw[i], refined[i], layout, camera.size)
        corners = {r: det.observations[r].corners for r in det.roles_seen if r not in det.unrefined}
        if corners:
            out.append((int(i), corners))
    return out


def _truth(dataset: Dataset, i: int) -> DockPose:
    return DockPose(
        float(dataset["truth_x_m"][i]), float(dataset["truth_y_m"][i]), math.radians(float(dataset["truth_yaw_deg"][i]))
    )


def measure_corner_noise(dataset: Dataset) -> CornerNoiseFit:
    """The refined corners' noise, from every row with truth (see CornerNoiseFit)."""
    model = planar_model(dataset.camera(), dataset.layout(), dataset.robot())
    errs, inverse, outward, trues = [], [], [], []
    for i, corners in _refined_rows(dataset):
        roles = tuple(r for r in ROLES if r in corners)
        true = model.project(_truth(dataset, i), roles)
        err = np.concatenate([corners[r] for r in roles]) - true
        trues.append(true)
        sides = np.maximum(corner_sides_px(true), 1e-9)
        centre = true.reshape(-1, 4, 2).mean(axis=1).repeat(4, axis=0)
        out_dir = true - centre
        out_dir /= np.linalg.norm(out_dir, axis=1, keepdims=True)
        errs.append(err)
        inverse.append(0.5 * (1.0 / sides[:, 0] + 1.0 / sides[:, 1]))
        outward.append(np.sum(err * out_dir, axis=1))
    if not errs or sum(len(e) for e in errs) < 40:
        raise InputError("fewer than 40 refined corners with truth to measure the corner noise on")
    e, inv, out = np.concatenate(errs), np.concatenate(inverse), np.concatenate(outward)
    gross = np.linalg.norm(e, axis=1) > 3.0  # a mis-detection, not noise
    e, inv, out = e[~gross], inv[~gross], out[~gross]
    length = 1.0 / inv
    k = np.searchsorted(SIDE_BINS_PX, length, side="right") - 1
    sig, counts = [], []
    for b in range(len(SIDE_BINS_PX) - 1):
        sel = k == b
        counts.append(int(sel.sum()))
        sig.append(float(np.sqrt(np.mean(np.var(e[sel], axis=0)))) if sel.sum() >= 8 else math.nan)
    per_axis_sq = 0.5 * np.sum((e - e.mean(axis=0)) ** 2, axis=1)
    (c2, f2), *_ = np.linalg.lstsq(np.column_stack([inv, np.ones_like(inv)]), per_axis_sq, rcond=None)
    fit = CornerNoiseFit(
        tuple(sig),
        tuple(counts),
        math.sqrt(max(float(c2), 1e-8)),
        math.sqrt(max(float(f2), 0.0)),
        float(np.mean(out)),
        float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
    )
    return replace(fit, correlation=_marker_correlation(errs, trues, fit))


def _marker_correlation(
    errs: list[NDArray[np.float64]], trues: list[NDArray[np.float64]], fit: CornerNoiseFit
) -> NDArray[np.float64] | None:
    """The 8x8 correlation of a marker's sigma-scaled corner errors (``CornerNoiseFit.correlation``)."""
    scaled = []
    for err, true in zip(errs, trues, strict=True):
        z = (err / fit.sigma(true)[:, None]).reshape(-1, 8)
        scaled.append(z[np.all(np.abs(err.reshape(-1, 8)) <= 3.0, axis=1)])  # no mis-detections
    z = np.concatenate(scaled)
    if len(z) < 40:
        return None
    cov = np.cov(z, rowvar=False)
    d = np.sqrt(np.diag(cov))
    return np.asarray(cov / np.outer(d, d), dtype=np.float64)


def bounds_by_row(dataset: Dataset, noise: CornerNoiseFit, *, correlated: bool = False) -> NDArray[np.float64]:
    """Per row, the 3x3 Cramér–Rao bound at the true pose for the markers refined there (NaN: none).

    Corners independent; with ``correlated``, with the measured correlation of a marker's corners (if any).
    """
    camera, layout, robot = dataset.camera(), dataset.layout(), dataset.robot()
    model = planar_model(camera, layout, robot)
    out = np.full((len(dataset), 3, 3), np.nan)
    for i, corners in _refined_rows(dataset):
        roles = tuple(r for r in ROLES if r in corners)
        pose = _truth(dataset, i)
        try:
            sigma = noise.sigma(model.project(pose, roles))
            out[i] = crlb(pose, camera, layout, robot, sigma, roles, noise.correlation if correlated else None)
        except InputError:
            continue
    return out


@dataclass(frozen=True)
class LimitRow:
    """One method in one band: rows, its RMS error, the bound's RMS standard deviation and their ratios."""

    method: str
    band: str
    rows: int
    rms: tuple[float, float, float]  # cm, cm, degrees
    bound: tuple[float, float, float]  # cm, cm, degrees

    @property
    def ratio(self) -> tuple[float, float, float]:
        return tuple(a / b if b > 0 else math.nan for a, b in zip(self.rms, self.bound, strict=True))  # type: ignore[return-value]


def limit_rows(
    depth_from_camera: NDArray[np.float64],
    truth: NDArray[np.float64],
    poses: Mapping[str, NDArray[np.float64]],
    bounds: NDArray[np.float64],
) -> list[LimitRow]:
    """Per method and 25 cm band (and "all"): RMS error against truth and the bound, over the rows where the
    method answered and a bound exists."""
    scale = np.array([100.0, 100.0, math.degrees(1.0)])
    has_bound = np.all(np.isfinite(bounds.reshape(len(bounds), -1)), axis=1)
    var = np.diagonal(bounds, axis1=1, axis2=2)
    out = []
    for method, p in poses.items():
        err = p - truth
        err[:, 2] = (err[:, 2] + math.pi) % (2 * math.pi) - math.pi
        ok = has_bound & np.all(np.isfinite(err), axis=1)
        for name, lo, hi in [*((f"{lo * 100:.0f}-{hi * 100:.0f}", lo, hi) for lo, hi in BANDS_M), ("all", 0, 99)]:
            sel = ok & (depth_from_camera >= lo) & (depth_from_camera < hi)
            if sel.sum() < 3:
                continue
            rms = np.sqrt(np.mean(err[sel] ** 2, axis=0)) * scale
            bound = np.sqrt(np.mean(var[sel], axis=0)) * scale
            out.append(LimitRow(method, name, int(sel.sum()), tuple(rms), tuple(bound)))
    return out


@dataclass(frozen=True)
class PhysicalLimit:
    """Every method against the Cramér–Rao bound on one held-out dataset with truth.

    Attributes:
        fit: the refined corners' measured noise (the bound uses it).
        rows: per method and band (and "all"), its RMS error and the bound, corners taken as independent.
        correlated: the same rows, keyed by (method, band), with the measured correlation of a marker's corners.
        what_if: the bound of other markers and cameras over a grid of poses, with the same corner noise model.
        correlation_eigenvalues: the lowest and highest eigenvalue of the 8x8 correlation (None: not measured).
        bound_change: the smallest and largest relative change of the bound with that correlation.
    """

    fit: CornerNoiseFit
    rows: tuple[LimitRow, ...]
    correlated: Mapping[tuple[str, str], LimitRow]
    what_if: WhatIfResult
    correlation_eigenvalues: tuple[float, float] | None
    bound_change: tuple[float, float]

    def to_dict(self) -> dict[str, Any]:
        """The ``physical_limit`` block of the evaluation's summary.json."""
        fit = self.fit
        return {
            "corner_noise": {
                "sigma_px_by_side": {
                    f"{lo:g}-{hi:g}": (v if math.isfinite(v) else None)
                    for lo, hi, v in zip(SIDE_BINS_PX[:-1], SIDE_BINS_PX[1:], fit.sigma_px, strict=True)
                },
                "floor_px": fit.floor_px,
                "c": fit.c,
                "rms_px": fit.rms_px,
                "outward_mean_px": fit.outward_mean_px,
                "corners": fit.corners,
            },
            "ratios": [
                {
                    "method": r.method,
                    "band": r.band,
                    "rows": r.rows,
                    "rms": list(r.rms),
                    "bound": list(r.bound),
                    "ratio": list(r.ratio),
                    "ratio_correlated": list(self.correlated[(r.method, r.band)].ratio)
                    if (r.method, r.band) in self.correlated
                    else None,
                }
                for r in self.rows
            ],
            "what_if": {
                name: {
                    "sd": [float(v) for v in self.what_if.overall[k]],
                    "ratio": [float(v) for v in self.what_if.overall_ratio()[k]],
                }
                for k, name in enumerate(self.what_if.variants)
            },
        }


def _bound_change(rows: list[LimitRow], correlated: Mapping[tuple[str, str], LimitRow]) -> tuple[float, float]:
    """The smallest and largest relative change of the bound, over bands and components, with the correlation."""
    changes = [
        b / a - 1.0
        for r in rows
        if (r.method, r.band) in correlated and r.band != "all"
        for a, b in zip(r.bound, correlated[(r.method, r.band)].bound, strict=True)
        if a > 0
    ]
    return (min(changes), max(changes)) if changes else (0.0, 0.0)


def physical_limit(dataset: Dataset, poses: Mapping[str, NDArray[np.float64]]) -> PhysicalLimit | None:
    """Every method's error against the bound at the same rows (None without truth or refined corners).

    ``poses`` are each method's (rows, 3) estimates, x m, y m, yaw rad, NaN where it had none.
    """
    truth = np.column_stack(
        [dataset["truth_x_m"], dataset["truth_y_m"], np.radians(np.asarray(dataset["truth_yaw_deg"], dtype=float))]
    ).astype(np.float64)
    if not np.isfinite(truth[:, 0]).any() or not np.isfinite(dataset.refined_corners()).any():
        return None
    fit = measure_corner_noise(dataset)
    depth = truth[:, 0] - dataset.robot().camera_mount.x
    rows = limit_rows(depth, truth, poses, bounds_by_row(dataset, fit))
    # The same with the measured correlation of a marker's corners (the bound above takes them as independent).
    correlated = {
        (r.method, r.band): r for r in limit_rows(depth, truth, poses, bounds_by_row(dataset, fit, correlated=True))
    }
    eigenvalues = None
    if fit.correlation is not None:
        w = np.linalg.eigvalsh(fit.correlation)
        eigenvalues = (float(w[0]), float(w[-1]))
    return PhysicalLimit(
        fit=fit,
        rows=tuple(rows),
        correlated=correlated,
        what_if=what_if(dataset.camera(), dataset.layout(), dataset.robot(), noise=fit.noise),
        correlation_eigenvalues=eigenvalues,
        bound_change=_bound_change(rows, correlated),
    )
