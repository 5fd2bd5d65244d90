"""The figures of a dock-sim run: its true paths by executed case and all together, where every run ended, and
one run at a time (its top view beside its errors and speed over time).

Top views are drawn as report.dock_cases draws them: the charger at the top, a dock-frame point (x, y) at (-y, x).
"""

from __future__ import annotations

import itertools
import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from monodock.core.layout import DockLayout
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.planner import CASES
from monodock.evaluation.dock_results import TrialResult
from monodock.evaluation.dock_sim import ROOM_BEARING_DEG, ROOM_DISTANCE, DockSimConfig
from monodock.report.dock_cases import draw_dock, draw_robot, top_uv
from monodock.report.dock_runs import (
    REVERSE_COLOUR,
    Phase,
    Variant,
    draw_path,
    nearest_index,
    path_times,
    phases,
    signed_speeds,
    state_colour,
    variant_label,
    variant_of,
    variants,
)
from monodock.report.plotting import METHOD_COLOURS, plt
from monodock.sim.diffdrive import DiffDriveConfig

__all__ = [
    "FAR_START",
    "final_error_plot",
    "room_far_trajectories",
    "room_success_map",
    "room_time_plot",
    "run_plot",
    "trajectory_overview",
    "trajectory_plot",
    "variant_grid",
]


def _limits(
    results: Sequence[TrialResult], default: tuple[float, float, float, float] = (-1.3, 1.3, -2.9, 0.4)
) -> tuple[float, float, float, float]:
    """A top view's (u0, u1, v0, v1): the default floor, grown to hold every path (and its footprint) and Point A."""
    u0, u1, v0, v1 = default
    for r in results:
        pts = [(p[0], p[1]) for p in r.path] + ([r.point_a] if r.point_a is not None else [])
        for x, y in pts:
            u0, u1 = min(u0, -y - 0.3), max(u1, -y + 0.3)
            v0, v1 = min(v0, x - 0.3), max(v1, x + 0.3)
    return u0, u1, v0, v1


def _mark_point_a(ax: Axes, r: TrialResult, *, ms: float = 5.0, label: bool = False) -> None:
    """The run's own Point A: a small cross (the papers' planner puts A on the start's heading line)."""
    if r.point_a is None:
        return
    u, v = top_uv(*r.point_a)
    ax.plot(u, v, marker="x", ms=ms, mew=1.2, color="tab:orange", zorder=5, ls="none")
    if label:
        ax.annotate("A", (u, v), xytext=(-14, -12), textcoords="offset points", fontsize=10, color="tab:orange")


def variant_grid(
    variant_list: Sequence[Variant],
) -> tuple[list[str], list[str], dict[Variant, tuple[int, int]]]:
    """Panels: a column per method, a row per planner."""
    methods = list(dict.fromkeys(m for m, _ in variant_list))
    planners = list(dict.fromkeys(p for _, p in variant_list))
    return methods, planners, {(m, p): (planners.index(p), methods.index(m)) for m, p in variant_list}


