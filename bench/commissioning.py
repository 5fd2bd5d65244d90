"""Commissioning in wrong worlds: what the nominal files cost, and what survey + mount + teach get back.

Each world (``monodock.sim.wrong_world``): every marker ±3 mm in place (standing 0-3 mm off the face), ±2° tilt,
printed at 97-103 %; the camera mount ±1.5 cm / ±1.5°; the contacts ±1 cm from ``front_offset``; the wheels'
radii as the simulated base draws them. ``monodock.evaluation.commission.commission_world`` photographs it (24
handheld views), drives a minute before it, backs off its contacts, runs the three commissioning steps, and
measures against the truth: the survey (relative to the centre marker), the mount, the fused method (geometry
alone: no LiDAR, no bundle) and board PnP by 25 cm band with the nominal, the commissioned and the exact files,
and closed-loop dockings (every case, ``--trials`` starts each) with the nominal and the commissioned files.

    python bench/commissioning.py [--worlds 13] [--frames 60] [--trials 1] [--scale-from odometry] [--out DIR]

Prints the tables and writes ``summary.json`` and ``accuracy.png`` into ``--out`` (default
bench_out/commissioning). About 4 minutes a world on one core; the worlds run on ``--jobs`` processes.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from monodock.evaluation.commission import (
    ACCURACY_METHODS,
    FILE_SETS,
    CommissioningSummary,
    WorldResult,
    commission_world,
    summarize_worlds,
)


def _world(task: tuple[int, int, int, str]) -> WorldResult:
    seed, frames, trials, scale_from = task
    return commission_world(seed, frames=frames, docking_trials=trials, scale_from=scale_from)


def _tables(s: CommissioningSummary, seconds: float) -> str:
    lines = [f"# Commissioning in {s.worlds} wrong worlds ({seconds / 60:.1f} min)", ""]
    lines += ["## Estimates: mean absolute error against the truth", ""]
    lines += ["| files | method | depth mm | lateral mm | yaw deg | frames |", "|---|---|---:|---:|---:|---:|"]
    for k in FILE_SETS:
        for m in ACCURACY_METHODS:
            o = s.overall[k][m]
            lines.append(f"| {k} | {m} | {o['x_mm']:.2f} | {o['y_mm']:.2f} | {o['yaw_deg']:.3f} | {o['n']} |")
    lines += ["", "By 25 cm band of depth from the camera (fused; depth / lateral mm, yaw deg):", ""]
    lines += ["| band cm | " + " | ".join(FILE_SETS) + " |", "|---|" + "---:|" * len(FILE_SETS)]
    for b, label in enumerate(s.bands):
        cells = [
            f"{s.mae[k]['fused']['x_mm'][b]:.2f} / {s.mae[k]['fused']['y_mm'][b]:.2f} / "
            f"{s.mae[k]['fused']['yaw_deg'][b]:.3f}"
            for k in FILE_SETS
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    m = s.marker
    lines += [
        "",
        "## Survey (each marker relative to the centre marker)",
        "",
        f"- position: max {m['position_max_mm']:.2f} mm, mean {m['position_mean_mm']:.2f} mm; with the print's "
        f"overall scale divided out: max {m['position_scaled_max_mm']:.3f} mm",
        f"- orientation: max {m['angle_max_deg']:.3f} deg, mean {m['angle_mean_deg']:.3f} deg",
        f"- side: max {m['side_max_mm']:.3f} mm; the print's overall scale (which no image shows): up to "
        f"{m['print_scale_max_error'] * 100:.2f} %",
        "",
        "## Mount (max |error|; z as the camera's height over the centre marker's)",
        "",
        "- " + ", ".join(f"{k} {v:.2f}" for k, v in s.mount.items()),
        "- teach (the taught pose through the markers into the world's frame, against where the robot stood): "
        + ", ".join(f"{k} {v:.2f}" for k, v in s.teach.items()),
        "",
        "## Docking",
        "",
        "| files | runs | docked | charging | at the first seat | Wilson 95 % | lateral mm | gap mm | heading deg |",
        "|---|---:|---:|---:|---:|---|---:|---:|---:|",
    ]
    for k, d in s.docking.items():
        lo, hi = d["charging_first_seat_wilson95"]  # type: ignore[misc]
        lines.append(
            f"| {k} | {d['runs']} | {d['docked']} | {d['charging']} | {d['charging_first_seat']} | "
            f"{lo * 100:.1f}-{hi * 100:.1f} % | {d['lateral_mm_median']:.2f} | {d['gap_mm_median']:.2f} | "
            f"{d['heading_deg_median']:.2f} |"
        )
    return "\n".join(lines)


def _figure(s: CommissioningSummary, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = [0.375 + 0.25 * b for b in range(len(s.bands))]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    colours = {"nominal": "tab:red", "commissioned": "tab:green", "layout": "tab:orange", "exact": "tab:blue"}
    for ax, key, label in zip(
        axes, ("x_mm", "y_mm", "yaw_deg"), ("depth (mm)", "lateral (mm)", "yaw (deg)"), strict=True
    ):
        for k in FILE_SETS:
            name = "fused, the commissioned layout alone" if k == "layout" else f"fused, {k} files"
            ax.semilogy(centres, s.mae[k]["fused"][key], "o-", color=colours[k], label=name)
        ax.set_xlabel("depth from the camera (m)")
        ax.set_ylabel(f"MAE {label}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"fused (geometry alone) in {s.worlds} wrong worlds: nominal, commissioned, layout alone, exact files")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, default=13)
    p.add_argument("--first", type=int, default=1, help="the first world's seed")
    p.add_argument("--frames", type=int, default=60, help="accuracy frames per world")
    p.add_argument("--trials", type=int, default=1, help="docking starts per case per world (8 cases)")
    p.add_argument("--scale-from", choices=("print", "odometry"), default="odometry")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default="bench_out/commissioning")
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(args.first + k, args.frames, args.trials, args.scale_from) for k in range(args.worlds)]
    t0 = time.perf_counter()
    results: list[WorldResult] = []
    with mp.get_context("spawn").Pool(args.jobs) as pool:
        for r in pool.imap(_world, tasks):
            results.append(r)
            d = r.docking.get("commissioned/fused", [])
            print(
                f"world {r.seed}: survey max {max(abs(v) for p in r.marker_position_scaled_mm.values() for v in p):.3f}"
                f" mm (scale removed), mount x/y/z {[round(r.mount_error[k] * 1e3, 2) for k in 'xyz']} mm, yaw "
                f"{math.degrees(r.mount_error['yaw']):+.3f} deg, docked {sum(x.docked for x in d)}/{len(d)}",
                file=sys.stderr,
                flush=True,
            )
    summary = summarize_worlds(results)
    seconds = time.perf_counter() - t0
    text = _tables(summary, seconds)
    print(text)
    (out / "summary.md").write_text(text + "\n", encoding="utf-8")
    worlds = [
        {k: v for k, v in asdict(r).items() if k not in ("errors", "docking")}
        | {"docking": {k: [asdict(x) for x in v] for k, v in r.docking.items()}}
        for r in results
    ]
    (out / "summary.json").write_text(
        json.dumps({"summary": asdict(summary), "worlds": worlds, "seconds": seconds}, indent=1, default=float),
        encoding="utf-8",
    )
    np.savez(out / "errors.npz", **{f"{r.seed}_{k}_{m}": r.errors[k][m] for r in results for k in FILE_SETS
                                    for m in ACCURACY_METHODS})  # fmt: skip
    _figure(summary, out / "accuracy.png")
    print(f"-> {out}/summary.md, summary.json, accuracy.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
