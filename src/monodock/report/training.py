"""The training report: the Sensors 2025 paper's Tables 1-3 and Fig. 9-10 for our own trained models.

Table 1: every model type's best test MSE and R² for depth. Table 2: per 5 cm segment, the rows (own,
borrowed, final N), the best model type and its test MSE and R², with the average row. Table 3: every model
type's test MSE in every segment (the paper shows five segments; here all of them, one row each). Fig. 9:
depth predicted against label on the test split and MSE by model type. Fig. 10: per segment the best MSE
coloured by the chosen model type, all types' MSEs, and the angle test samples against their labels.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from monodock.core.atomic import check_writable, write_bytes_atomic, write_text_atomic
from monodock.estimation.segments import SegmentTable
from monodock.learning.regressors import MODEL_NAMES, describe_search_space
from monodock.learning.tasks import segment_quota
from monodock.learning.train import SetResult, TaskResult, TrainingResult
from monodock.report.plotting import plt

__all__ = [
    "MODEL_LABELS",
    "angle_figure",
    "depth_figure",
    "training_tables",
    "write_training_report",
]

# The paper's names for the model types.
MODEL_LABELS = {
    "linear": "Linear Regression",
    "ridge": "Ridge Regression",
    "lasso": "Lasso Regression",
    "decision_tree": "Decision Tree",
    "random_forest": "Random Forest",
    "svr": "SVR",
    "gradient_boosting": "Gradient Boosting",
}
_COLOURS = {m: plt.get_cmap("tab10")(i) for i, m in enumerate(MODEL_NAMES)}


def _mse(x: float) -> str:
    """An MSE for a table: 4 decimals as the paper, or 3 significant digits when smaller."""
    if not math.isfinite(x):
        return "—"
    if x == 0 or x >= 0.01:
        return f"{x:.4f}"
    return f"{x:.{2 - math.floor(math.log10(x))}f}"


def _r2(x: float) -> str:
    return "—" if not math.isfinite(x) else f"{x:.4f}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str) -> str:
    sep = ["---" if a == "l" else "---:" for a in align]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(sep) + " |"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _params(params: dict[str, object]) -> str:
    def one(v: object) -> str:
        return f"{v:.3g}" if isinstance(v, float) else str(v)

    return ", ".join(f"{k}={one(v)}" for k, v in sorted(params.items())) or "—"


def _runs(segments: Sequence[int]) -> list[tuple[int, int]]:
    """Sorted segment indices as (first, last) runs of consecutive indices."""
    runs: list[tuple[int, int]] = []
    for k in sorted(segments):
        if runs and k == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], k)
        else:
            runs.append((k, k))
    return runs


def _borrowed(task: TaskResult, segments: SegmentTable) -> str:
    """The neighbour segments whose rows a segment used, in cm, e.g. '35–40, 45–55 cm (±2)', or '—'."""
    if task.borrowed is None or task.segment is None or task.best is None:
        return "—"
    lo, hi = task.borrowed
    reach = max(task.segment - lo, hi - task.segment)
    others = [k for k in task.sources if k != task.segment]
    if not others:
        return f"none with rows (±{reach})"
    cm = [f"{segments.bounds(a)[0] * 100:g}–{segments.bounds(b)[1] * 100:g}" for a, b in _runs(others)]
    return f"{', '.join(cm)} cm (±{reach})"


def _depth_table(s: SetResult) -> str:
    rows = []
    chosen = s.depth.chosen
    for model, sc in s.depth.scores.items():
        mark = " ★" if model == chosen else ""
        name = f"**{MODEL_LABELS[model]}**{mark}" if model == chosen else MODEL_LABELS[model]
        rows.append(
            [
                name,
                _mse(sc.mse),
                _r2(sc.r2),
                f"{math.sqrt(sc.mse) * 100:.2f}" if math.isfinite(sc.mse) else "—",
                str(sc.trials),
                str(sc.n_fit),
                f"{sc.fit_seconds:.2f}",
                _params(sc.params),
            ]
        )
    return _table(
        ["model", "best test MSE (m²)", "best test R²", "RMSE (cm)", "draws", "rows fit", "fit s", "best parameters"],
        rows,
        "lrrrrrrl",
    )


def _segment_table(s: SetResult, segments: SegmentTable) -> str:
    rows = []
    for t in s.angle:
        assert t.segment is not None
        best = t.best
        rows.append(
            [
                segments.label(t.segment),
                str(t.n_own),
                _borrowed(t, segments),
                str(t.n_rows),
                MODEL_LABELS[t.chosen] if t.chosen else f"no model: {t.reason}",
                _mse(best.mse) if best else "—",
                _r2(best.r2) if best else "—",
            ]
        )
    scored = [t.best for t in s.angle if t.best is not None]
    mse = float(np.mean([b.mse for b in scored])) if scored else math.nan
    r2s = [b.r2 for b in scored if math.isfinite(b.r2)]
    r2 = float(np.mean(r2s)) if r2s else math.nan
    rows.append(["**Avg**", "", "", "", f"{len(scored)} models", f"**{_mse(mse)}**", f"**{_r2(r2)}**"])
    return _table(["distance", "N own", "borrowed from", "N", "regression model", "MSE (deg²)", "R²"], rows, "lrlrlrr")


def _segment_models_table(s: SetResult, segments: SegmentTable, models: Sequence[str]) -> str:
    rows = []
    for t in s.angle:
        assert t.segment is not None
        row = [segments.label(t.segment)]
        for m in models:
            sc = t.scores.get(m)
            cell = "—" if sc is None else _mse(sc.mse)
            row.append(f"**{cell}**" if m == t.chosen else cell)
        rows.append(row)
    return _table(["distance", *(MODEL_LABELS[m] for m in models)], rows, "l" + "r" * len(models))


def _titles(s: SetResult, segments: SegmentTable) -> tuple[str, str, str]:
    n_models = sum(t.best is not None for t in s.angle)
    return (
        f"Table 1 — marker set {s.name}: depth models (best test MSE and R² per model type; ★ chosen)",
        f"Table 2 — marker set {s.name}: the best angle model per segment "
        f"({n_models} of {segments.count} segments have a model)",
        f"Table 3 — marker set {s.name}: test MSE (deg²) of every model type per segment (chosen in bold)",
    )


def training_tables(result: TrainingResult) -> dict[str, str]:
    """The paper's Tables 1-3 for every marker set as markdown, keyed by a title; in order, to embed elsewhere.

    Table 1: every model type's best test MSE (m²) and R² for depth, the chosen one marked. Table 2: per segment
    the rows (own, borrowed, final N), the best model type, its MSE (deg²) and R², and the average row. Table 3:
    every model type's test MSE (deg²) in every segment, the chosen in bold.
    """
    seg = result.config.segments
    out: dict[str, str] = {}
    for s in result.sets:
        t1, t2, t3 = _titles(s, seg)
        out[t1] = _depth_table(s)
        out[t2] = _segment_table(s, seg)
        out[t3] = _segment_models_table(s, seg, result.config.models)
    return out


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def depth_figure(s: SetResult) -> bytes:
    """Fig. 9 equivalent as PNG bytes: depth predicted vs label on the test split, and test MSE by model type."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5), constrained_layout=True)
    t = s.depth
    best = t.best
    if best is not None and t.chosen is not None:
        y, p = t.y_test * 100, t.y_pred * 100
        ax.scatter(y, p, s=6, alpha=0.4, color=_COLOURS[t.chosen], label=f"test rows (n = {len(y)})")
        lims = [min(y.min(), p.min()), max(y.max(), p.max())]
        ax.plot(lims, lims, "k--", lw=1, label="predicted = label")
        ax.set_title(
            f"{MODEL_LABELS[t.chosen]} (chosen): MSE {_mse(best.mse)} m², R² {_r2(best.r2)}, "
            f"RMSE {math.sqrt(best.mse) * 100:.2f} cm",
            fontsize=10,
        )
        ax.legend(loc="upper left", fontsize=9)
    ax.set_xlabel("depth label (cm)")
    ax.set_ylabel("predicted depth (cm)")
    ax.grid(True, alpha=0.3)

    models = list(t.scores)
    mses = [t.scores[m].mse for m in models]
    colours = [_COLOURS[m] for m in models]
    bars = bx.bar(
        range(len(models)), mses, color=colours, edgecolor=["black" if m == t.chosen else "none" for m in models]
    )
    for b, m, v in zip(bars, models, mses, strict=True):
        bx.annotate(
            _mse(v) + (" ★" if m == t.chosen else ""),
            (b.get_x() + b.get_width() / 2, v),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    bx.set_xticks(range(len(models)), [MODEL_LABELS[m] for m in models], rotation=25, ha="right", fontsize=9)
    if all(v > 0 and math.isfinite(v) for v in mses):
        bx.set_yscale("log")
    bx.set_ylabel("best test MSE (m², log scale)")
    bx.set_title("depth: test MSE by model type (★ chosen)", fontsize=10)
    bx.grid(True, axis="y", which="both", alpha=0.3)
    fig.suptitle(f"Depth model, marker set {s.name} (cf. the paper's Fig. 9 and Table 1)")
    return _png(fig)


def angle_figure(s: SetResult, segments: SegmentTable) -> bytes:
    """Fig. 10 equivalent as PNG bytes: best MSE per segment coloured by model type, every type's MSE, samples."""
    fig, (ax, bx, cx) = plt.subplots(3, 1, figsize=(14, 12.5), layout="constrained")
    x = np.arange(segments.count)
    labels = [f"{segments.bounds(i)[0] * 100:g}" for i in range(segments.count)]
    models = list(s.depth.scores)
    missing = [t.segment for t in s.angle if t.best is None and t.segment is not None]
    for a in (ax, bx):
        for lo, hi in _runs(missing):
            a.axvspan(lo - 0.5, hi + 0.5, color="0.93", lw=0, zorder=0)
            a.text((lo + hi) / 2, 0.5, "no model", transform=a.get_xaxis_transform(), ha="center", va="center",
                   fontsize=8, color="0.45", rotation=90 if hi - lo < 3 else 0)  # fmt: skip
    for t in s.angle:
        if t.best is None or t.chosen is None or t.segment is None:
            continue
        ax.bar(
            t.segment,
            max(t.best.mse, 1e-12),
            color=_COLOURS[t.chosen],
            hatch="//" if t.borrowed else None,
            edgecolor="white" if t.borrowed else "none",
            lw=0,
        )
    ax.set_yscale("log")
    ax.set_ylabel("best test MSE (deg², log)")
    ax.set_title("per segment: the chosen model type (colour) and its test MSE (Table 2)", fontsize=10)

    for m in models:
        v = [t.scores[m].mse if m in t.scores else np.nan for t in s.angle]
        bx.plot(x, v, "o-", ms=3, lw=1, color=_COLOURS[m])
    bx.set_yscale("log")
    bx.set_ylabel("test MSE (deg², log)")
    bx.set_title("per segment: every model type's best test MSE (Table 3)", fontsize=10)
    for a in (ax, bx):
        a.set_xticks(x[::2], labels[::2], fontsize=8)
        a.set_xlim(-0.7, segments.count - 0.3)
        a.set_xlabel("segment start (cm from the camera)")
        a.grid(True, axis="y", which="both", alpha=0.3)
    handles = [Patch(color=_COLOURS[m], label=MODEL_LABELS[m]) for m in models]
    handles.append(Patch(facecolor="0.55", hatch="//", edgecolor="white", label="rows borrowed from neighbours"))
    ax.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 1.07), ncol=len(handles), fontsize=9)

    ys, ps, starts, names = [], [], [], []
    n = 0
    for t in s.angle:
        if t.best is None or t.segment is None:
            continue
        order = np.argsort(t.y_test, kind="stable")
        starts.append(n)
        names.append(labels[t.segment])
        ys.append(t.y_test[order])
        ps.append(t.y_pred[order])
        n += len(order)
    if ys:
        cx.plot(np.concatenate(ys), color="tab:blue", lw=1, label="label")
        cx.plot(np.concatenate(ps), color="tab:red", lw=0.8, alpha=0.85, label="predicted (chosen model)")
        for st in starts[1:]:
            cx.axvline(st - 0.5, color="0.75", lw=0.5, zorder=0)
        # Label segment starts on top, skipping those too close to the last labelled one to be legible.
        ticks: list[int] = []
        for i, st in enumerate(starts):
            if not ticks or st - starts[ticks[-1]] >= n / 30:
                ticks.append(i)
        top = cx.secondary_xaxis("top")
        top.set_xticks([starts[i] for i in ticks], [names[i] for i in ticks], fontsize=7)
        top.set_xlabel("segment start (cm)", fontsize=8)
        cx.legend(fontsize=8, loc="lower right")
        cx.set_xlim(-1, n)
    cx.set_xlabel("test sample (N): segment by segment from near to far, each sorted by its label")
    cx.set_ylabel("yaw (°)")
    cx.set_title(
        "test samples: label (blue) and the chosen model's prediction (red), as the paper's Fig. 10", fontsize=10
    )
    cx.grid(True, alpha=0.3)
    fig.suptitle(f"Angle models per 5 cm segment, marker set {s.name} (cf. the paper's Fig. 10 and Tables 2-3)")
    return _png(fig)


