"""The commissioning report: every calibrated value with its uncertainty, the survey's views with the fitted markers
drawn on them, the residuals, the drive's path, the teaching back-off, and the verdict."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from monodock.calibrate.commission import Commissioning, summary_values
from monodock.core import transforms
from monodock.core.config import json_text
from monodock.core.layout import ROLES
from monodock.report.html import HtmlReport
from monodock.report.plotting import saved_figure

__all__ = ["write_commission_report"]

_GREEN, _RED = (60, 200, 60), (40, 40, 230)


def _views_png(c: Commissioning, path: Path, count: int = 8) -> bool:
    """Up to ``count`` survey views, each with the surveyed markers projected through its fitted camera (green)
    and the refined corners it measured (red)."""
    survey = c.survey
    if survey is None:
        return False
    shown = [v for v in c.views if v.image is not None and v.name in survey.camera_poses]
    if not shown:
        return False
    step = max(1, len(shown) // count)
    shown = shown[::step][:count]
    tiles = []
    for v in shown:
        assert v.image is not None
        img = cv2.cvtColor(v.image, cv2.COLOR_GRAY2BGR) if v.image.ndim == 2 else v.image.copy()
        optical_T_dock = transforms.invert(survey.camera_poses[v.name])
        for role in ROLES:
            pts = transforms.apply(optical_T_dock, survey.layout.corners_in_dock(role))
            if np.all(pts[:, 2] > 0):
                px = c.camera.project(pts) if v.image.shape[1] == c.camera.width else None
                if px is not None:
                    cv2.polylines(img, [np.round(px * 4).astype(np.int32)], True, _GREEN, 1, cv2.LINE_AA, shift=2)
        for quad in v.corners.values():
            for u, w in quad:
                cv2.circle(img, (round(u * 4), round(w * 4)), 8, _RED, 1, cv2.LINE_AA, shift=2)
        note = next((n for n in survey.views if n.name == v.name), None)
        label = f"{v.name}  {note.rms_px:.3f} px" if note is not None else v.name
        cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(cv2.resize(img, (320, round(320 * img.shape[0] / img.shape[1]))))
    while len(tiles) % 4:
        tiles.append(np.full_like(tiles[0], 255))
    rows = [np.hstack(tiles[k : k + 4]) for k in range(0, len(tiles), 4)]
    cv2.imwrite(str(path), np.vstack(rows))
    return True


def _layout_png(c: Commissioning, path: Path) -> None:
    """The charger's face from the front: the nominal markers (grey) and the surveyed ones (green), their centres'
    moves drawn 20x; and from above: each marker's standing off the face and its yaw, 20x."""
    nominal, final = c.nominal_layout, c.layout
    with saved_figure(path, 1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [3, 2]}) as (_, (front, top)):
        for layout, colour, style in ((nominal, "0.6", "--"), (final, "tab:green", "-")):
            for role in ROLES:
                corners = layout.corners_in_dock(role)
                ys, zs = -corners[:, 1], corners[:, 2]  # the robot's view: its left on the left
                front.plot([*ys, ys[0]], [*zs, zs[0]], style, color=colour, lw=1.2)
        for role in ROLES:
            a, b = nominal.marker(role), final.marker(role)
            front.annotate(
                "",
                xy=(-(a.y + 20 * (b.y - a.y)), a.z + 20 * (b.z - a.z)),
                xytext=(-a.y, a.z),
                arrowprops={"arrowstyle": "->", "color": "tab:red"},
            )
            front.text(-a.y, a.z - 0.75 * nominal.side(role), f"{role}\nid {a.id}", ha="center", va="top", fontsize=8)
            # From above, 20x: the marker's face as a segment, standing off by x and turned by its yaw.
            half, turn = 0.5 * final.side(role), 20.0 * b.yaw
            ends_y = [-b.y - half * math.cos(turn), -b.y + half * math.cos(turn)]
            ends_x = [20.0 * b.x + half * math.sin(turn), 20.0 * b.x - half * math.sin(turn)]
            top.plot(ends_y, ends_x, color="tab:green", lw=2)
            top.plot([-a.y - 0.5 * nominal.side(role), -a.y + 0.5 * nominal.side(role)], [0.0, 0.0], "--",
                     color="0.6")  # fmt: skip
        front.set_aspect("equal")
        front.set_xlabel("across the face, robot's left to right (m)")
        front.set_ylabel("height (m)")
        front.set_title("nominal (grey) and surveyed (green); red: centre moves x20")
        top.set_xlabel("across the face, robot's left to right (m)")
        top.set_ylabel("into the charger (m, x20)")
        top.set_title("from above: stand-off and yaw, x20")


