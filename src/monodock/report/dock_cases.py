"""The docking cases in pictures: the top view's charger and robot, and the diagrams of the eight cases (the docs').

Top views are drawn as a person standing behind the robot sees the floor: the charger at the top, the dock
frame's y (left) to the left. A dock-frame point (x, y) is drawn at (-y, x) (top_uv).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

from matplotlib.axes import Axes
from matplotlib.patches import FancyArrowPatch, Polygon, Rectangle

from monodock.core.layout import DockLayout
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.planner import CASES, PLANNERS, Manoeuvre, PlannerConfig, plan_for, point_a
from monodock.report.plotting import plt
from monodock.sim.diffdrive import DiffDriveConfig
from monodock.sim.world import ChargerGeometry

__all__ = [
    "case_diagram",
    "draw_dock",
    "draw_robot",
    "example_start",
    "top_uv",
    "write_case_diagrams",
]


_LABEL_BOX = {"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.85}


def top_uv(x: float, y: float) -> tuple[float, float]:
    """Where a top view draws the dock-frame point (x, y): at (-y, x)."""
    return -y, x


def draw_dock(ax: Axes, layout: DockLayout, a: Pose2D | None, reach: float = 2.6) -> None:
    """The charger, its markers, the approach axis and Point A."""
    ch = ChargerGeometry()
    ax.add_patch(Rectangle((-ch.width / 2, 0.0), ch.width, ch.depth, color="0.75", zorder=1))
    ax.plot([-ch.width / 2, ch.width / 2], [0, 0], color="0.2", lw=3, zorder=2)
    colours = {"left": "tab:red", "center": "tab:green", "right": "tab:blue"}
    for m in layout.markers:
        u, half = -m.y, 0.5 * (m.size or layout.marker_size)
        ax.plot(
            [u - half, u + half],
            [0.012, 0.012],
            color=colours.get(m.role, "tab:purple"),  # extra markers (a far-field one): purple
            lw=4,
            zorder=3,
        )
    ax.plot([0, 0], [-reach, 0], ls="--", color="0.5", lw=1, zorder=1)
    if a is not None:
        ax.plot(*top_uv(a.x, a.y), marker="*", ms=14, color="tab:orange", zorder=5)
        ax.annotate("A", top_uv(a.x, a.y), xytext=(8, -4), textcoords="offset points", fontsize=11, color="tab:orange")


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
    pts = [top_uv(*pose.point(cx, cy)) for cx, cy in corners]
    ax.add_patch(Polygon(pts, closed=True, fill=False, ec=color, lw=1.2, alpha=alpha, zorder=4))
    tip = top_uv(*pose.point(robot.front_offset * 0.9, 0.0))
    ax.add_patch(
        FancyArrowPatch(
            top_uv(pose.x, pose.y), tip, arrowstyle="-|>", mutation_scale=10, color=color, alpha=alpha, zorder=4
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
            FancyArrowPatch(top_uv(start.x, start.y), top_uv(backed.x, backed.y), color="tab:purple", ls="--", **style)
        )
    if abs(m.first_turn) > 1e-6:
        draw_robot(ax, turned, robot, drive, color="tab:blue", alpha=0.35)
    draw_robot(ax, at_a, robot, drive, color="tab:orange", alpha=0.5)
    draw_robot(ax, Pose2D(a.x, a.y, 0.0), robot, drive, color="tab:orange")
    draw_robot(ax, docked, robot, drive, color="tab:green")
    ax.add_patch(
        FancyArrowPatch(
            top_uv(backed.x, backed.y), top_uv(a.x, a.y), color="tab:purple", ls="--" if m.reverse else "-", **style
        )
    )
    ax.add_patch(FancyArrowPatch(top_uv(a.x, a.y), top_uv(docked.x, docked.y), color="tab:green", **style))
    words = f"back out {m.back_out:.2f} m,\n" if m.back_out > 0 else ""
    _phase_label(
        ax,
        f"Moving₁: {words}turn {math.degrees(m.first_turn):+.0f}°,\n"
        f"{'reverse' if m.reverse else 'drive'} {m.drive_distance:.2f} m",
        top_uv(start.x, start.y),
        (12 * side, -28),
        "tab:purple",
        ha="right" if side > 0 else "left",
    )
    _phase_label(
        ax,
        f"Moving₂: turn {math.degrees(m.second_turn):+.0f}°",
        top_uv(a.x, a.y),
        (-12 * side, -18),
        "tab:orange",
        ha="left" if side > 0 else "right",
    )
    _phase_label(ax, "Moving₃: P-control", top_uv(0.5 * (a.x - robot.front_offset), 0.0), (8, 0), "tab:green")
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


def _phase_label(
    ax: Axes, text: str, at: tuple[float, float], offset: tuple[float, float], color: str, ha: str = "left"
) -> None:
    """A phase's words ``offset`` points from where it acts, in its colour on a white box (``ha``: matplotlib's)."""
    ax.annotate(text, at, xytext=offset, textcoords="offset points", fontsize=9, ha=ha, color=color, bbox=_LABEL_BOX)


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
