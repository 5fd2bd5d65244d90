"""The tables of a dock-sim run: each variant's success and final errors (by case and overall), the dock filter
against single frames, the faults' outcomes, and a few lines for the terminal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from monodock.evaluation.commission import wilson
from monodock.evaluation.dock_faults import FAULTS
from monodock.evaluation.dock_results import AbsStats, DockSimSummary, FilterBlock, RunGroup, TrialResult
from monodock.evaluation.dock_sim import DockSimConfig

__all__ = ["comparison_table", "console_table", "fault_table", "filter_table", "room_table"]


def _fmt_stats(s: AbsStats) -> str:
    return " / ".join("–" if v is None else f"{v:.2f}" for v in (s.median, s.p95, s.max))


def comparison_table(summary: DockSimSummary, *, cases: bool = True, overall: bool = True) -> str:
    """Markdown: per case and overall, each method's success and median / p95 / max final errors."""
    head = (
        "| case | method | success | lateral cm (median / p95 / max) | gap cm (median / p95 / max) "
        "| heading ° (median / p95 / max) | time s (median) | retries |"
    )
    lines = [head, "|---|---|---:|---:|---:|---:|---:|---:|"]
    groups: list[tuple[str, str, RunGroup]] = []
    if cases:
        groups += [(str(case), m, block.cases[case]) for case in summary.cases for m, block in summary.methods.items()]
    if overall:
        groups += [("all", m, block.overall) for m, block in summary.methods.items()]
    for case, m, g in groups:
        time_med = g.time_s.median
        lines.append(
            f"| {case} | {m} | {g.successes}/{g.runs} | {_fmt_stats(g.final_lateral_cm)} | "
            f"{_fmt_stats(g.final_longitudinal_cm)} | {_fmt_stats(g.final_heading_deg)} | "
            f"{'–' if time_med is None else f'{time_med:.1f}'} | {g.retries_total} |"
        )
    return "\n".join(lines) + "\n"


