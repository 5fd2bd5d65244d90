"""Docking in pictures and tables: the case diagrams (the docs'), and the files and report of a dock-sim run.

Top views are drawn as a person standing behind the robot sees the floor: the charger at the top, the dock
frame's y (left) to the left. A dock-frame point (x, y) is drawn at (-y, x).

``python -m monodock.report.docking DIR`` redraws the eight case diagrams into DIR.
"""

from __future__ import annotations

import math
import sys
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from matplotlib.axes import Axes
from matplotlib.patches import FancyArrowPatch, Polygon, Rectangle

from monodock.core.layout import DockLayout
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.planner import CASES, PlannerConfig, plan, point_a
from monodock.evaluation.dock_sim import (
    AbsStats,
    DockSimConfig,
    DockSimSummary,
    FilterBlock,
    RunGroup,
    TrialResult,
    runs_csv,
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
    """A typical start of the case, for its diagram."""
    spec = CASES[case]
    d_a = -point_a(planner, robot.front_offset).x
    d = d_a + 0.7 if spec.zone == "before" else d_a - 0.2
    side = 1.0 if spec.side == "left" else -1.0
    turn = -side if spec.heading == "towards" else side
    return Pose2D(-d, side * 0.45, turn * math.radians(20.0))


def case_diagram(
    case: int,
    path: Path,
    *,
    planner: PlannerConfig | None = None,
    layout: DockLayout | None = None,
    robot: RobotConfig | None = None,
    drive: DiffDriveConfig | None = None,
) -> None:
    """The case's region and its manoeuvre from a typical start: turn, drive (or reverse) to A, turn, approach."""
    planner = planner or PlannerConfig()
    layout = layout or DockLayout.default()
    robot = robot or RobotConfig.default()
    drive = drive or DiffDriveConfig()
    start = example_start(case, planner, robot)
    m = plan(start, planner, robot.front_offset)
    a = m.point_a
    fig, ax = plt.subplots(figsize=(5.2, 6.4))
    draw_dock(ax, layout, a)
    # The region: which side of the axis, and before or past A.
    side = 1.0 if CASES[case].side == "left" else -1.0
    y0, y1 = sorted((0.0, -side * 1.2))
    x0, x1 = (-3.0, a.x) if CASES[case].zone == "before" else (a.x, -robot.front_offset)
    ax.add_patch(Rectangle((y0, x0), y1 - y0, x1 - x0, color="tab:blue", alpha=0.06, zorder=0))
    turned = Pose2D(start.x, start.y, m.drive_heading)
    at_a = Pose2D(a.x, a.y, m.drive_heading)
    docked = Pose2D(-robot.front_offset, 0.0, 0.0)
    draw_robot(ax, start, robot, drive, color="tab:blue")
    draw_robot(ax, turned, robot, drive, color="tab:blue", alpha=0.35)
    draw_robot(ax, at_a, robot, drive, color="tab:orange", alpha=0.5)
    draw_robot(ax, Pose2D(a.x, a.y, 0.0), robot, drive, color="tab:orange")
    draw_robot(ax, docked, robot, drive, color="tab:green")
    style: dict[str, Any] = {"arrowstyle": "-|>", "mutation_scale": 14, "lw": 2}
    ax.add_patch(
        FancyArrowPatch(
            _uv(start.x, start.y), _uv(a.x, a.y), color="tab:purple", ls="--" if m.reverse else "-", **style
        )
    )
    ax.add_patch(FancyArrowPatch(_uv(a.x, a.y), _uv(docked.x, docked.y), color="tab:green", **style))
    ax.annotate(
        f"Moving₁: turn {math.degrees(m.first_turn):+.0f}°,\n"
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
    ax.set_title(CASES[case].title, fontsize=10)
    fig.text(0.5, 0.01, textwrap.fill(CASES[case].manoeuvre, 80), ha="center", va="bottom", fontsize=7.5)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trajectory_plot(
    case: int,
    runs: Mapping[str, Sequence[tuple[Sequence[tuple[float, float, float]], bool]]],
    path: Path,
    *,
    planner: PlannerConfig,
    layout: DockLayout,
    robot: RobotConfig,
    drive: DiffDriveConfig,
) -> None:
    """The true paths of one case's runs, one panel per method; red paths did not dock within the tolerances."""
    methods = list(runs)
    fig, axes = plt.subplots(1, len(methods), figsize=(4.6 * len(methods), 6.0), squeeze=False)
    a = point_a(planner, robot.front_offset)
    for ax, method in zip(axes[0], methods, strict=True):
        draw_dock(ax, layout, a)
        ok = 0
        for trail, success in runs[method]:
            ok += success
            us = [-p[1] for p in trail]
            vs = [p[0] for p in trail]
            ax.plot(us, vs, color="tab:blue" if success else "tab:red", lw=0.8, alpha=0.7, zorder=3)
            draw_robot(ax, Pose2D(*trail[0]), robot, drive, color="0.4", alpha=0.25)
            draw_robot(ax, Pose2D(*trail[-1]), robot, drive, color="tab:green" if success else "tab:red", alpha=0.5)
        ax.set_aspect("equal")
        ax.set_xlim(-1.3, 1.3)
        ax.set_ylim(-2.9, 0.4)
        ax.set_title(f"case {case}, {method}: {ok}/{len(runs[method])} docked", fontsize=10)
        ax.set_xlabel("← left of the axis (m)   |   right →")
    axes[0][0].set_ylabel("distance along the axis (m)")
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
    """case_1.png … case_8.png into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for case in CASES:
        p = folder / f"case_{case}.png"
        case_diagram(case, p, planner=planner)
        out.append(p)
    return out


def trajectory_overview(
    results: Sequence[TrialResult],
    config: DockSimConfig,
    path: Path,
    *,
    panel_px: int = 220,
) -> None:
    """Every run's true path in one small top view per method (all cases together), for a report's first screen.

    Blue paths docked within the tolerances, red ones did not; grey footprints are the starts.
    """
    methods = list(config.methods)
    dpi = 100
    width = max(panel_px * len(methods), 280) / dpi
    # Panels of equal aspect over 2.6 m x 3.3 m of floor, plus room for the titles and labels.
    height = 0.85 * panel_px / dpi * 3.3 / 2.6 + 0.6
    fig, axes = plt.subplots(1, len(methods), figsize=(width, height), squeeze=False, sharey=True)
    a = point_a(config.mission.planner, config.robot.front_offset)
    for ax, method in zip(axes[0], methods, strict=True):
        draw_dock(ax, config.layout, a)
        runs = [r for r in results if r.method == method]
        for r in runs:
            ax.plot(
                [-p[1] for p in r.path],
                [p[0] for p in r.path],
                color="tab:blue" if r.success else "tab:red",
                lw=0.9,
                alpha=0.75,
                zorder=3,
            )
            draw_robot(ax, Pose2D(*r.path[0]), config.robot, config.drive, color="0.45", alpha=0.3)
        ax.set_aspect("equal")
        ax.set_xlim(-1.3, 1.3)
        ax.set_ylim(-2.9, 0.4)
        ax.set_title(f"{method}: {sum(r.success for r in runs)}/{len(runs)} docked", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("lateral (m)", fontsize=7)
    axes[0][0].set_ylabel("along the axis (m)", fontsize=7)
    fig.tight_layout(pad=0.4)
    fig.savefig(path, dpi=dpi)
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
    """A few lines for the terminal: per method, success and median final errors."""
    lines = []

    def med(s: AbsStats) -> str:
        v = s.median
        return "-" if v is None or not math.isfinite(v) else f"{v:.2f}"

    for m, block in summary.methods.items():
        g = block.overall
        lines.append(
            f"{m:10s} docked {g.successes}/{g.runs} ({(g.success_rate or 0) * 100:.0f} %)  median final "
            f"lateral {med(g.final_lateral_cm)} cm  gap {med(g.final_longitudinal_cm)} cm  heading "
            f"{med(g.final_heading_deg)} deg  time {med(g.time_s)} s"
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


def write_dock_files(out: Path, results: Sequence[TrialResult], config: DockSimConfig) -> None:
    """runs.csv, one trajectory PNG per case and an overview, the case diagrams and the error scatter, into ``out``."""
    (out / "runs.csv").write_text(runs_csv(results), encoding="utf-8")
    scene = {"planner": config.mission.planner, "layout": config.layout, "robot": config.robot, "drive": config.drive}
    for case in config.cases:
        runs = {m: [(r.path, r.success) for r in results if r.case == case and r.method == m] for m in config.methods}
        trajectory_plot(case, runs, out / f"trajectories_case_{case}.png", **scene)  # type: ignore[arg-type]
        case_diagram(case, out / f"case_{case}.png", **scene)  # type: ignore[arg-type]
    trajectory_overview(results, config, out / "trajectories.png")
    c = config.mission
    final_error_plot(
        [(r.method, r.lateral_cm, r.heading_deg, r.longitudinal_cm) for r in results],
        out / "final_errors.png",
        (c.tolerance_lateral * 100, c.tolerance_heading_deg),
    )


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
        "Point A": {"planner": c.planner.kind, "standoff_m": c.planner.standoff},
        "robot": {
            "camera_rate_hz": d.camera_rate,
            "camera_latency_ms": round(d.camera_latency * 1000, 3),
            "command_latency_ms": round(d.command_latency * 1000, 3),
            "wheel_scale_error_pct": round(d.wheel_scale_sd * 100, 6),
            "wheel_noise_pct_per_step": round(d.wheel_noise_sd * 100, 6),
            "contact_sensor": d.contact_sensor,
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
) -> None:
    """The closed-loop docking section: the side-by-side table, error scatter, filter table and trajectories.

    ``folder`` is where write_dock_files put the images, relative to the report (e.g. ``"docking/"``).
    """
    with report.details("Settings of the docking runs"):
        report.settings(dock_settings(config))
    report.table(comparison_table(summary, cases=False))
    with report.details("Every case"):
        report.table(comparison_table(summary))
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
    with report.details("Trajectories, case by case"):
        for case in config.cases:
            report.image(
                f"{folder}trajectories_case_{case}.png",
                f"{CASES[case].title}. Grey: starts; green: where docked runs ended; red: runs that failed.",
                width=min(1200, 400 * len(config.methods)),
            )


def write_dock_report(
    out: Path, results: Sequence[TrialResult], summary: DockSimSummary, config: DockSimConfig
) -> None:
    """Everything of a dock-sim run into ``out`` (an existing, empty folder): files, report and summary.json."""
    write_dock_files(out, results, config)
    report = HtmlReport(
        "monodock dock-sim: closed-loop docking, camera in the loop",
        lead="The papers' docking (eight cases, Point A, Moving₁-₃ with P-control) in the simulator: the robot sees "
        "only rendered camera frames and its wheel odometry; the truth is used only to measure where it ended. "
        "Every method docks from the same starts with the same wheel and camera draws.",
    )
    report.image(
        "trajectories.png",
        "Every run's true path; blue: docked within the tolerances, red: not.",
        width=max(220 * len(config.methods), 280),
    )
    dock_section(report, summary, config)
    with report.details("The eight cases"):
        for case in config.cases:
            report.image(f"case_{case}.png", CASES[case].manoeuvre, width=420)
    report.write(out, summary.to_json())


if __name__ == "__main__":  # python -m monodock.report.docking docs/dock_cases
    for p in write_case_diagrams(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/dock_cases")):
        print(p)