def trajectory_plot(
    case: int | None,
    runs: Mapping[Variant, Sequence[TrialResult]],
    path: Path,
    *,
    layout: DockLayout,
    robot: RobotConfig,
    drive: DiffDriveConfig,
) -> None:
    """The true paths of the runs that executed ``case`` (None: the runs that never planned), a panel per variant
    (a column per method, a row per planner). Blue paths docked within the tolerances, red ones did not; dashed
    purple legs the robot reversed; arrows every 0.4 m the way it moved; crosses each run's Point A; grey
    footprints the starts (orange: a start in another case's region), red where failed runs ended."""
    variant_list = list(runs)
    methods, planners, cell = variant_grid(variant_list)
    rows, cols = len(planners), len(methods)
    every = [r for v in variant_list for r in runs[v]]
    u0, u1, v0, v1 = _limits(every)
    panel_w = 4.0
    panel_h = 0.86 * panel_w * (v1 - v0) / (u1 - u0) + 0.75
    fig, axes = plt.subplots(rows, cols, figsize=(panel_w * cols, panel_h * rows + 0.6), squeeze=False)
    for ax in axes.flat:
        ax.set_visible(False)
    for v in variant_list:
        ax = axes[cell[v]]
        ax.set_visible(True)
        draw_dock(ax, layout, None)
        ok = 0
        faint = 0.3 if len(runs[v]) <= 8 else 0.16  # many footprints would hide the paths
        for r in runs[v]:
            ok += r.success
            if not r.path:
                continue
            draw_path(ax, r.path, color="tab:blue" if r.success else "tab:red", lw=0.8, alpha=0.6, arrow_size=8.0)
            _mark_point_a(ax, r)
            other = case is not None and r.case != case
            draw_robot(ax, Pose2D(*r.path[0]), robot, drive, color="tab:orange" if other else "0.4", alpha=faint)
            if not r.success:  # a docked run ends at the face, like every other docked run
                draw_robot(ax, Pose2D(*r.path[-1]), robot, drive, color="tab:red", alpha=0.45)
        ax.set_aspect("equal")
        ax.set_xlim(u0, u1)
        ax.set_ylim(v0, v1)
        label = variant_label(v, planners)
        others = sum(case is not None and r.case != case for r in runs[v])
        more = f"\n{others} from another region" if others else ""
        ax.set_title(f"{label}: {ok}/{len(runs[v])} docked{more}", fontsize=10)
        ax.set_xlabel("← left of the axis (m)   |   right →", fontsize=8)
        ax.tick_params(labelsize=7)
        if cell[v][1] == 0:
            ax.set_ylabel("distance along the axis (m)", fontsize=8)
    head = "never planned (no case executed)" if case is None else f"executed case {case}: {CASES[case].title}"
    fig.suptitle(textwrap.fill(head, int(13 * panel_w * cols)), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def final_error_plot(
    results: Sequence[tuple[str, float, float, float]], path: Path, tolerances: tuple[float, float]
) -> None:
    """Final lateral error against final heading error, every run, a colour per method; the tolerance box."""
    fig, ax = plt.subplots(figsize=(6.0, 4.6))
    methods = sorted({r[0] for r in results})
    for i, m in enumerate(methods):
        pts = [(r[1], r[2]) for r in results if r[0] == m]
        colour = METHOD_COLOURS.get(m, f"C{i}")
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=12, alpha=0.7, label=m, color=colour)
    lat, head = tolerances
    ax.add_patch(Rectangle((-lat, -head), 2 * lat, 2 * head, fill=False, ls="--", ec="0.3"))
    ax.set_xlabel("final lateral error, cm (+ left of the axis)")
    ax.set_ylabel("final heading error, degrees")
    ax.set_title("where every run ended (dashed: the docking tolerances)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def trajectory_overview(
    results: Sequence[TrialResult],
    config: DockSimConfig,
    path: Path,
    *,
    panel_px: int = 220,
) -> None:
    """Every run's true path in one small top view per variant (all cases together; a column per method, a row per
    planner), for a report's first screen.

    Blue paths docked within the tolerances, red ones did not, dashed purple legs were driven in reverse; arrows
    point the way the robot moved; crosses are the runs' Points A; grey footprints are the starts.
    """
    variant_list = variants(results, config)
    methods, planners, cell = variant_grid(variant_list)
    rows, cols = len(planners), len(methods)
    dpi = 100
    u0, u1, v0, v1 = _limits(results)
    width = max(panel_px * cols, 280) / dpi
    # Panels of equal aspect over the floor drawn, plus room for the titles and labels.
    height = rows * (0.85 * panel_px / dpi * (v1 - v0) / (u1 - u0) + 0.6) + 0.15
    fig, axes = plt.subplots(rows, cols, figsize=(width, height), squeeze=False, sharex=True, sharey=True)
    for ax in axes.flat:
        ax.set_visible(False)
    for v in variant_list:
        ax = axes[cell[v]]
        ax.set_visible(True)
        draw_dock(ax, config.layout, None)
        runs = [r for r in results if variant_of(r) == v]
        faint = 0.3 if len(runs) <= 8 else 0.15
        for r in runs:
            if not r.path:
                continue
            draw_path(
                ax,
                r.path,
                color="tab:blue" if r.success else "tab:red",
                lw=0.7,
                alpha=0.6,
                arrow_every=0.8,
                arrow_size=4.5,
            )
            _mark_point_a(ax, r, ms=3.0)
            draw_robot(ax, Pose2D(*r.path[0]), config.robot, config.drive, color="0.45", alpha=faint)
        ax.set_aspect("equal")
        ax.set_xlim(u0, u1)
        ax.set_ylim(v0, v1)
        ax.set_title(f"{variant_label(v, planners)}\n{sum(r.success for r in runs)}/{len(runs)} docked", fontsize=8.5)
        ax.tick_params(labelsize=7)
        if cell[v][0] == rows - 1:
            ax.set_xlabel("lateral (m)", fontsize=7)
        if cell[v][1] == 0:
            ax.set_ylabel("along the axis (m)", fontsize=7)
    fig.tight_layout(pad=0.4)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


