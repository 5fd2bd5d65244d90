"""The robustness report: the headline of the worst levels, and per axis a table and a plot of every method."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib import ticker

from monodock.core.records import to_record
from monodock.evaluation.robustness import RobustnessResult
from monodock.evaluation.robustness_results import METHODS, STALE, AxisKind, AxisResult, HeadlineRow
from monodock.report.html import HtmlReport
from monodock.report.plotting import METHOD_COLOURS, METHOD_LABELS, plt

__all__ = ["axis_plot", "axis_table", "headline_table", "write_robustness_report"]

_SHORT = {"regression": "regression", "pnp": "pnp", "board": "board", "fused": "fused", STALE: "fused, stale"}


def _fmt(v: float, digits: int = 2) -> str:
    return "—" if not math.isfinite(v) else f"{v:.{digits}f}"


def headline_table(rows: tuple[HeadlineRow, ...]) -> str:
    """Markdown: per axis and method the worst level's "depth / lateral / yaw" MAE (the lowest valid rate when
    below 100 %), and whether fused and board stay within the good-enough bound."""
    methods = (*METHODS, STALE)
    head = "| axis | " + " | ".join(_SHORT[m] for m in methods) + " | fused within | board within |\n"
    head += "|---|" + "---:|" * len(methods) + "---|---|\n"
    lines = []
    for row in rows:
        cells = []
        for m in methods:
            w = row.worst.get(m)
            if w is None:
                cells.append("")
                continue
            rate = f" ({math.floor(w.valid_rate * 100)} %)" if w.valid_rate < 1.0 else ""
            cells.append(f"{_fmt(w.depth_mae_cm)} / {_fmt(w.lateral_mae_cm)} / {_fmt(w.yaw_mae_deg)}{rate}")
        verdict = ("yes, board not" if not row.board_within else "yes") if row.fused_within else "no"
        name = row.axis.replace("_", " ")
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {verdict} | {'yes' if row.board_within else 'no'} |")
    return head + "\n".join(lines) + "\n"


def axis_table(a: AxisResult) -> str:
    """One axis as a markdown table: a row per level and method."""
    head = (
        f"| level ({a.axis.unit}) | method | valid % | depth MAE cm | lateral MAE cm | yaw MAE ° | depth bias % |\n"
        "|---:|---|---:|---:|---:|---:|---:|\n"
    )
    lines = []
    for i, level in enumerate(a.axis.levels):
        mark = " (default)" if level == a.axis.default else ""
        for m, s in a.methods.items():
            lines.append(
                f"| {level:g}{mark} | {METHOD_LABELS[m]} | {s.valid_rate[i] * 100:.0f} | {_fmt(s.depth_mae_cm[i])} "
                f"| {_fmt(s.lateral_mae_cm[i])} | {_fmt(s.yaw_mae_deg[i])} | {_fmt(s.depth_bias_pct[i], 1)} |"
            )
    return head + "\n".join(lines) + "\n"


def axis_plot(key: str, a: AxisResult, path: Path) -> None:
    """Three panels (depth, lateral, yaw MAE against the level), one line per method, the default marked."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), layout="constrained")
    levels = np.array(a.axis.levels, dtype=float)
    for ax, stat, label in zip(
        axes,
        ("depth_mae_cm", "lateral_mae_cm", "yaw_mae_deg"),
        ("depth (x) MAE (cm)", "lateral (y) MAE (cm)", "yaw MAE (°)"),
        strict=True,
    ):
        values = []
        for m, s in a.methods.items():
            v = np.array(s.stat(stat), dtype=float)
            values += [x for x in v if math.isfinite(x) and x > 0]
            valid = min(s.valid_rate) * 100
            ax.plot(
                levels,
                v,
                "--" if m == STALE else "-",
                marker="s" if m == STALE else "o",
                color=METHOD_COLOURS[m],
                label=f"{METHOD_LABELS[m]} (valid ≥ {valid:.0f} %)",
                ms=5,
                mfc="none" if m == STALE else None,
            )
        if values and max(values) / min(values) > 10:
            ax.set_yscale("log")
            ax.yaxis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _pos: f"{v:g}"))
            ax.yaxis.set_minor_formatter(ticker.NullFormatter())
        ax.axvline(a.axis.default, color="grey", ls=":", lw=1.2)
        ax.annotate(
            "default",
            (a.axis.default, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -12),
            textcoords="offset points",
            fontsize=8,
            color="grey",
        )
        ax.set_xticks(levels)
        ax.set_xlabel(f"{a.axis.title} ({a.axis.unit})")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.suptitle(f"{a.axis.title}: error against the simulator's truth, {a.frames} frames per level ({key})")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _occlusion_text(result: RobustnessResult) -> str:
    o = result.occlusion
    assert o is not None
    return (
        "Share of the marker hidden, as the simulator measures it (9x9 grid): "
        + ", ".join(f"{lv:g} %: {h:.0f} %" for lv, h in zip(o.levels, o.hidden_measured_pct, strict=True))
        + ". ArUco found the occluded marker in "
        + ", ".join(f"{d:.0f} %" for d in o.occluded_marker_detected_pct)
        + " of the frames. Occluded marker: "
        + ", ".join(f"{k} {v}" for k, v in o.occluded_marker.items())
        + " frames."
    )


