"""Top views of docking: one diagram per case (the README's), and the trajectories of closed-loop runs.

Drawn as a person standing behind the robot sees the floor: the charger at the top, the dock frame's y (left)
to the left. A dock-frame point (x, y) is drawn at (-y, x).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.axes import Axes
from matplotlib.patches import FancyArrowPatch, Polygon, Rectangle

from monodock.core.layout import DockLayout
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.planner import CASES, PlannerConfig, plan, point_a
from monodock.sim.diffdrive import DiffDriveConfig
from monodock.sim.world import ChargerGeometry

__all__ = ["case_diagram", "draw_dock", "draw_robot", "example_start", "trajectory_plot"]


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


def error_plot(results: Sequence[tuple[str, float, float, float]], path: Path, tolerances: tuple[float, float]) -> None:
    """Final lateral error against final heading error, every run, a colour per method; the tolerance box."""
    fig, ax = plt.subplots(figsize=(6.0, 4.6))
    methods = sorted({r[0] for r in results})
    for i, m in enumerate(methods):
        pts = [(r[1], r[2]) for r in results if r[0] == m]
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=12, alpha=0.7, label=m, color=f"C{i}")
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


if __name__ == "__main__":  # python -m monodock.report.dock_plots docs/dock_cases
    import sys

    for p in write_case_diagrams(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/dock_cases")):
        print(p)
