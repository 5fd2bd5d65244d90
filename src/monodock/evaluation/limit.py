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
from monodock.perception.features import refined_detection_from_row

__all__ = ["CornerNoiseFit", "LimitRow", "bounds_by_row", "limit_rows", "measure_corner_noise"]

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


def _refined_rows(dataset: Any) -> list[tuple[int, dict[str, NDArray[np.float64]]]]:
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


def _truth(dataset: Any, i: int) -> DockPose:
    return DockPose(
        float(dataset["truth_x_m"][i]), float(dataset["truth_y_m"][i]), math.radians(float(dataset["truth_yaw_deg"][i]))
    )


def measure_corner_noise(dataset: Any) -> CornerNoiseFit:
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


def bounds_by_row(dataset: Any, noise: CornerNoiseFit, *, correlated: bool = False) -> NDArray[np.float64]:
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


def limit_table(rows: list[LimitRow]) -> str:
    """Markdown: per band and method, RMS error / bound for depth, lateral and yaw."""
    head = (
        "| band cm | method | rows | depth RMS / bound cm | ratio | lateral RMS / bound cm | ratio "
        "| yaw RMS / bound ° | ratio |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n"
    )
    lines = []
    for r in rows:
        q = r.ratio
        lines.append(
            f"| {r.band} | {r.method} | {r.rows} | {r.rms[0]:.3f} / {r.bound[0]:.3f} | {q[0]:.2f}× "
            f"| {r.rms[1]:.3f} / {r.bound[1]:.3f} | {q[1]:.2f}× | {r.rms[2]:.3f} / {r.bound[2]:.3f} | {q[2]:.2f}× |"
        )
    return head + "\n".join(lines) + "\n"


def _what_if_table(result: Any) -> str:
    """Markdown: each set-up's bound (overall RMS sd) and its ratio to the current one."""
    head = (
        "| set-up | depth bound cm | lateral bound cm | yaw bound ° | × current (depth / lateral / yaw) |\n"
        "|---|---:|---:|---:|---:|\n"
    )
    ratio = result.overall_ratio()
    lines = []
    for k, name in enumerate(result.variants):
        sd = result.overall[k] * np.array([100.0, 100.0, math.degrees(1.0)])
        lines.append(
            f"| {name} | {sd[0]:.3f} | {sd[1]:.3f} | {sd[2]:.3f} | "
            f"{ratio[k, 0]:.2f} / {ratio[k, 1]:.2f} / {ratio[k, 2]:.2f} |"
        )
    return head + "\n".join(lines) + "\n"


def _band_points(
    rows: list[LimitRow], method: str, field: str, component: int, centres: list[float]
) -> list[tuple[float, float]]:
    """(band centre cm, ``field`` ("rms" or "bound") of one component) of one method's rows, in band order."""
    return [
        (c, float(getattr(r, field)[component]))
        for c, (lo, hi) in zip(centres, BANDS_M, strict=True)
        for r in rows
        if r.method == method and r.band == f"{lo * 100:.0f}-{hi * 100:.0f}"
    ]