def _survey_residuals_png(c: Commissioning, path: Path) -> None:
    assert c.survey is not None
    used = c.survey.used
    with saved_figure(path, figsize=(9, 2.8)) as (_, ax):
        ax.bar(range(len(used)), [v.rms_px for v in used], color="tab:blue")
        ax.set_xlabel("view")
        ax.set_ylabel("RMS reprojection (px)")
        ax.set_title(f"survey: {len(used)} views, RMS {c.survey.rms_px:.3f} px over every corner")


def _drive_png(c: Commissioning, path: Path) -> None:
    """The drive seen from above: base_link's fitted path in the dock's floor frame, coloured by the frame's
    reprojection error, and the dock's face."""
    assert c.mount is not None
    p, res = c.mount.path, c.mount.residuals_px
    with saved_figure(path, 1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1, 1]}) as (fig, (top, series)):
        sc = top.scatter(-p[:, 1], p[:, 0], c=res, s=9, cmap="viridis")
        step = max(1, len(p) // 25)
        top.quiver(-p[::step, 1], p[::step, 0], -np.sin(p[::step, 2]), np.cos(p[::step, 2]), width=0.004, scale=25)
        half = max(abs(m.y) for m in c.layout.markers) + c.layout.marker_size
        top.plot([-half, half], [0, 0], color="k", lw=3)
        top.text(0, 0.02, "dock face", ha="center", fontsize=8)
        top.set_aspect("equal")
        top.set_xlabel("across the dock (m, robot's left negative)")
        top.set_ylabel("x in the dock frame (m)")
        top.set_title("the drive: base_link's fitted path")
        fig.colorbar(sc, ax=top, label="frame RMS (px)", fraction=0.04)
        series.plot(res, ".", ms=3)
        series.set_xlabel("frame")
        series.set_ylabel("RMS reprojection (px)")
        series.set_title(f"mount fit: {c.mount.frames} frames, RMS {c.mount.rms_px:.3f} px")


def _teach_png(c: Commissioning, path: Path) -> None:
    assert c.teach is not None
    r = c.teach.residuals
    with saved_figure(path, 1, 3, figsize=(11, 3.0)) as (fig, axes):
        for ax, k, label, scale in (
            (axes[0], 1, "x (mm)", 1e3),
            (axes[1], 2, "y (mm)", 1e3),
            (axes[2], 3, "yaw (deg)", 180 / math.pi),
        ):
            ax.plot(r[:, 0], r[:, k] * scale, ".", ms=3)
            ax.axhline(0.0, color="0.5", lw=1)
            ax.set_xlabel("backed off (m)")
            ax.set_ylabel(label)
        fig.suptitle("teaching: each frame's estimate of the dock from the charging pose, minus the taught one")


def _values_table(c: Commissioning) -> str:
    rows = ["| value | nominal | commissioned | sd |", "|---|---:|---:|---:|"]
    if c.survey is not None:
        for role, m in c.survey.markers.items():
            n = c.nominal_layout.marker(role)
            f = c.layout.marker(role)
            for key, unit in (("x", "mm"), ("y", "mm"), ("z", "mm"), ("roll", "deg"), ("pitch", "deg"), ("yaw", "deg")):
                k = 1e3 if unit == "mm" else 180 / math.pi
                rows.append(
                    f"| {role} {key} ({unit}) | {getattr(n, key) * k:.2f} | {getattr(f, key) * k:.2f} | "
                    f"{m.sd[key] * k:.2f} |"
                )
            rows.append(
                f"| {role} side (mm) | {c.nominal_layout.side(role) * 1e3:.2f} | {c.layout.side(role) * 1e3:.2f} | "
                f"{m.sd['size'] * 1e3:.2f} |"
            )
    if c.mount is not None:
        nm, fm, sd = c.nominal_robot.camera_mount, c.robot.camera_mount, c.mount.sd
        for key in ("x", "y", "z", "roll", "pitch", "yaw"):
            k, unit = (1e3, "mm") if key in ("x", "y", "z") else (180 / math.pi, "deg")
            rows.append(
                f"| camera mount {key} ({unit}) | {getattr(nm, key) * k:.2f} | {getattr(fm, key) * k:.2f} | "
                f"{sd[key] * k:.3f} |"
            )
        odo = c.robot.odometry
        drift, drift_sd = math.degrees(odo.drift_per_m), math.degrees(sd["drift_per_m"])
        rows.append(f"| odometry distance scale | 1 | {odo.distance_scale:.5f} | {sd['log_odometry_scale']:.5f} |")
        rows.append(f"| odometry rotation scale | 0 | {odo.rotation_scale:+.5f} | {sd['rotation_scale']:.5f} |")
        rows.append(f"| odometry drift (deg/m) | 0 | {drift:+.3f} | {drift_sd:.3f} |")
        rows.append(
            f"| dock lean roll, pitch (deg) | 0, 0 | {math.degrees(c.mount.dock_roll):+.3f}, "
            f"{math.degrees(c.mount.dock_pitch):+.3f} | {math.degrees(sd['dock_roll']):.3f}, "
            f"{math.degrees(sd['dock_pitch']):.3f} |"
        )
    if c.teach is not None:
        o, sd3 = c.teach.offset, c.teach.sd
        rows.append(f"| charging offset x (mm) | 0 | {o.x * 1e3:+.2f} | {sd3[0] * 1e3:.2f} |")
        rows.append(f"| charging offset y (mm) | 0 | {o.y * 1e3:+.2f} | {sd3[1] * 1e3:.2f} |")
        rows.append(f"| charging offset yaw (deg) | 0 | {o.yaw_deg:+.3f} | {math.degrees(sd3[2]):.3f} |")
    return "\n".join(rows)


def write_commission_report(c: Commissioning, out: Path, files: dict[str, str]) -> None:
    """report.html, report.md, summary.json and the PNGs into ``out`` (a folder being written)."""
    report = HtmlReport(
        "monodock commissioning",
        lead="A new robot and dock: the dock surveyed from photographs, the camera mount and odometry from a "
        "drive, the charging pose taught from a back-off off the contacts.",
    )
    report.heading("Verdict")
    report.bullets(c.verdict())
    report.table(_values_table(c))
    report.note("sd: one standard deviation from each fit's covariance. Lengths in mm, angles in degrees.")
    notes = [*(c.survey.notes if c.survey else ()), *(c.mount.notes if c.mount else ()), *(c.teach.notes if c.teach
             else ())]  # fmt: skip
    if notes:
        report.bullets(notes)
    if c.survey is not None:
        report.heading("Survey")
        if _views_png(c, out / "survey_views.png"):
            report.image("survey_views.png", "survey views: the surveyed markers through each view's fitted camera "
                         "(green) and the refined corners measured (red)")  # fmt: skip
        _layout_png(c, out / "survey_layout.png")
        report.image("survey_layout.png", "the layout: nominal and surveyed")
        _survey_residuals_png(c, out / "survey_residuals.png")
        report.image("survey_residuals.png", "each view's RMS reprojection error")
        skipped = [f"{v.name}: {v.reason}" for v in c.survey.views if not v.used]
        if skipped:
            with report.details(f"{len(skipped)} views not used"):
                report.bullets(skipped)
    if c.mount is not None:
        report.heading("Camera mount")
        _drive_png(c, out / "drive.png")
        report.image("drive.png", "the commissioning drive and each frame's reprojection error")
        report.paragraph(c.mount.summary())
    if c.teach is not None:
        report.heading("Charging pose")
        _teach_png(c, out / "teach.png")
        report.image("teach.png", "the back-off: each frame's view of the charging pose against the taught one")
        report.paragraph(c.teach.summary())
    if c.failures:
        report.heading("What failed")
        report.bullets([f"{f.step}: {f.reason}" for f in c.failures])
    report.heading("Files")
    report.bullets([f"{name}: {what}" for name, what in files.items()])
    report.write(out, json_text(summary_values(c)))