def _axes_of(axes: Mapping[str, AxisResult], kind: AxisKind) -> list[tuple[str, AxisResult]]:
    return [(k, a) for k, a in axes.items() if a.axis.kind is kind]


def write_robustness_report(result: RobustnessResult, out: Path) -> None:
    """report.html, report.md, summary.json, frames.npz and one PNG per axis in ``out``."""
    summary = result.summary()
    report = HtmlReport("monodock robustness: every method against one nuisance at a time")
    report.heading("Headline: the worst level of each axis")
    report.paragraph(
        "Per axis and method: depth MAE (cm) / lateral MAE (cm) / yaw MAE (°), each at the level where it is "
        "worst, and in brackets the lowest valid rate over the levels when below 100 %. 'fused within': "
        "fused stays within 1 cm depth, 1 cm lateral and 1° yaw at every level (on calibration axes: fused "
        "with re-learned tables); 'yes, board not': where board does not."
    )
    report.table(headline_table(summary.headline))
    report.heading("Settings")
    report.settings(to_record(result.settings))
    report.paragraph(
        "Each axis is swept on its own, everything else at the defaults (Nuisances()). The same test poses are "
        "used at every level, each frame with the same random draws (sensor noise, exposure jitter, motion-blur "
        "direction, occluder), so the curves differ by the nuisance alone. Errors are against the simulator's "
        "truth; MAE is over each method's valid frames (its valid rate is given beside it)."
    )
    report.bullets(
        [
            "regression: the papers' (the bundle's models); pnp: marker 2 alone (IPPE); board: every visible "
            "marker; fused: planar PnP on refined corners combined with the regression.",
            "Calibration axes render the default images and give every method the wrong file. 'fused' has its "
            "tables re-learned with the same wrong files on a LiDAR-labelled calibration set, as monodock train "
            "would have on that robot (also at level 0, from that small set); 'fused (stale tables)' keeps the "
            "bundle's tables, learned with the right files (a calibration that changed after training).",
            "The regression is not retrained per level: under a wrong focal length its inputs shift, which a "
            "regression retrained with the same wrong file would absorb (and so would fused's regression half).",
            "MAE is over each method's own valid frames: where a nuisance makes a method drop frames, its MAE "
            "is over the frames it still answers, which need not be the easy ones nor the hard ones; read it with "
            "the valid rate (in the tables and the legends). frames.npz has every frame's numbers.",
            "Noise: the read noise is the level; the shot noise is scaled by the same factor (a higher gain).",
            "Occlusion: a board 5 cm in front of the charger face, parallel to it, hides the given share of one "
            "marker's area from one side (the marker and side drawn per frame, the same at every level). ArUco "
            "may then miss that marker: the valid rates count it.",
        ]
    )
    for kind, title in ((AxisKind.IMAGE, "Image nuisances"), (AxisKind.CALIBRATION, "Calibration errors")):
        report.heading(title)
        for key, a in _axes_of(result.axes, kind):
            report.heading(f"{a.axis.title} ({a.axis.unit})", 3)
            axis_plot(key, a, out / f"{key}.png")
            report.image(f"{key}.png", a.axis.title)
            if key == "occlusion" and result.occlusion is not None:
                report.paragraph(_occlusion_text(result))
            with report.details(f"{a.axis.title}: every level and method"):
                report.table(axis_table(a))
    report.paragraph(
        "frames.npz holds every frame's numbers: 'truth' (frames x 3: x m, y m, yaw rad) and one array per "
        "condition and method ('CONDITION|METHOD', the same layout, NaN where the method gave no estimate)."
    )
    result.save_frames(out / "frames.npz")
    report.write(out, summary.to_json())
