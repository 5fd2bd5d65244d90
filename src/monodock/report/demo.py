"""The demo's report: a first screen a person takes in at a glance, and the evidence below it.

The first screen (the top ~800 px of a 1280 px wide window) shows a camera frame of the held-out drive with the
detected markers and every method's estimate drawn, the headline table against the papers, and the closed-loop
docking trajectories. Below it come the settings (as YAML), the docking tables, the evaluation's figures and,
in collapsed sections, the long tables: errors by depth band, the papers' Tables 1-5 and the filter table.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import ROLES, DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.estimation.pnp import PoseEstimate
from monodock.evaluation.dock_results import DockSimSummary, TrialResult
from monodock.evaluation.dock_sim import DockSimConfig
from monodock.evaluation.heldout import PAPERS, HeldoutResult, HeldoutSummary
from monodock.learning.dataset import LabelError, LabelRun, label_error_table
from monodock.learning.train import TrainingResult
from monodock.perception.detect import Detection
from monodock.report.docking import dock_section
from monodock.report.evaluation import (
    band_sections,
    headline_note,
    headline_table,
    miscalibration_section,
    paper_sections,
    reasons_bullets,
)
from monodock.report.html import HtmlReport
from monodock.report.limit import limit_section
from monodock.report.plotting import METHOD_COLOURS, METHOD_LABELS, plt
from monodock.report.training import training_tables
from monodock.sim.lidar import LidarModel

__all__ = [
    "FRAME_FILE",
    "DemoPage",
    "DockingRun",
    "FrameView",
    "LidarOverlay",
    "estimates_figure",
    "lidar_settings",
    "papers_table",
    "write_demo_report",
]

FRAME_FILE = "first_frame.png"
# The first screen's columns at a 1280 px window: the camera frame, and the tables and trajectories beside it.
FRAME_WIDTH_PX = 560
TRAJECTORIES_WIDTH_PX = 640


@dataclass(frozen=True)
class FrameView:
    """One camera frame of the held-out drive, what the detector found in it and every method's estimate.

    Attributes:
        image: the frame as recorded (grey or BGR).
        detection: the markers the detector found.
        estimates: per method (regression, pnp, board, fused) its estimate of the frame.
        truth: the simulator's true DockPose at the frame.
        truth_corners: the markers' exact corner pixels.
    """

    image: NDArray[np.uint8]
    detection: Detection
    estimates: Mapping[str, PoseEstimate]
    truth: DockPose
    truth_corners: Mapping[str, NDArray[np.float64]]
    camera: CameraModel
    layout: DockLayout
    robot: RobotConfig


@dataclass(frozen=True)
class LidarOverlay:
    """A PNG of the papers' Fig. 8c/9 (LiDAR points on the image) with its file name and caption."""

    file: str
    caption: str
    png: bytes


@dataclass(frozen=True)
class DockingRun:
    """The demo's closed-loop docking: what ran, every run, and the summary; its files are in ``folder``."""

    config: DockSimConfig
    results: tuple[TrialResult, ...]
    summary: DockSimSummary
    folder: str = "docking/"


@dataclass(frozen=True)
class DemoPage:
    """Everything the demo's report shows.

    Attributes:
        heldout: every method on the held-out drive, and the studies.
        summary: the summary.json written beside the report.
        docking: the closed-loop docking runs (their files already written into the docking folder).
        frame: the first screen's camera frame, or None when the held-out drive had none to show.
        lidar_overlays: LiDAR points on the image at a few depths.
        training: the training's result (the papers' Tables 1-3), or None to leave them out.
        label_run, label_errors: the training drive's labelling counts, and its labels against the truth.
        settings: what the demo ran, as plain values (rendered as YAML).
        trials: hyperparameter draws per model.
        train_seconds: wall time of the drive, labels and training.
    """

    heldout: HeldoutResult
    summary: HeldoutSummary
    docking: DockingRun
    frame: FrameView | None
    lidar_overlays: tuple[LidarOverlay, ...]
    training: TrainingResult | None
    label_run: LabelRun
    label_errors: tuple[LabelError, ...]
    settings: Mapping[str, object]
    trials: int
    train_seconds: float