_SeriesPanel = tuple[str, np.ndarray, np.ndarray, int | None]  # y label, times, values, tolerance index (or None)


def _state_start_dots(ax: Axes, r: TrialResult, t: np.ndarray, ph: Sequence[Phase]) -> None:
    """A dot on the top view where each state began; states that began at the same spot as concentric rings, the
    first outermost."""
    spots = [top_uv(*r.path[nearest_index(t, phase.start)][:2]) for phase in ph]
    clusters: list[list[int]] = []
    for k, (u, v) in enumerate(spots):
        near = [c for c in clusters if math.dist(spots[c[0]], (u, v)) < 0.03]
        if near:
            near[0].append(k)
        else:
            clusters.append([k])
    for cluster in clusters:
        for i, k in enumerate(cluster):
            ax.plot(
                *spots[k],
                marker="o",
                ms=6 + 4 * (len(cluster) - 1 - i),
                mec="0.15",
                mew=0.6,
                color=state_colour(ph[k].state),
                zorder=6 + 0.01 * i,
                ls="none",
            )


def _frame_run_top(ax: Axes, r: TrialResult) -> None:
    """The limits, aspect, labels and grid of a run's top view."""
    u0, u1, v0, v1 = _limits([r], default=(-0.35, 0.35, -0.5, 0.25))
    # Equal aspect in a tall panel: widen the narrower side so the panel is filled.
    span_u, span_v = u1 - u0, v1 - v0
    if span_u < span_v * 0.62:
        grow = (span_v * 0.62 - span_u) / 2
        u0, u1 = u0 - grow, u1 + grow
    ax.set_aspect("equal")
    ax.set_xlim(u0, u1)
    ax.set_ylim(v0, v1)
    ax.set_xlabel("← left of the axis (m)   |   right →", fontsize=8)
    ax.set_ylabel("distance along the axis (m); charger face at 0", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.2)


def _run_series(r: TrialResult, t: np.ndarray, robot: RobotConfig) -> list[_SeriesPanel]:
    """The time series of a run: lateral error, gap to the face, heading (at the path's samples) and speed."""
    p = np.asarray(r.path, dtype=float).reshape(-1, 3)
    lateral = p[:, 1] * 100
    gap = (-p[:, 0] - robot.front_offset) * 100
    heading = np.degrees(p[:, 2])
    t0, t1, speed = signed_speeds(r)
    # The speed as steps: constant over each step between samples.
    ts, speed = np.column_stack([t0, t1]).ravel(), np.repeat(speed, 2)
    return [
        ("lateral error, cm\n(+ left)", t, lateral, 0),
        ("gap to the face, cm", t, gap, 1),
        ("heading, °", t, heading, 2),
        ("speed along the\nheading, m/s", ts, speed, None),
    ]


