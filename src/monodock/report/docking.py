"""Docking in pictures and tables: the case diagrams (the docs'), and the files and report of a dock-sim run.

Top views are drawn as a person standing behind the robot sees the floor: the charger at the top, the dock
frame's y (left) to the left. A dock-frame point (x, y) is drawn at (-y, x).

``python -m monodock.report.docking DIR`` redraws the eight case diagrams into DIR.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import FancyArrowPatch, Polygon, Rectangle

from monodock.core.layout import DockLayout
from monodock.core.parallel import map_with_state
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.planner import CASES, PLANNERS, Manoeuvre, PlannerConfig, plan_for, point_a
from monodock.evaluation.dock_sim import (
    FAULTS,
    AbsStats,
    DockSimConfig,
    DockSimSummary,
    FilterBlock,
    RunGroup,
    TrialResult,
    runs_csv,
)
from monodock.report.dock_runs import (
    REVERSE_COLOUR,
    Phase,
    Variant,
    agreement_table,
    draw_path,
    executed_case_table,
    nearest_index,
    path_times,
    phases,
    run_file,
    select_runs,
    signed_speeds,
    state_colour,
    variant_label,
    variant_of,
    variants,
)
from monodock.report.html import HtmlReport, plain
from monodock.report.plotting import METHOD_COLOURS, plt
from monodock.sim.diffdrive import DiffDriveConfig
from monodock.sim.world import ChargerGeometry

__all__ = [
    "case_diagram",
    "comparison_table",
    "console_table",
    "dock_section",
    "dock_settings",
    "draw_dock",
    "draw_robot",
    "example_start",
    "filter_table",
    "final_error_plot",
    "run_plot",
    "trajectory_cases",
    "trajectory_file",
    "trajectory_overview",
    "trajectory_plot",
    "write_case_diagrams",
    "write_dock_files",
    "write_dock_report",
]


_LABEL_BOX = {"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.85}


def _uv(x: float, y: float) -> tuple[float, float]:
    return -y, x


def draw_dock(ax: Axes, layout: DockLayout, a: Pose2D | None, reach: float = 2.6) -> None:
    """The charger, its markers, the approach axis and Point A."""
    ch = ChargerGeometry()
    ax.add_patch(Rectangle((-ch.width / 2, 0.0), ch.width, ch.depth, color="0.75", zorder=1))
    ax.plot([-ch.width / 2, ch.width / 2], [0, 0], color="0.2", lw=3, zorder=2)
    colours = {"left": "tab:red", "center": "tab:green", "right": "tab:blue"}
    for m in layout.markers:
        u = -m.y
        ax.plot(
            [u - layout.marker_size / 2, u + layout.marker_size / 2],
            [0.012, 0.012],
            color=colours[m.role],
            lw=4,
            zorder=3,
        )
    ax.plot([0, 0], [-reach, 0], ls="--", color="0.5", lw=1, zorder=1)
    if a is not None:
        ax.plot(*_uv(a.x, a.y), marker="*", ms=14, color="tab:orange", zorder=5)
        ax.annotate("A", _uv(a.x, a.y), xytext=(8, -4), textcoords="offset points", fontsize=11, color="tab:orange")


def draw_robot(
    ax: Axes, pose: Pose2D, robot: RobotConfig, drive: DiffDriveConfig, *, color: str, alpha: float = 1.0
) -> None:
    """The robot's footprint and a heading arrow, at a pose in the dock frame."""
    half = drive.footprint_width / 2
    corners = [
        (robot.front_offset, half),
        (robot.front_offset, -half),
        (-drive.rear_offset, -half),
        (-drive.rear_offset, half),
    ]
    pts = [_uv(*pose.point(cx, cy)) for cx, cy in corners]
    ax.add_patch(Polygon(pts, closed=True, fill=False, ec=color, lw=1.2, alpha=alpha, zorder=4))
    tip = _uv(*pose.point(robot.front_offset * 0.9, 0.0))
    ax.add_patch(
        FancyArrowPatch(
            _uv(pose.x, pose.y), tip, arrowstyle="-|>", mutation_scale=10, color=color, alpha=alpha, zorder=4
        )
    )