def lidar_settings(model: LidarModel) -> dict[str, object]:
    """The simulated LiDAR's knobs as a person reads them: angles in degrees, units in the names."""
    return {
        "angle_min_deg": round(math.degrees(model.angle_min), 6),
        "angle_max_deg": round(math.degrees(model.angle_max), 6),
        "angle_increment_deg": round(math.degrees(model.angle_increment), 6),
        "beams": model.beams,
        "range_m": [model.range_min, model.range_max],
        "range_noise_m": model.range_noise,
        "dropout": model.dropout,
        "scan_time_s": model.scan_time,
        "frame_id": model.frame_id,
    }


# --- the first screen -------------------------------------------------------------------------------------


def _project(view: FrameView, pose: DockPose, points_in_dock: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixels of dock-frame points seen from the camera if the dock were at ``pose``; NaN where it cannot see."""
    optical_T_dock = transforms.invert(view.robot.base_T_optical()) @ pose.matrix()
    p = transforms.apply(optical_T_dock, points_in_dock)
    px = np.asarray(view.camera.project(p), dtype=np.float64)
    # Outside the lens model's field the polynomial folds points back into the image: leave them out.
    px[~view.camera.in_view_field(p)] = np.nan
    return px


def _draw_dock(ax: Axes, view: FrameView, pose: DockPose, colour: str, *, ls: str = "-", lw: float = 1.4) -> None:
    """The three markers' outlines and the approach axis on the floor (1 m out from the face) at ``pose``."""
    for role in ROLES:
        c = _project(view, pose, view.layout.corners_in_dock(role))
        ax.plot(*np.vstack([c, c[:1]]).T, ls=ls, color=colour, lw=lw)
    # Sampled along its length, so that it is drawn up to where it leaves the camera's field.
    axis = _project(view, pose, np.column_stack([np.linspace(0.0, -1.0, 41), np.zeros(41), np.zeros(41)]))
    ax.plot(*axis.T, ls=ls, color=colour, lw=lw + 0.4)
    ax.plot(*axis[0], "o", color=colour, ms=4)


def _draw_frame(ax: Axes, view: FrameView, image: NDArray[np.uint8], *, labels: bool) -> None:
    """The image, the detected markers and every method's dock (and the truth's) on one axes."""
    ax.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    for role, obs in view.detection.observations.items():
        c = np.vstack([obs.corners, obs.corners[:1]])
        ax.plot(*c.T, color="yellow", lw=0.8)
        if labels:
            x, y = obs.corners.min(axis=0)
            ax.text(x, y - 4, view.layout.marker(role).label, color="yellow", fontsize=7)
    _draw_dock(ax, view, view.truth, "black", ls="--", lw=1.2)
    for method, est in view.estimates.items():
        if est.pose is not None:
            _draw_dock(ax, view, est.pose, METHOD_COLOURS.get(method, "grey"))


def _legend(view: FrameView) -> list[Line2D]:
    """One entry per method: its error against the truth (or why it has no estimate); the truth itself."""
    t = view.truth
    handles = [
        Line2D([], [], color="yellow", lw=1.0, label="detected markers"),
        Line2D(
            [],
            [],
            color="black",
            ls="--",
            label=f"truth: depth {t.x:.3f} m, lateral {t.y * 100:+.1f} cm, yaw {t.yaw_deg:+.2f}°",
        ),
    ]
    for method, est in view.estimates.items():
        colour = METHOD_COLOURS.get(method, "grey")
        label = METHOD_LABELS.get(method, method)
        if est.pose is None:
            handles.append(Line2D([], [], color=colour, lw=2, label=f"{label}: no estimate ({est.reason})"))
            continue
        p = est.pose
        yaw = math.degrees(math.remainder(p.yaw - t.yaw, math.tau))
        handles.append(
            Line2D(
                [],
                [],
                color=colour,
                lw=2,
                label=f"{label}: error depth {(p.x - t.x) * 100:+.2f} cm, lateral {(p.y - t.y) * 100:+.2f} cm, "
                f"yaw {yaw:+.2f}°",
            )
        )
    return handles


def _error_inset(ax: Axes, view: FrameView) -> None:
    """Where each method puts the dock against the truth, seen from above: depth and lateral error in cm."""
    t = view.truth
    errors = {
        m: ((e.pose.y - t.y) * 100, (e.pose.x - t.x) * 100) for m, e in view.estimates.items() if e.pose is not None
    }
    reach = max([1.0, *(1.25 * max(abs(a), abs(b)) for a, b in errors.values())])
    ax.axhline(0, color="0.6", lw=0.6)
    ax.axvline(0, color="0.6", lw=0.6)
    ax.plot(0, 0, "+", color="black", ms=8, mew=1.2)
    for m, (lateral, depth) in errors.items():
        # Drawn as seen from behind the robot: the charger ahead (up), the robot's left to the left.
        ax.plot(-lateral, depth, "o", color=METHOD_COLOURS.get(m, "grey"), ms=5, mec="black", mew=0.4)
    ax.set_xlim(-reach, reach)
    ax.set_ylim(-reach, reach)
    ticks = [-round(reach * 0.8, 1), 0.0, round(reach * 0.8, 1)]
    ax.set_xticks(ticks, [f"{v:g}" for v in ticks])
    ax.set_yticks(ticks, [f"{v:g}" for v in ticks])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6, pad=1, length=2)
    ax.set_title("error from the truth, cm", fontsize=7, pad=2)
    ax.set_xlabel("← left   lateral   right →", fontsize=6, labelpad=1)
    ax.set_ylabel("depth (+: too far)", fontsize=6, labelpad=1)