def _draw_run_series(
    series: Sequence[Axes],
    data: Sequence[_SeriesPanel],
    ph: Sequence[Phase],
    tolerances: tuple[float, float, float] | None,
) -> None:
    """Each time series in its panel over the states' shading, reversing filled, with its tolerance band dashed."""
    for ax, (name, xs, ys, tol) in zip(series, data, strict=True):
        for phase in ph:
            ax.axvspan(phase.start, phase.end, color=state_colour(phase.state), alpha=0.35, lw=0, zorder=0)
            ax.axvline(phase.start, color="0.5", lw=0.5, zorder=1)
        if tol is None and len(ys):
            ax.fill_between(xs, ys, 0, where=ys < 0, color=REVERSE_COLOUR, alpha=0.5, lw=0, zorder=2)
        ax.plot(xs, ys, color="0.15", lw=1.1, zorder=3)
        ax.axhline(0.0, color="0.4", lw=0.6, zorder=1)
        if tolerances is not None and tol is not None:
            band = tolerances[tol]
            for s in (-1, 1):  # the success test is |error| <= band, the gap's overshoot into the face included
                ax.axhline(s * band, color="0.3", lw=0.7, ls="--", zorder=1)
        ax.set_ylabel(name, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.2)
        if ax is not series[-1]:
            ax.tick_params(labelbottom=False)


def _state_legend(fig: Figure, ph: Sequence[Phase]) -> None:
    """The states, in the order the run met them, as the legend of the dots and the shading."""
    seen = list(dict.fromkeys(phase.state for phase in ph))
    handles: list[Artist] = [Rectangle((0, 0), 1, 1, color=state_colour(s), alpha=0.6) for s in seen]
    handles.append(Line2D([], [], color=REVERSE_COLOUR, ls=(0, (3, 1.5)), lw=1.8))
    fig.legend(handles, [*seen, "reversing"], loc="lower center", ncol=min(len(handles), 8), fontsize=8, frameon=False)


def _run_title(r: TrialResult, label: str) -> str:
    """A run plot's title: its start region and executed case, outcome and final errors."""
    executed = "none (never planned)" if r.classified_case is None else str(r.classified_case)
    agree = "" if r.classified_case in (None, r.case) else " (not the start region's)"
    outcome = "docked" if r.success else f"failed{f' ({r.failure})' if r.failure else ''}"
    return (
        f"{label}, trial {r.trial}: start region {r.case}, executed case {executed}{agree} — {outcome}; "
        f"final lateral {r.lateral_cm:+.1f} cm, gap {r.longitudinal_cm:+.1f} cm, heading {r.heading_deg:+.1f}°, "
        f"{r.time_s:.1f} s, {r.retries} retries"
    )


def run_plot(
    result: TrialResult,
    path: Path,
    *,
    layout: DockLayout,
    robot: RobotConfig,
    drive: DiffDriveConfig,
    label: str | None = None,
    tolerances: tuple[float, float, float] | None = None,
) -> None:
    """One run: its top view (the path with arrows, dashed purple where it reversed; start and end footprints;
    its Point A; a dot where each state of its log began) beside the lateral error, the gap to the face, the
    heading and the signed speed along the heading over time, the states shaded.

    ``tolerances``: the success box (lateral cm, gap cm, heading °), drawn dashed on the time series.
    """
    r = result
    label = label or f"{r.method} · {r.planner}"
    fig = plt.figure(figsize=(12.0, 6.6))
    grid = fig.add_gridspec(4, 2, width_ratios=(1.0, 1.45), hspace=0.12, wspace=0.16)
    top = fig.add_subplot(grid[:, 0])
    series = [fig.add_subplot(grid[0, 1])]
    series += [fig.add_subplot(grid[i, 1], sharex=series[0]) for i in (1, 2, 3)]
    draw_dock(top, layout, None)
    t = path_times(r)
    ph = phases(r)
    colour = "tab:blue" if r.success else "tab:red"
    if r.path:
        draw_path(top, r.path, color=colour, lw=1.4, alpha=0.85, arrow_every=0.25, arrow_size=10.0)
        draw_robot(top, Pose2D(*r.path[0]), robot, drive, color="0.35", alpha=0.6)
        draw_robot(top, Pose2D(*r.path[-1]), robot, drive, color="tab:green" if r.success else "tab:red")
        _state_start_dots(top, r, t, ph)
    _mark_point_a(top, r, ms=9.0, label=True)
    _frame_run_top(top, r)

    _draw_run_series(series, _run_series(r, t, robot), ph, tolerances)
    series[-1].set_xlabel("time since the start, s", fontsize=8)
    if len(t):
        series[0].set_xlim(0.0, max(float(t[-1]), *(phase.end for phase in ph)) if ph else float(t[-1]) or 1.0)
    _state_legend(fig, ph)
    fig.suptitle(_run_title(r, label), fontsize=9.5)
    fig.subplots_adjust(left=0.06, right=0.985, top=0.93, bottom=0.13)
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- the room envelope (``dock-sim --starts room``) ------------------------------------------------------------

