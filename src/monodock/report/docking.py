"""Docking in pictures and tables: the files and report of a dock-sim run.

The pictures and tables themselves are drawn by report.dock_cases (the case diagrams, the docs'),
report.dock_figures (a run's trajectories, final errors and runs one by one) and report.dock_tables; their public
names are importable from here too.

``python -m monodock.report.docking DIR`` redraws the eight case diagrams into DIR.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from monodock.compute import map_with_state
from monodock.dock.planner import CASES
from monodock.evaluation.dock_results import DockSimSummary, TrialResult, runs_csv
from monodock.evaluation.dock_sim import ROOM_BEARING_DEG, ROOM_DISTANCE, DockSimConfig
from monodock.report.dock_cases import case_diagram, write_case_diagrams
from monodock.report.dock_figures import (
    FAR_START,
    final_error_plot,
    room_far_trajectories,
    room_success_map,
    room_time_plot,
    run_plot,
    trajectory_overview,
    trajectory_plot,
    variant_grid,
)
from monodock.report.dock_runs import (
    agreement_table,
    executed_case_table,
    run_file,
    select_runs,
    variant_label,
    variant_of,
    variants,
)
from monodock.report.dock_tables import comparison_table, fault_table, filter_table, room_table
from monodock.report.html import HtmlReport, plain

__all__ = [
    "dock_section",
    "dock_settings",
    "room_section",
    "trajectory_cases",
    "trajectory_file",
    "write_dock_files",
    "write_dock_report",
]


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
    tolerances = (c.retry.tolerance_lateral * 100, c.retry.tolerance_longitudinal * 100, c.retry.tolerance_heading_deg)
    errors = [(r.method, r.lateral_cm, r.heading_deg, r.longitudinal_cm) for r in results]
    figures.append((final_error_plot, (errors, out / "final_errors.png", (tolerances[0], tolerances[2])), {}))
    if config.starts == "room":
        figures.append((room_success_map, (results, config, out / "room_map.png"), {}))
        figures.append((room_time_plot, (results, out / "room_time.png"), {}))
        figures.append((room_far_trajectories, (results, config, out / "room_far.png"), {}))
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
    starts: dict[str, object]
    if config.starts == "room":
        starts = {
            "room": config.trials,
            "seed": config.seed,
            "distance_from_face_centre_m": list(ROOM_DISTANCE),
            "bearing_from_axis_deg": ROOM_BEARING_DEG,
            "heading": "any",
        }
    else:
        starts = {
            "per case": config.trials,
            "seed": config.seed,
            "distance_from_face_m": list(config.distance),
            "max_heading_deg": config.max_heading_deg,
            "marker 2 in view": True,
        }
    return {
        "starts": starts,
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
            "lateral_cm": c.retry.tolerance_lateral * 100,
            "gap_cm": c.retry.tolerance_longitudinal * 100,
            "heading_deg": c.retry.tolerance_heading_deg,
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
    methods, _, _ = variant_grid(variant_list)
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


def room_section(report: HtmlReport, results: Sequence[TrialResult]) -> None:
    """The room envelope (``--starts room``): success with its Wilson interval by start distance, the success map,
    the time to dock by distance and the far starts' paths."""
    report.heading("The room envelope", level=2)
    report.paragraph(
        "Starts 0.5-5 m from the face centre (base_link), within 60 degrees of the dock's axis, any heading (the dock "
        "often behind the robot); those from which the robot could not turn on the spot clear of the face are "
        "redrawn. Docked and charging by the simulator's truth (within the tolerances, the charger reporting "
        "charging); the Wilson 95 % interval of that rate."
    )
    report.table(room_table(results), wrap=True)
    posed = sum(r.posed_frames for r in results)
    predicted = sum(r.predicted_frames for r in results)
    if posed:
        report.paragraph(
            f"Frames with a pose: {posed}; of them {predicted} ({100 * predicted / posed:.1f} %) used a marker the "
            "detector missed and the predicted-corner fit found where the dock track put it (predicted_markers)."
        )
    report.image("room_map.png", "Every start by its outcome; dashed: the envelope.", width=1100)
    report.image("room_time.png", "Time to dock by start distance.", width=620)
    report.image("room_far.png", f"The true paths from the starts at least {FAR_START:g} m out.", width=1100)


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
    methods, _, _ = variant_grid(variant_list)
    report.image(
        "trajectories.png",
        "Every run's true path; blue: docked within the tolerances, red: not; dashed purple: reversing; crosses: "
        "Point A.",
        width=max(220 * len(methods), 280),
    )
    if config.starts == "room":
        room_section(report, results)
    dock_section(report, summary, config, results=results)
    for kind in config.planner_kinds:
        with report.details(f"The eight cases, {kind} planner"):
            for case in config.cases:
                report.image(f"{kind}_case_{case}.png", CASES[case].title, width=420)
    report.write(out, summary.to_json())


if __name__ == "__main__":  # python -m monodock.report.docking docs/dock_cases
    for p in write_case_diagrams(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/dock_cases")):
        print(p)