def estimates_figure(view: FrameView, path: Path, *, width_px: int = FRAME_WIDTH_PX) -> None:
    """The camera frame, the detected markers (ids), and every method's dock drawn where it estimates it.

    Each method's dock is its three markers' outlines and the approach axis on the floor, in the method's
    colour; the truth is dashed black. The estimates part by millimetres to centimetres, too little to see on
    the image: an inset shows each one's depth and lateral error from above, and the legend gives the numbers.
    """
    h, w = view.image.shape[:2]
    dpi = 100
    width, image_h = width_px / dpi, width_px / dpi * h / w
    # Below the image: the legend on the left, the error inset (1.3 in square) on the right.
    below = 1.75
    fig = plt.figure(figsize=(width, image_h + below), dpi=dpi)
    height = image_h + below
    ax = fig.add_axes((0.0, below / height, 1.0, image_h / height))
    image = view.image if view.image.ndim == 2 else view.image[:, :, ::-1]
    _draw_frame(ax, view, image, labels=True)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.axis("off")
    side = 1.2
    _error_inset(fig.add_axes(((width - side - 0.08) / width, 0.3 / height, side / width, side / height)), view)
    fig.legend(handles=_legend(view), loc="upper left", fontsize=7, frameon=False, bbox_to_anchor=(0.0, below / height))
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def papers_table(summary: HeldoutSummary) -> str:
    """Markdown: each method's mean absolute errors over all depths (against the truth when known and against
    the LiDAR labels), and the papers' own figures against their LiDAR."""
    truth, lidar = summary.against_truth, summary.against_lidar
    head = ["method", "valid"]
    if truth is not None:
        head += ["depth cm vs truth", "angle ° vs truth"]
    head += ["depth cm vs LiDAR", "angle ° vs LiDAR"]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    for method, row in lidar.items():
        main = truth.get(method, row) if truth is not None else row
        cells = [method, f"{main.valid}/{main.frames}"]
        if truth is not None:
            cells += [f"{main.depth_mae_cm:.2f}", f"{main.yaw_mae_deg:.2f}"]
        cells += [f"{row.depth_mae_cm:.2f}", f"{row.yaw_mae_deg:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    for p in PAPERS:
        cells = [f"{p.method} (papers)", str(p.samples)]
        if truth is not None:
            cells += ["—", "—"]
        cells += [f"{p.depth_mae_cm:.2f}", f"{p.yaw_mae_deg:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _first_screen(report: HtmlReport, page: DemoPage, out: Path) -> None:
    """The camera frame on the left; the headline against the papers and the docking trajectories on the right."""
    d = page.docking
    with report.block("first-screen"):
        with report.block("column"):
            if page.frame is not None:
                estimates_figure(page.frame, out / FRAME_FILE)
                depth = page.frame.truth.x - page.frame.robot.camera_mount.x
                report.image(
                    FRAME_FILE,
                    f"A held-out frame, {depth:.2f} m from the camera: every method's dock (its markers and the "
                    "approach axis on the floor) where it estimates it, dashed the truth; right: each one's error "
                    "seen from above.",
                    width=FRAME_WIDTH_PX,
                )
        with report.block("column"):
            report.heading("Against the papers: mean absolute error, all depths")
            report.table(papers_table(page.summary))
            report.note(
                "Ours on the held-out drive; the papers' against their own LiDAR labels (Tables 4-5), their "
                "SolvePnP given a wrong calibration. Every method here has the right one."
            )
            report.heading("Closed-loop docking from the eight cases")
            report.image(
                f"{d.folder}trajectories.png",
                f"{d.config.trials} start(s) per case, every method from the same starts; blue: docked within "
                "the tolerances, red: not.",
                width=TRAJECTORIES_WIDTH_PX,
            )


def write_demo_report(out: Path, page: DemoPage) -> None:
    """report.html, report.md, the figures and summary.json of the demo into ``out``."""
    report = HtmlReport(
        "monodock demo: the papers' regression against SolvePnP, on the simulator",
        lead="The whole pipeline on the simulator: a drive recorded as a rosbag2 bag, LiDAR labels, the papers' "
        "regressors in an ONNX bundle; then every method on a held-out drive against the LiDAR labels and the exact "
        "truth, and closed-loop docking with the camera in the loop.",
    )
    _first_screen(report, page, out)
    result = page.heldout

    report.heading("Settings")
    report.paragraph(
        "Files beside this page: train.parquet and test.parquet (the datasets), bundle/ (the models; "
        "bundle/report/training.md is the training report), docking/ (the docking runs)."
    )
    report.settings(page.settings)

    report.heading("Every method against both references")
    report.table(headline_table(result))
    report.paragraph(headline_note())
    band_sections(report, result)

    report.heading("Closed-loop docking, camera in the loop (monodock dock-sim)")
    report.paragraph(
        "The papers' eight docking cases from random starts 1-2.5 m away, the robot seeing only rendered "
        "frames and its odometry, with the bundle trained above, with board PnP, and with the fused method "
        "through the EKF. A longer run: monodock dock-sim --method regression,board,fused --out DIR."
    )
    dock_section(
        report, page.docking.summary, page.docking.config, folder=page.docking.folder, results=page.docking.results
    )

    if result.limit is not None:
        limit_section(report, result.limit, out)
    paper_sections(report, result, out)
    miscalibration_section(report, result, out)
    _training_sections(report, page)
    _overlay_section(report, page.lidar_overlays, out)
    report.heading("Why frames have no estimate")
    report.bullets(reasons_bullets(result.invalid_reasons))
    report.write(out, page.summary.to_json())


def _training_sections(report: HtmlReport, page: DemoPage) -> None:
    """The teacher's (LiDAR labels') error, and the papers' Tables 1-3 for the trained models (collapsed)."""
    if page.training is None:
        return
    report.heading("The teacher: LiDAR label error against the simulator's truth (training drive)")
    report.table(label_error_table(list(page.label_errors)), wrap=True)
    run = page.label_run
    report.paragraph(
        f"Training drive: {run.images} images, {run.paired} paired with a scan, {run.labelled} labelled. "
        "The regression learns these labels; their noise averages out over many frames, their bias does not."
    )
    report.heading("Training (Tables 1-3 of the paper; full report in bundle/report/training.md)")
    report.paragraph(
        f"{page.trials} hyperparameter draws per model; drive, labels and training took {page.train_seconds:.0f} s."
    )
    for title, md in training_tables(page.training).items():
        with report.details(title):
            report.table(md, wrap=True)


def _overlay_section(report: HtmlReport, overlays: Sequence[LidarOverlay], out: Path) -> None:
    """The LiDAR points on the image at a few depths (papers' Fig. 8c, 9)."""
    if not overlays:
        return
    report.heading("Overlays: LiDAR points on the image (papers' Fig. 8c, 9)")
    report.paragraph(
        "Blue: every LiDAR return projected through the calibrated mounts; magenta: the points across "
        "marker 2 that make the label. Green: detected corners; red crosses: true corners; arrows: dock axes."
    )
    for o in sorted(overlays, key=lambda o: o.file):
        (out / o.file).write_bytes(o.png)
        report.image(o.file, o.caption, width=600)
