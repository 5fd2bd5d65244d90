"""The physical-limit section of a held-out report: every method's error against the Cramér–Rao bound."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from monodock.evaluation.limit import BANDS_M, SIDE_BINS_PX, LimitRow, PhysicalLimit
from monodock.evaluation.what_if import WhatIfResult
from monodock.report.html import HtmlReport
from monodock.report.plotting import plt

__all__ = ["limit_plot", "limit_section", "limit_table", "what_if_table"]


def limit_table(rows: list[LimitRow] | tuple[LimitRow, ...]) -> str:
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


def what_if_table(result: WhatIfResult) -> str:
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
    rows: tuple[LimitRow, ...], method: str, field: str, component: int, centres: list[float]
) -> list[tuple[float, float]]:
    """(band centre cm, ``field`` ("rms" or "bound") of one component) of one method's rows, in band order."""
    return [
        (c, float(getattr(r, field)[component]))
        for c, (lo, hi) in zip(centres, BANDS_M, strict=True)
        for r in rows
        if r.method == method and r.band == f"{lo * 100:.0f}-{hi * 100:.0f}"
    ]


def limit_plot(limit: PhysicalLimit, path: Path) -> None:
    """Per component, every method's RMS error by band, the bound at the same rows and the what-if bounds."""
    rows, what = limit.rows, limit.what_if
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


def _noise_text(limit: PhysicalLimit) -> str:
    fit = limit.fit
    correlation = ""
    if limit.correlation_eigenvalues is not None:
        lowest, highest = limit.correlation_eigenvalues
        low, high = limit.bound_change
        correlation = (
            " A marker's corners share its fitted sides, so their errors are not independent: the eigenvalues of "
            f"their measured 8x8 correlation run from {lowest:.2f} to {highest:.2f} (all 1 for independent corners). "
            f"With it the bound would change by {100 * low:+.0f} % to {100 * high:+.0f} % per band and component "
            "(summary.json: ratio_correlated); an estimator would need that correlation, which LiDAR labels are "
            "too coarse to learn, to gain from it."
        )
    return (
        f"Refined corners against the truth on these rows: {fit.corners} corners, RMS {fit.rms_px:.3f} px, mean "
        f"outward error {fit.outward_mean_px:+.4f} px. Their noise, measured per edge length (the bound uses these): "
        + ", ".join(
            f"{lo:.0f}-{hi:.0f} px: {s:.3f}" if math.isfinite(hi) else f"≥{lo:.0f} px: {s:.3f}"
            for lo, hi, s in zip(SIDE_BINS_PX[:-1], SIDE_BINS_PX[1:], fit.sigma_px, strict=True)
            if math.isfinite(s)
        )
        + f" px per axis; as a model, σ² = ({fit.c:.3f})²·(1/L₁+1/L₂)/2 + ({fit.floor_px:.3f})² px². "
        "The bound of a row is (JᵀWJ)⁻¹ at its true pose for the markers refined there; a band's bound is the root "
        "of its mean variance. Ratio = RMS error / bound: 1.0× is as good as these pixels allow." + correlation
    )


def limit_section(report: HtmlReport, limit: PhysicalLimit, out: Path, *, level: int = 2) -> None:
    """The "physical limit" section; its figure is written into ``out`` as physical_limit.png."""
    report.heading("The physical limit: every method against the Cramér–Rao bound", level)
    report.paragraph(_noise_text(limit))
    with report.details("Every method against the bound, by 25 cm band"):
        report.table(limit_table(limit.rows))
    report.paragraph(
        "What would buy more: the same bound (same corner noise model) for other markers and cameras, over a grid "
        "of poses in 25-250 cm, ±40 cm, ±30°:"
    )
    report.table(what_if_table(limit.what_if))
    limit_plot(limit, out / "physical_limit.png")
    report.image("physical_limit.png", "")