def _plot(rows: list[LimitRow], what: Any, path: Any) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    centres = [0.5 * (lo + hi) * 100 for lo, hi in BANDS_M]
    units = ("depth (cm)", "lateral (cm)", "yaw (°)")
    scale = np.array([100.0, 100.0, math.degrees(1.0)])
    for j, ax in enumerate(axes):
        for method in dict.fromkeys(r.method for r in rows):
            pts = _band_points(rows, method, "rms", j, centres)
            if pts:
                ax.plot(*zip(*pts, strict=True), "-o", ms=3, label=f"{method} RMS error")
        # The yardstick of the ratios: the bound at these rows' own poses (the widest method's rows).
        widest = max(dict.fromkeys(r.method for r in rows), key=lambda m: sum(r.rows for r in rows if r.method == m))
        own = _band_points(rows, widest, "bound", j, centres)
        if own:
            ax.plot(*zip(*own, strict=True), "-k", lw=2, label="bound at these rows' poses")
        # The what-if study's bounds are over its own pose grid: the current set-up's is the reference there.
        for k, name in enumerate(what.variants):
            ax.plot(
                centres[: what.sd.shape[1]],
                what.sd[k, :, j] * scale[j],
                "--" if k else ":k",
                lw=1.2,
                label=f"bound: {name}" + ("" if k else " (pose grid)"),
            )
        ax.set_yscale("log")
        ax.set_xlabel("depth from the camera (cm)")
        ax.set_title(units[j])
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=6)
    fig.suptitle(
        "Every method's RMS error against the Cramér–Rao bound at the same poses (solid black)\n"
        "dashed: the bound of other set-ups over a pose grid (dotted: this set-up on that grid)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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


def limit_section(report: Any, dataset: Any, poses: Mapping[str, NDArray[np.float64]], out: Any) -> dict[str, Any]:
    """The report's "physical limit" section; returns its summary (empty without truth or refined corners)."""
    from monodock.evaluation.what_if import what_if

    truth = np.column_stack(
        [dataset["truth_x_m"], dataset["truth_y_m"], np.radians(np.asarray(dataset["truth_yaw_deg"], dtype=float))]
    ).astype(np.float64)
    if not np.isfinite(truth[:, 0]).any() or not np.isfinite(dataset.refined_corners()).any():
        return {}
    fit = measure_corner_noise(dataset)
    depth = truth[:, 0] - dataset.robot().camera_mount.x
    rows = limit_rows(depth, truth, poses, bounds_by_row(dataset, fit))
    # The same with the measured correlation of a marker's corners (the bound above takes them as independent).
    correlated = {
        (r.method, r.band): r for r in limit_rows(depth, truth, poses, bounds_by_row(dataset, fit, correlated=True))
    }
    if fit.correlation is not None:
        w = np.linalg.eigvalsh(fit.correlation)
        low, high = _bound_change(rows, correlated)
        correlation_note = (
            " A marker's corners share its fitted sides, so their errors are not independent: the eigenvalues of "
            f"their measured 8x8 correlation run from {w[0]:.2f} to {w[-1]:.2f} (all 1 for independent corners). "
            f"With it the bound would change by {100 * low:+.0f} % to {100 * high:+.0f} % per band and component "
            "(summary.json: ratio_correlated); an estimator would need that correlation, which LiDAR labels are "
            "too coarse to learn, to gain from it."
        )
    else:
        correlation_note = ""
    what = what_if(dataset.camera(), dataset.layout(), dataset.robot(), noise=fit.noise)
    report.heading("The physical limit: every method against the Cramér–Rao bound")
    report.paragraph(
        f"Refined corners against the truth on these rows: {fit.corners} corners, RMS {fit.rms_px:.3f} px, mean "
        f"outward error {fit.outward_mean_px:+.4f} px. Their noise, measured per edge length (the bound uses these): "
        + ", ".join(
            f"{lo:.0f}-{hi:.0f} px: {s:.3f}" if math.isfinite(hi) else f"≥{lo:.0f} px: {s:.3f}"
            for lo, hi, s in zip(SIDE_BINS_PX[:-1], SIDE_BINS_PX[1:], fit.sigma_px, strict=True)
            if math.isfinite(s)
        )
        + f" px per axis; as a model, σ² = ({fit.c:.3f})²·(1/L₁+1/L₂)/2 + ({fit.floor_px:.3f})² px². "
        "The bound of a row is (JᵀWJ)⁻¹ at its true pose for the markers refined there; a band's bound is the root "
        "of its mean variance. Ratio = RMS error / bound: 1.0× is as good as these pixels allow." + correlation_note
    )
    report.table(limit_table(rows))
    report.paragraph(
        "What would buy more: the same bound (same corner noise model) for other markers and cameras, over a grid "
        "of poses in 25-250 cm, ±40 cm, ±30°:"
    )
    report.table(_what_if_table(what))
    _plot(rows, what, out / "physical_limit.png")
    report.image("physical_limit.png", "")
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
                "ratio_correlated": list(correlated[(r.method, r.band)].ratio)
                if (r.method, r.band) in correlated
                else None,
            }
            for r in rows
        ],
        "what_if": {
            name: {"sd": [float(v) for v in what.overall[k]], "ratio": [float(v) for v in what.overall_ratio()[k]]}
            for k, name in enumerate(what.variants)
        },
    }