def _notes(result: TrainingResult) -> list[str]:
    cfg = result.config
    seg = cfg.segments
    lines = [
        f"- Split: {round((1 - cfg.test_size) * 100)}/{round(cfg.test_size * 100)} per task (train/test), seed "
        f"{cfg.seed}; up to {cfg.trials} random hyperparameter draws per model type and task; the model type with "
        "the lowest test MSE is chosen (the paper's rule). MSE and R² are on the test split.",
        f"- Depth: one global model per marker set on all rows. Angle: one model per {seg.width_m * 100:g} cm segment "
        f"over {seg.start_m * 100:g}–{seg.end_m * 100:g} cm. A segment with fewer than "
        + ", ".join(f"{segment_quota(cfg, len(s.feature_names))} ({s.name})" for s in result.sets)
        + f" rows (at least {cfg.min_segment_samples}, and {cfg.min_rows_per_feature:g} per input feature) "
        f"borrows the rows of its neighbours (±1, ±2, … up to ±{cfg.max_borrow} segments); one still under "
        f"{cfg.min_rows} rows gets no model.",
        f"- Training: {result.n_fits} fits in {result.seconds:.1f} s on {result.jobs} worker "
        f"process{'es' if result.jobs != 1 else ''} "
        f"({result.fit_cpu_seconds:.1f} CPU s in fits).",
    ]
    for s in result.sets:
        for t in (s.depth, *s.angle):
            sc = t.scores.get("svr")
            if sc is not None and sc.n_fit < t.n_train:
                where = "depth" if t.segment is None else seg.label(t.segment)
                lines.append(
                    f"- SVR (O(n²) to fit) was fit on a seeded subsample of {sc.n_fit} of the {t.n_train} training "
                    f"rows for {s.name} {where}; it is scored on the full test split."
                )
    lines.append("- Search spaces:")
    lines += [f"  - {MODEL_LABELS[m]}: {describe_search_space(m)}" for m in cfg.models]
    return lines