def example_start(case: int, planner: PlannerConfig, robot: RobotConfig) -> Pose2D:
    """A typical start of the case for its diagram: in the case's region, and one from which the configured
    planner executes that case (the papers' planner reaches some cases only from some starts of the region)."""
    spec = CASES[case]
    d_a = -point_a(planner, robot.front_offset).x
    side = 1.0 if spec.side == "left" else -1.0
    turn = -side if spec.heading == "towards" else side
    candidates = [
        Pose2D(-(d_a + dd if spec.zone == "before" else d_a - dd), side * y, turn * math.radians(h))
        for dd in ((0.7, 0.4, 1.0) if spec.zone == "before" else (0.2, 0.1, 0.3))
        for y in (0.45, 0.3, 0.6, 0.2)
        for h in (20.0, 30.0, 12.0, 40.0)
    ]
    matching = [(start, plan_for(start, planner, robot.front_offset)) for start in candidates]
    matching = [(start, m) for start, m in matching if m.case == case]
    # The most telling start: the papers' own heading-line manoeuvre where the case has one; monodock's back-out
    # short of its cap.
    for start, m in matching:
        if (m.planner == "papers") if planner.kind == "papers" else m.back_out < planner.max_back_out:
            return start
    return matching[0][0] if matching else candidates[0]


def case_diagram(
    case: int,
    path: Path,
    *,
    planner: PlannerConfig | None = None,
    layout: DockLayout | None = None,
    robot: RobotConfig | None = None,
    drive: DiffDriveConfig | None = None,
) -> None:
    """The case's region and its manoeuvre by the configured planner from a typical start: (back out,) turn,
    drive (or reverse) to A, turn, approach."""
    planner = planner or PlannerConfig()
    layout = layout or DockLayout.default()
    robot = robot or RobotConfig.default()
    drive = drive or DiffDriveConfig()
    start = example_start(case, planner, robot)
    m = plan_for(start, planner, robot.front_offset)
    a = m.point_a
    fixed_a = point_a(planner, robot.front_offset)
    fig, ax = plt.subplots(figsize=(5.2, 6.4))
    draw_dock(ax, layout, a)
    # The region: which side of the axis, and before or past the stand-off Point A.
    side = 1.0 if CASES[case].side == "left" else -1.0
    y0, y1 = sorted((0.0, -side * 1.2))
    x0, x1 = (-3.0, fixed_a.x) if CASES[case].zone == "before" else (fixed_a.x, -robot.front_offset)
    ax.add_patch(Rectangle((y0, x0), y1 - y0, x1 - x0, color="tab:blue", alpha=0.06, zorder=0))
    backed = start.compose(Pose2D(-m.back_out, 0.0, 0.0))
    turned = Pose2D(backed.x, backed.y, m.drive_heading)
    at_a = Pose2D(a.x, a.y, m.drive_heading)
    docked = Pose2D(-robot.front_offset, 0.0, 0.0)
    draw_robot(ax, start, robot, drive, color="tab:blue")
    style: dict[str, Any] = {"arrowstyle": "-|>", "mutation_scale": 14, "lw": 2}
    if m.back_out > 0:
        draw_robot(ax, backed, robot, drive, color="tab:purple", alpha=0.35)
        ax.add_patch(
            FancyArrowPatch(_uv(start.x, start.y), _uv(backed.x, backed.y), color="tab:purple", ls="--", **style)
        )
    if abs(m.first_turn) > 1e-6:
        draw_robot(ax, turned, robot, drive, color="tab:blue", alpha=0.35)
    draw_robot(ax, at_a, robot, drive, color="tab:orange", alpha=0.5)
    draw_robot(ax, Pose2D(a.x, a.y, 0.0), robot, drive, color="tab:orange")
    draw_robot(ax, docked, robot, drive, color="tab:green")
    ax.add_patch(
        FancyArrowPatch(
            _uv(backed.x, backed.y), _uv(a.x, a.y), color="tab:purple", ls="--" if m.reverse else "-", **style
        )
    )
    ax.add_patch(FancyArrowPatch(_uv(a.x, a.y), _uv(docked.x, docked.y), color="tab:green", **style))
    words = f"back out {m.back_out:.2f} m,\n" if m.back_out > 0 else ""
    ax.annotate(
        f"Moving₁: {words}turn {math.degrees(m.first_turn):+.0f}°,\n"
        f"{'reverse' if m.reverse else 'drive'} {m.drive_distance:.2f} m",
        _uv(start.x, start.y),
        xytext=(12 * side, -28),
        textcoords="offset points",
        fontsize=9,
        ha="right" if side > 0 else "left",
        color="tab:purple",
        bbox=_LABEL_BOX,
    )
    ax.annotate(
        f"Moving₂: turn {math.degrees(m.second_turn):+.0f}°",
        _uv(a.x, a.y),
        xytext=(-12 * side, -18),
        textcoords="offset points",
        fontsize=9,
        ha="left" if side > 0 else "right",
        color="tab:orange",
        bbox=_LABEL_BOX,
    )
    ax.annotate(
        "Moving₃: P-control",
        _uv(0.5 * (a.x - robot.front_offset), 0.0),
        xytext=(8, 0),
        textcoords="offset points",
        fontsize=9,
        color="tab:green",
        bbox=_LABEL_BOX,
    )
    ax.set_aspect("equal")
    ax.set_xlim(-1.3, 1.3)
    ax.set_ylim(-3.0, 0.45)
    ax.set_xlabel("← left of the axis (m)   |   right →")
    ax.set_ylabel("distance along the axis (m); charger face at 0")
    ax.set_title(f"{CASES[case].title}\n{_PLANNER_TITLES[m.planner]}", fontsize=9.5)
    fig.text(0.5, 0.01, textwrap.fill(_manoeuvre_words(m), 80), ha="center", va="bottom", fontsize=7.5)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