FAR_START = 3.5  # m from the face centre: the room figures' "far starts"


def _start_distance(r: TrialResult) -> float:
    return math.hypot(r.start.x, r.start.y)


def _start_bearing_deg(r: TrialResult) -> float:
    """The start's bearing off the dock's axis, seen from the face centre, degrees (+ left)."""
    return math.degrees(math.atan2(r.start.y, -r.start.x))


def _outcome(r: TrialResult) -> str:
    """docked, or the failure's name (the state when the mission did not say)."""
    if r.success:
        return "docked"
    return str(r.failure) if r.failure is not None else f"not docked ({r.state})"


_OUTCOME_MARKERS = ("x", "s", "^", "v", "D", "P", "*")


def room_success_map(results: Sequence[TrialResult], config: DockSimConfig, path: Path) -> None:
    """Where every room start lay (top view, the charger at the top), a dot per run coloured by its outcome (a
    panel per variant): blue docked and charging, red and a marker per failure reason otherwise; a tick from each
    dot shows the start heading. Dashed: the envelope (0.5-5 m, ±60°)."""
    variant_list = variants(results, config)
    methods, planners, _ = variant_grid(variant_list)
    n = len(variant_list)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    panel = 5.5 if n == 1 else 3.3  # one panel: room for 200 dots
    # the envelope is about 0.6 as deep as it is wide; the rest is the titles and the legend
    fig, axes = plt.subplots(rows, cols, figsize=(panel * cols, 0.72 * panel * rows + 0.9), squeeze=False)
    for ax in axes.flat:
        ax.set_visible(False)
    failures = sorted({_outcome(r) for r in results} - {"docked"})
    for i, v in enumerate(variant_list):
        ax = axes[i // cols][i % cols]
        ax.set_visible(True)
        draw_dock(ax, config.layout, None)
        b = math.radians(ROOM_BEARING_DEG)
        for d in ROOM_DISTANCE:
            t = np.linspace(-b, b, 60)
            ax.plot(d * np.sin(t), -d * np.cos(t), ls="--", color="0.6", lw=0.7)
        for s in (-1, 1):
            ax.plot(
                [s * ROOM_DISTANCE[0] * math.sin(b), s * ROOM_DISTANCE[1] * math.sin(b)],
                [-ROOM_DISTANCE[0] * math.cos(b), -ROOM_DISTANCE[1] * math.cos(b)],
                ls="--",
                color="0.6",
                lw=0.7,
            )
        runs = [r for r in results if variant_of(r) == v]
        for r in runs:
            u, w = top_uv(r.start.x, r.start.y)
            du, dw = top_uv(math.cos(r.start.theta), math.sin(r.start.theta))
            ok = r.success
            colour = "tab:blue" if ok else "tab:red"
            ax.plot([u, u + 0.25 * du], [w, w + 0.25 * dw], color=colour, lw=0.6, alpha=0.7)
            marker = "o" if ok else _OUTCOME_MARKERS[failures.index(_outcome(r)) % len(_OUTCOME_MARKERS)]
            ax.plot(u, w, marker=marker, ms=3.5 if ok else 5.5, color=colour, ls="none", alpha=0.85)
        ax.set_aspect("equal")
        ax.set_xlim(-4.8, 4.8)
        ax.set_ylim(-5.3, 0.5)
        ax.set_title(f"{variant_label(v, planners)}: {sum(r.success for r in runs)}/{len(runs)} docked", fontsize=8.5)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("lateral (m)", fontsize=7)
        ax.set_ylabel("along the axis (m)", fontsize=7)
    handles = [Line2D([], [], marker="o", color="tab:blue", ls="none", label="docked and charging")]
    handles += [
        Line2D([], [], marker=_OUTCOME_MARKERS[i % len(_OUTCOME_MARKERS)], color="tab:red", ls="none", label=f)
        for i, f in enumerate(failures)
    ]
    fig.tight_layout()
    # The panels keep the room's aspect, so they do not fill their cells: the title and the legend go against the
    # panels as drawn, and the blank bands around them are cropped.
    shown = [ax for ax in axes.flat if ax.get_visible()]
    for ax in shown:
        ax.apply_aspect()
    top = max(ax.get_position().y1 for ax in shown)
    bottom = min(ax.get_position().y0 for ax in shown)
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, bottom - 0.1 / rows),
        ncol=min(4, len(handles)),
        fontsize=7.5,
        frameon=False,
    )
    fig.suptitle("room starts by outcome (a tick: the start heading)", fontsize=9, y=top + 0.08 / rows)
    fig.savefig(path, dpi=90, bbox_inches="tight", pad_inches=0.1)
    plt.close(fig)
    del methods


