"""The files of a ``dock-sim`` run: summary.json (the contract), runs.csv, trajectory plots and report.html."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from monodock.dock.planner import CASES
from monodock.evaluation.dock_sim import (
    DockSimConfig,
    TrialResult,
    comparison_table,
    filter_table,
    runs_csv,
    summarize,
)
from monodock.report.dock_plots import case_diagram, error_plot, trajectory_plot
from monodock.report.html import HtmlReport

__all__ = ["dock_section", "write_dock_files", "write_dock_report"]


def write_dock_files(out: Path, results: Sequence[TrialResult], config: DockSimConfig) -> dict[str, Any]:
    """runs.csv, one trajectory PNG per case, the case diagrams and the error scatter, into ``out``; the summary."""
    summary = summarize(results, config)
    (out / "runs.csv").write_text(runs_csv(results), encoding="utf-8")
    scene = {"planner": config.mission.planner, "layout": config.layout, "robot": config.robot, "drive": config.drive}
    for case in config.cases:
        runs = {m: [(r.path, r.success) for r in results if r.case == case and r.method == m] for m in config.methods}
        trajectory_plot(case, runs, out / f"trajectories_case_{case}.png", **scene)  # type: ignore[arg-type]
        case_diagram(case, out / f"case_{case}.png", **scene)  # type: ignore[arg-type]
    c = config.mission
    error_plot(
        [(r.method, r.lateral_cm, r.heading_deg, r.longitudinal_cm) for r in results],
        out / "final_errors.png",
        (c.tolerance_lateral * 100, c.tolerance_heading_deg),
    )
    return summary


def dock_section(report: HtmlReport, summary: dict[str, Any], config: DockSimConfig, folder: str = "") -> None:
    """The closed-loop docking section: settings, the side-by-side table, error scatter and trajectories.

    ``folder`` is where write_dock_files put the images, relative to the report (e.g. ``"docking/"``).
    """
    c = config.mission
    report.settings(
        {
            "starts": f"{config.trials} per case, seed {config.seed}; base_link {config.distance[0]:g}-"
            f"{config.distance[1]:g} m from the face, heading within ±{config.max_heading_deg:g}°, marker 2 in view",
            "Point A": f"{c.planner.standoff:g} m of floor between the front edge and the face",
            "robot": f"camera {config.drive.camera_rate:g} fps, {config.drive.camera_latency * 1000:.0f} ms latency; "
            f"commands {config.drive.command_latency * 1000:.0f} ms late; wheel scale error "
            f"{config.drive.wheel_scale_sd * 100:g} % per wheel per run, noise {config.drive.wheel_noise_sd * 100:g} % "
            "per step; contact sensor " + ("on" if config.drive.contact_sensor else "off"),
            "success": f"docked by the robot's own judgement and, by the truth, within {c.tolerance_lateral * 100:g} cm"
            " "
            f"lateral, {c.tolerance_longitudinal * 100:g} cm gap and {c.tolerance_heading_deg:g}°",
            "nuisances": str(config.nuisances.updated(supersample=config.supersample)),
        }
    )
    report.table(comparison_table(summary))
    report.paragraph(
        "Errors are absolute values against the simulator's truth at the end of each run: lateral is base_link's "
        "distance from the approach axis, gap the front edge's distance from the face when it stopped short, or "
        "minus how far the wheels drove on against the face (the face is solid), heading the angle to the face's "
        "normal. Failed runs count with wherever they stopped."
    )
    report.image(f"{folder}final_errors.png", "Where every run ended; dashed: the tolerances.", width=620)
    report.heading("The dock filter against single frames", level=3)
    report.paragraph(
        "At every camera frame of Moving₃ and the settle at the face (after the filter is seeded at Calculate): "
        "the filtered DockPose (the extended Kalman filter's dock in the odometry frame, mapped to base_link with "
        "the odometry pose at the frame's exposure) and the frame's own estimate, each against the truth; mean "
        "absolute errors by the true depth from the camera, over the frames that had an estimate. Coasting "
        "frames had none (markers out of view): the filter alone. NEES: the filter's normalised estimation "
        "error squared against the truth, 3 on average for a consistent covariance."
    )
    report.table(filter_table(summary))
    for case in config.cases:
        report.image(
            f"{folder}trajectories_case_{case}.png",
            f"{CASES[case].title}. Grey: starts; green: where docked runs ended; red: runs that failed.",
            width=480 * len(config.methods),
        )


def write_dock_report(out: Path, results: Sequence[TrialResult], config: DockSimConfig) -> dict[str, Any]:
    """Everything of a dock-sim run into ``out`` (an existing, empty folder); returns the summary."""
    summary = write_dock_files(out, results, config)
    report = HtmlReport("monodock dock-sim: closed-loop docking, camera in the loop")
    report.paragraph(
        "The papers' docking (eight cases, Point A, Moving₁-₃ with P-control) in the simulator: the robot sees "
        "only rendered camera frames and its wheel odometry; the truth is used only to measure where it ended. "
        "Every method docks from the same starts with the same wheel and camera draws."
    )
    dock_section(report, summary, config)
    report.heading("The eight cases")
    for case in config.cases:
        report.image(f"case_{case}.png", CASES[case].manoeuvre, width=420)
    report.write(out, summary)
    return summary


def console_table(summary: dict[str, Any]) -> str:
    """A few lines for the terminal: per method, success and median final errors."""
    lines = []
    for m, block in summary["methods"].items():
        g = block["overall"]

        def med(key: str, group: dict[str, Any] = g) -> str:
            v = group[key]["median"]
            return "-" if v is None or not math.isfinite(v) else f"{v:.2f}"

        lines.append(
            f"{m:10s} docked {g['successes']}/{g['runs']} ({(g['success_rate'] or 0) * 100:.0f} %)  median final "
            f"lateral {med('final_lateral_cm')} cm  gap {med('final_longitudinal_cm')} cm  heading "
            f"{med('final_heading_deg')} deg  time {med('time_s')} s"
        )
    for m, acc in summary.get("filter", {}).items():
        b = acc["all"]
        f, r = b["filtered"], b["single_frame"]
        if f is None or r is None:
            continue
        lines.append(
            f"{m:10s} filter vs single frame, MAE 25-250 cm over {b['frames']} frames: depth "
            f"{f['depth_cm']:.2f} vs {r['depth_cm']:.2f} cm, lateral {f['lateral_cm']:.2f} vs "
            f"{r['lateral_cm']:.2f} cm, yaw {f['yaw_deg']:.2f} vs {r['yaw_deg']:.2f} deg"
        )
    return "\n".join(lines)