_PLANNER_TITLES = {
    "monodock": "monodock's planner: A at the stand-off, no jumps",
    "papers": "papers' planner: A on the heading line, Moving₁ straight",
    "turn-first": "papers' planner, no usable crossing: Fig. 15's turn first",
}


def _manoeuvre_words(m: Manoeuvre) -> str:
    """What the robot does, in words."""
    turn1, turn2 = math.degrees(m.first_turn), math.degrees(m.second_turn)

    def turn(deg: float) -> str:
        return f"turn {'left' if deg > 0 else 'right'} {abs(deg):.0f}°"

    legs = [f"back out straight {m.back_out:.2f} m along its heading"] if m.back_out > 0 else []
    if abs(turn1) > 0.5:
        legs.append(turn(turn1) + (" to put its back to A" if m.reverse else " to face A"))
    legs.append(f"{'reverse' if m.reverse else 'drive forward'} {m.drive_distance:.2f} m to A")
    legs.append(turn(turn2) + " square to the face (Θab)")
    legs.append("straight in under P-control")
    return "; ".join(legs)


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
    u, v = _uv(*r.point_a)
    ax.plot(u, v, marker="x", ms=ms, mew=1.2, color="tab:orange", zorder=5, ls="none")
    if label:
        ax.annotate("A", (u, v), xytext=(-14, -12), textcoords="offset points", fontsize=10, color="tab:orange")