def write_training_report(
    out_dir: str | os.PathLike[str], result: TrainingResult, *, title: str, force: bool = False
) -> list[Path]:
    """Write ``training.md`` with Tables 1-3 per marker set and the Fig. 9-10 style PNGs beside it.

    Args:
        out_dir: Folder for the report (created if missing).
        result: What ``train.train`` returned.
        title: The report's heading.
        force: Replace existing report files.

    Returns:
        The files written, ``training.md`` first.

    Raises:
        InputError: A report file exists and ``force`` is not given, or the folder cannot be written.
    """
    out = Path(out_dir)
    md_path = out / "training.md"
    pngs = {s.name: (out / f"training_{s.name}_depth.png", out / f"training_{s.name}_yaw.png") for s in result.sets}
    for p in [md_path, *(p for pair in pngs.values() for p in pair)]:
        check_writable(p, force=force)

    seg = result.config.segments
    written: list[Path] = []
    lines = [f"# {title}", "", *_notes(result), ""]
    for s in result.sets:
        depth_png, yaw_png = pngs[s.name]
        write_bytes_atomic(depth_png, depth_figure(s), force=force)
        write_bytes_atomic(yaw_png, angle_figure(s, seg), force=force)
        written += [depth_png, yaw_png]
        t1, t2, t3 = _titles(s, seg)
        lines += [
            f"## Marker set {s.name}: {s.n_rows} rows, {len(s.feature_names)} features",
            "",
            f"### {t1}",
            "",
            _depth_table(s),
            "",
            f"![depth model, marker set {s.name}]({depth_png.name})",
            "",
            f"### {t2}",
            "",
            _segment_table(s, seg),
            "",
            f"### {t3}",
            "",
            _segment_models_table(s, seg, result.config.models),
            "",
            f"![angle models, marker set {s.name}]({yaw_png.name})",
            "",
        ]
    write_text_atomic(md_path, "\n".join(lines), force=force)
    return [md_path, *written]