def room_time_plot(results: Sequence[TrialResult], path: Path) -> None:
    """Time to dock against the start's distance from the face centre (docked runs; a colour per variant), with
    the median per metre."""
    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    labels = sorted({r.variant or r.method for r in results})
    for i, label in enumerate(labels):
        runs = [r for r in results if (r.variant or r.method) == label and r.success]
        ax.scatter([_start_distance(r) for r in runs], [r.time_s for r in runs], s=10, alpha=0.6, color=f"C{i}")
        ax.scatter([], [], s=10, color=f"C{i}", label=label)
    docked = [r for r in results if r.success]
    edges = np.arange(0.5, 5.51, 1.0)
    mids, medians = [], []
    for lo, hi in itertools.pairwise(edges):
        times = [r.time_s for r in docked if lo <= _start_distance(r) < hi]
        if times:
            mids.append(0.5 * (lo + hi))
            medians.append(float(np.median(times)))
    ax.plot(mids, medians, "k-o", ms=4, lw=1.2, label="median, per metre")
    ax.set_xlabel("start distance from the face centre, m")
    ax.set_ylabel("time to dock, s")
    ax.set_title("time to dock by start distance (docked runs)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def room_far_trajectories(results: Sequence[TrialResult], config: DockSimConfig, path: Path, *, cap: int = 30) -> None:
    """The true paths of the far starts (beyond FAR_START from the face centre), at most ``cap`` per variant's
    panel: blue docked, red not; dashed purple: reversing; a footprint at each start."""
    variant_list = variants(results, config)
    _, planners, _ = variant_grid(variant_list)
    n = len(variant_list)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.3 * cols, 3.3 * rows), squeeze=False)
    for ax in axes.flat:
        ax.set_visible(False)
    for i, v in enumerate(variant_list):
        ax = axes[i // cols][i % cols]
        ax.set_visible(True)
        draw_dock(ax, config.layout, None)
        far = [r for r in results if variant_of(r) == v and _start_distance(r) >= FAR_START]
        # every failure drawn, then docked runs up to the cap (beyond it the picture is a blur of lines)
        runs = [r for r in far if not r.success] + [r for r in far if r.success]
        runs = runs[: max(cap, sum(not r.success for r in far))]
        for r in runs:
            draw_path(ax, r.path, color="tab:blue" if r.success else "tab:red", lw=0.7, alpha=0.7, arrow_every=1.0)
            draw_robot(ax, Pose2D(*r.path[0]), config.robot, config.drive, color="0.45", alpha=0.25)
        ax.set_aspect("equal")
        ax.set_xlim(-4.8, 4.8)
        ax.set_ylim(-5.3, 0.5)
        docked = sum(r.success for r in far)
        drawn = "" if len(runs) == len(far) else f", {len(runs)} drawn"
        title = f"{variant_label(v, planners)}: {docked}/{len(far)} docked from ≥ {FAR_START:g} m{drawn}"
        ax.set_title(title, fontsize=8.5)
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