def _variant_grid(
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
    methods, planners, cell = _variant_grid(variant_list)
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


def write_case_diagrams(folder: Path, planner: PlannerConfig | None = None) -> list[Path]:
    """<planner>_case_1.png … <planner>_case_8.png into ``folder``: the configured planner's, or both planners'."""
    folder.mkdir(parents=True, exist_ok=True)
    kinds = [planner] if planner is not None else [PlannerConfig(kind=k) for k in PLANNERS]
    out = []
    for config in kinds:
        for case in CASES:
            p = folder / f"{config.kind}_case_{case}.png"
            case_diagram(case, p, planner=config)
            out.append(p)
    return out


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
    methods, planners, cell = _variant_grid(variant_list)
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
    spots = [_uv(*r.path[nearest_index(t, phase.start)][:2]) for phase in ph]
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
            for s in (-1, 1) if tol != 1 else (1,):
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


# --- dock-sim's files and report ------------------------------------------------------------------------


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


def trajectory_cases(results: Sequence[TrialResult], config: DockSimConfig) -> list[int | None]:
    """The executed cases with a trajectory figure: the config's cases, any other a run executed, and None (the
    runs that never planned) when there are such."""
    cases: list[int | None] = list(config.cases)
    cases += sorted({r.classified_case for r in results if r.classified_case is not None} - set(config.cases))
    if any(r.classified_case is None for r in results):
        cases.append(None)
    return cases


def trajectory_file(case: int | None) -> str:
    return f"trajectories_case_{'none' if case is None else case}.png"


def _draw(_: None, figure: tuple[Any, tuple[Any, ...], dict[str, Any]]) -> None:
    """Draw one figure: ``fn(*args, **kwargs)`` (in a worker process when write_dock_files has jobs > 1)."""
    fn, args, kwargs = figure
    fn(*args, **kwargs)


def write_dock_files(
    out: Path, results: Sequence[TrialResult], config: DockSimConfig, *, jobs: int = 1
) -> list[TrialResult]:
    """Into ``out``: runs.csv; the trajectories of every variant, one PNG per executed case (trajectory_file) and an
    overview (trajectories.png); the case diagrams; the error scatter; and runs/*.png, a figure for each run of
    select_runs. Returns those runs.

    The figures are independent of each other: with ``jobs`` > 1 they are drawn in that many worker processes
    (the same files)."""
    (out / "runs.csv").write_text(runs_csv(results), encoding="utf-8")
    scene = {"layout": config.layout, "robot": config.robot, "drive": config.drive}
    variant_list = variants(results, config)
    figures: list[tuple[Any, tuple[Any, ...], dict[str, Any]]] = []
    for case in trajectory_cases(results, config):
        runs = {v: [r for r in results if r.classified_case == case and variant_of(r) == v] for v in variant_list}
        figures.append((trajectory_plot, (case, runs, out / trajectory_file(case)), scene))
    for kind in config.planner_kinds:
        planner = dataclasses.replace(config.mission.planner, kind=kind)
        for case in config.cases:
            figures.append((case_diagram, (case, out / f"{kind}_case_{case}.png"), {"planner": planner, **scene}))
    figures.append((trajectory_overview, (results, config, out / "trajectories.png"), {}))
    c = config.mission
    tolerances = (c.tolerance_lateral * 100, c.tolerance_longitudinal * 100, c.tolerance_heading_deg)
    errors = [(r.method, r.lateral_cm, r.heading_deg, r.longitudinal_cm) for r in results]
    figures.append((final_error_plot, (errors, out / "final_errors.png", (tolerances[0], tolerances[2])), {}))
    chosen = select_runs(results, variant_list)
    if chosen:
        (out / "runs").mkdir(exist_ok=True)
    planners = [p for _, p in variant_list]
    for r in chosen:
        label = variant_label(variant_of(r), planners)
        figures.append((run_plot, (r, out / run_file(r)), {"label": label, "tolerances": tolerances, **scene}))
    # A worker costs ~3 s of a core to start (numba's and matplotlib's imports), a figure ~0.3 s: a pool pays
    # from about two dozen figures on (the demo's forty; not one dock-sim run's five).
    for _ in map_with_state(_draw, None, figures, jobs=jobs if len(figures) >= 24 else 1, chunksize=1):
        pass
    return chosen


def dock_settings(config: DockSimConfig) -> dict[str, object]:
    """A dock-sim run's settings, as a person reads them (units in the names, angles in degrees)."""
    c, d = config.mission, config.drive
    return {
        "starts": {
            "per case": config.trials,
            "seed": config.seed,
            "distance_from_face_m": list(config.distance),
            "max_heading_deg": config.max_heading_deg,
            "marker 2 in view": True,
        },
        "Point A": {"planners": ", ".join(config.planner_kinds), "standoff_m": c.planner.standoff},
        "robot": {
            "camera_rate_hz": d.camera_rate,
            "camera_latency_ms": round(d.camera_latency * 1000, 3),
            "command_latency_ms": round(d.command_latency * 1000, 3),
            "wheel_scale_error_pct": round(d.wheel_scale_sd * 100, 6),
            "wheel_noise_pct_per_step": round(d.wheel_noise_sd * 100, 6),
            "contact_sensor": d.contact_sensor,
            "exposure_ms": round(d.exposure_time * 1000, 3),
            "frame_drop_rate": d.frame_drop_rate,
            "latency_spike_rate": d.latency_spike_rate,
            "rear_range_sensor": d.rear_sensor,
            "charging_signal": d.charging_signal,
            "charger_contacts": f"lateral within {d.contact_lateral_tolerance * 100:g} cm, heading within "
            f"{d.contact_heading_tolerance_deg:g} deg, for {d.charge_delay:g} s",
        },
        "success (by the truth)": {
            "lateral_cm": c.tolerance_lateral * 100,
            "gap_cm": c.tolerance_longitudinal * 100,
            "heading_deg": c.tolerance_heading_deg,
        },
        "nuisances": plain(config.nuisances.updated(supersample=config.supersample)),
    }


def dock_section(
    report: HtmlReport,
    summary: DockSimSummary,
    config: DockSimConfig,
    folder: str = "",
    *,
    level: int = 3,
    results: Sequence[TrialResult] = (),
) -> None:
    """The closed-loop docking section: the side-by-side table, error scatter, filter table and trajectories.

    ``folder`` is where write_dock_files put the images, relative to the report (e.g. ``"docking/"``). With the
    ``results``, also the executed case against the start region, success by executed case, and the figures of
    the runs write_dock_files drew one by one.
    """
    with report.details("Settings of the docking runs"):
        report.settings(dock_settings(config))
    report.table(comparison_table(summary, cases=False))
    with report.details("Every case (by start region)"):
        report.table(comparison_table(summary))
    variant_list = variants(results, config)
    if results:
        report.paragraph(
            "The case executed is the manoeuvre the mission planned at Calculate, from its own estimate: the side "
            "of the axis and the heading (towards or away from it) of the robot then, and whether the manoeuvre "
            "drives backwards before Moving₂ (cases 5–8: the papers' planner reverses along its heading line to a "
            "Point A behind it; monodock's backs out straight before turning to A). The start region is the case "
            "whose region (relative to the stand-off Point A) the start was drawn in. They differ when the robot "
            "first turned to face the dock (Center: the heading, and so the case, changes), when the papers' "
            "heading line crosses the axis behind a start before the stand-off A, or when monodock needs no "
            "back-out from a start just past A (or a run-up from one just before it). Agreement: the runs that "
            "executed their start region's case."
        )
        report.table(agreement_table(results, variant_list, regions=False))
        with report.details("Executed case against start region, region by region"):
            report.table(agreement_table(results, variant_list), wrap=True)
        report.table(executed_case_table(results, variant_list))
    if config.faults:
        report.heading("Faults", level=level)
        report.paragraph(
            "Each fault strikes every start once, at its moment (judged from the truth and the mission's state); "
            "'fault sprung' counts the runs where that moment came (a run with no reverse leg meets no one behind "
            "it). Recovered: docked after a retry, a recovery from lost markers, a re-seat or a wait for the space "
            "behind to clear. Failed cleanly: the mission stopped with its reason. Hit: the footprint touched an "
            "obstacle (the simulator's truth)."
        )
        report.table(fault_table(summary, config), wrap=True)
    report.paragraph(
        "Errors are absolute values against the simulator's truth at the end of each run: lateral is base_link's "
        "distance from the approach axis, gap the front edge's distance from the face when it stopped short, or "
        "minus how far the wheels drove on against the face (the face is solid), heading the angle to the face's "
        "normal. Failed runs count with wherever they stopped."
    )
    report.image(f"{folder}final_errors.png", "Where every run ended; dashed: the tolerances.", width=620)
    report.heading("The dock filter against single frames", level=level)
    report.paragraph(
        "At every camera frame of Moving₃ and the settle at the face (after the filter is seeded at Calculate): "
        "the filtered DockPose (the extended Kalman filter's dock in the odometry frame, mapped to base_link with "
        "the odometry pose at the frame's exposure) and the frame's own estimate, each against the truth; mean "
        "absolute errors by the true depth from the camera, over the frames that had an estimate. Coasting "
        "frames had none (markers out of view): the filter alone. NEES: the filter's normalised estimation "
        "error squared against the truth, 3 on average for a consistent covariance."
    )
    with report.details("The filter table, by 25 cm band of the depth from the camera"):
        report.table(filter_table(summary), wrap=True)
    methods, _, _ = _variant_grid(variant_list)
    with report.details("Trajectories, by the case executed"):
        report.paragraph(
            "A panel per variant (method and planner). Blue: docked within the tolerances, red: not; dashed purple: "
            "legs driven in reverse; arrows every 0.4 m point the way the robot moved; crosses: each run's Point A; "
            "grey footprints: starts (orange: started in another case's region), red: where failed runs ended."
        )
        for case in trajectory_cases(results, config):
            title = "Runs that never planned" if case is None else f"Executed case {case}: {CASES[case].title}"
            report.image(f"{folder}{trajectory_file(case)}", title, width=min(1200, 400 * len(methods)))
    chosen = select_runs(results, variant_list)
    if chosen:
        planners = [p for _, p in variant_list]
        with report.details(f"Runs one by one ({len(chosen)}: each variant's first run of each region, and failures)"):
            report.paragraph(
                "Left: the top view, a dot where each state of the mission's log began; right: the lateral error, "
                "the gap to the face, the heading and the signed speed along the heading (negative, purple: "
                "reversing), the states shaded; dashed: the tolerances."
            )
            for r in chosen:
                outcome = "docked" if r.success else f"failed ({r.failure or r.state})"
                executed = "none" if r.classified_case is None else r.classified_case
                report.image(
                    f"{folder}{run_file(r)}",
                    f"{variant_label(variant_of(r), planners)}, start region {r.case}, trial {r.trial}: executed case "
                    f"{executed}, {outcome}.",
                    width=1200,
                )


def write_dock_report(
    out: Path, results: Sequence[TrialResult], summary: DockSimSummary, config: DockSimConfig
) -> None:
    """Everything of a dock-sim run into ``out`` (an existing, empty folder): files (write_dock_files), report
    and summary.json."""
    write_dock_files(out, results, config, jobs=config.jobs)
    report = HtmlReport(
        "monodock dock-sim: closed-loop docking, camera in the loop",
        lead="The papers' docking (eight cases, Point A, Moving₁-₃ with P-control) in the simulator: the robot sees "
        "only rendered camera frames and its wheel odometry; the truth is used only to measure where it ended. "
        "Every method docks from the same starts with the same wheel and camera draws.",
    )
    variant_list = variants(results, config)
    methods, _, _ = _variant_grid(variant_list)
    report.image(
        "trajectories.png",
        "Every run's true path; blue: docked within the tolerances, red: not; dashed purple: reversing; crosses: "
        "Point A.",
        width=max(220 * len(methods), 280),
    )
    dock_section(report, summary, config, results=results)
    for kind in config.planner_kinds:
        with report.details(f"The eight cases, {kind} planner"):
            for case in config.cases:
                report.image(f"{kind}_case_{case}.png", CASES[case].title, width=420)
    report.write(out, summary.to_json())


if __name__ == "__main__":  # python -m monodock.report.docking docs/dock_cases
    for p in write_case_diagrams(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/dock_cases")):
        print(p)