def filter_table(summary: DockSimSummary) -> str:
    """Markdown: per method and depth band, the filter's MAE against single frames'."""
    lines = [
        "| method | depth from camera cm | frames | depth MAE cm (filtered / frame) "
        "| lateral MAE cm (filtered / frame) | yaw MAE ° (filtered / frame) "
        "| coasting frames (MAE depth / lateral / yaw) | NEES |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]

    def pair(block: FilterBlock, key: str) -> str:
        f, r = block.filtered, block.single_frame
        return "–" if f is None or r is None else f"{getattr(f, key):.2f} / {getattr(r, key):.2f}"

    for m, acc in summary.filter.items():
        rows = [(f"{b.depth_cm[0]}-{b.depth_cm[1]}", b.block) for b in acc.bands]
        rows += [("25-250 (all)", acc.all), ("under 25 (blind)", acc.under_25cm)]
        for name, b in rows:
            if not b.frames and not b.coasting_frames:
                continue
            c = b.coasting
            coast = f"{b.coasting_frames}" + (
                "" if c is None else f" ({c.depth_cm:.2f} / {c.lateral_cm:.2f} / {c.yaw_deg:.2f})"
            )
            nees = "–" if b.nees_mean is None else f"{b.nees_mean:.1f}"
            lines.append(
                f"| {m} | {name} | {b.frames} | {pair(b, 'depth_cm')} | {pair(b, 'lateral_cm')} | "
                f"{pair(b, 'yaw_deg')} | {coast} | {nees} |"
            )
    return "\n".join(lines) + "\n"


def console_table(summary: DockSimSummary) -> str:
    """A few lines for the terminal: per variant, success, median / p95 final errors, what went wrong and right."""
    lines = []

    def med(s: AbsStats) -> str:
        return "/".join("-" if v is None or not math.isfinite(v) else f"{v:.2f}" for v in (s.median, s.p95))

    for m, block in summary.methods.items():
        g = block.overall
        extra = f"charging {g.charging}, re-seats {g.reseats_total}, recovered {g.recovered}, hit {g.collisions}"
        if g.redock_tried:
            extra += f", undock+redock {g.redocked}/{g.redock_tried}"
        lines.append(
            f"{m:10s} docked {g.successes}/{g.runs} ({(g.success_rate or 0) * 100:.0f} %)  median/p95 final "
            f"lateral {med(g.final_lateral_cm)} cm  gap {med(g.final_longitudinal_cm)} cm  heading "
            f"{med(g.final_heading_deg)} deg  time {med(g.time_s)} s  ({extra})"
        )
    for m, acc in summary.filter.items():
        b = acc.all
        f, r = b.filtered, b.single_frame
        if f is None or r is None:
            continue
        lines.append(
            f"{m:10s} filter vs single frame, MAE 25-250 cm over {b.frames} frames: depth "
            f"{f.depth_cm:.2f} vs {r.depth_cm:.2f} cm, lateral {f.lateral_cm:.2f} vs "
            f"{r.lateral_cm:.2f} cm, yaw {f.yaw_deg:.2f} vs {r.yaw_deg:.2f} deg"
        )
    return "\n".join(lines)


def fault_table(summary: DockSimSummary, config: DockSimConfig) -> str:
    """Markdown: per fault and variant, how the runs ended: docked (of which after a recovery), failed cleanly
    (with a reason, stopped), docked outside the tolerances by the truth, and anything hit."""
    head = (
        "| fault | what happens | variant | runs | fault sprung | docked | of which recovered | failed cleanly "
        "| outside the tolerances | hit |\n|---|---|---|---:|---:|---:|---:|---:|---:|---:|"
    )
    rows = []
    for label, method, planner, fault in config.variants:
        block = summary.methods.get(label)
        if block is None:
            continue
        g = block.overall
        variant = method if len(config.planner_kinds) == 1 else f"{method} · {planner}"
        outside = g.failures.get("docked outside the tolerances", 0)
        rows.append(
            f"| {fault} | {FAULTS[fault]} | {variant} | {g.runs} | {g.faults_triggered if fault != 'none' else '–'} "
            f"| {g.successes} | {g.recovered} | {g.failed_cleanly} | {outside} | {g.collisions} |"
        )
    return "\n".join([head, *rows])


def room_table(results: Sequence[TrialResult]) -> str:
    """Per variant, and per start-distance band: docked and charging (by the sim's truth) with the Wilson 95 %
    interval, the median time to dock, and the failures by reason."""
    lines = [
        "| variant | starts | docked and charging | Wilson 95 % | median time, s | failures |",
        "|---|---|---|---|---|---|",
    ]
    labels = sorted({r.variant or r.method for r in results})
    bands = ((0.0, 99.0, "all"), (0.5, 2.0, "0.5-2 m"), (2.0, 3.5, "2-3.5 m"), (3.5, 99.0, "3.5-5 m"))
    # Several variants (faults, planners, methods): every run together first, the figure the envelope is judged by.
    pooled = ["every run"] if len(labels) > 1 else []
    for label in pooled + labels:
        for lo, hi, name in bands:
            runs = [
                r
                for r in results
                if label in ((r.variant or r.method), "every run") and lo <= math.hypot(r.start.x, r.start.y) < hi
            ]
            if not runs:
                continue
            ok = [r for r in runs if _docked_and_charging(r)]
            low, high = wilson(len(ok), len(runs))
            reasons: dict[str, int] = {}
            for r in runs:
                if not _docked_and_charging(r):
                    key = str(r.failure) if r.failure is not None else f"{r.state} (outside the tolerances)"
                    reasons[key] = reasons.get(key, 0) + 1
            times = [r.time_s for r in ok]
            median = f"{float(np.median(times)):.1f}" if times else "–"
            why = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())) or "–"
            lines.append(
                f"| {label} | {name} | {len(ok)}/{len(runs)} ({100 * len(ok) / len(runs):.1f} %) | "
                f"{100 * low:.1f}-{100 * high:.1f} % | {median} | {why} |"
            )
    return "\n".join(lines) + "\n"


def _docked_and_charging(r: TrialResult) -> bool:
    """Docked within the tolerances by the sim's truth, and charging where the robot could tell."""
    return r.success and r.charging is not False
