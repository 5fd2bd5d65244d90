"""What one closed-loop docking run costs: `monodock dock-sim --cases 1 --trials 1 --method board --jobs 1`.

Runs the same docking (case 1, one start, board PnP, the default robot, camera and nuisances) in this process:
once cold (numba loads its cached kernels, the camera's rays are computed: what a fresh `dock-sim` process pays
once), then ``--repeats`` times warm. Per run: wall and CPU seconds, each split into rendering the camera frames,
estimation (detection and the method's estimate) and the rest (physics, controller, dock filter), as dock-sim
reports them; the medians of the warm runs stand beside the target of 4 s a run. Every warm run must end
exactly where the first did (same seed, same figures); the script fails if one does not. On a loaded machine
the wall time also counts waiting for a core: read the CPU columns then.

Run from the repo root:

    python bench/dock_sim_speed.py [--repeats 3] [--case 1] [--method board] [--seed 0] [--one-core] [--out FILE.md]
"""

from __future__ import annotations

import time

_T0_CPU, _T0_WALL = time.process_time(), time.perf_counter()  # the interpreter's start is before this

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
from typing import Any  # noqa: E402

from _common import emit, environment, fmt, markdown_table, pin_one_cpu  # noqa: E402
from monodock.evaluation.dock_results import TrialResult  # noqa: E402
from monodock.evaluation.dock_sim import ALL_METHODS, BUNDLE_METHODS, DockSimConfig, run_dock_sim  # noqa: E402

TARGET_S = 4.0  # one run, wall, on a quiet 2-core machine (issue 24)


def _row(label: str, r: TrialResult) -> list[str]:
    other_wall = r.wall_s - r.render_s - r.perceive_s
    other_cpu = r.cpu_s - r.render_cpu_s - r.perceive_cpu_s
    return [
        label,
        str(r.frames),
        fmt(r.wall_s),
        fmt(r.render_s),
        fmt(r.perceive_s),
        fmt(other_wall),
        fmt(r.cpu_s),
        fmt(r.render_cpu_s),
        fmt(r.perceive_cpu_s),
        fmt(other_cpu),
    ]


def _figures(r: TrialResult) -> tuple[Any, ...]:
    return (r.state, r.success, r.frames, r.time_s, r.lateral_cm, r.longitudinal_cm, r.heading_deg)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--repeats", type=int, default=3, help="warm runs after the cold one (3)")
    p.add_argument("--case", type=int, default=1, choices=range(1, 9), help="the docking case, 1-8 (1)")
    p.add_argument("--method", default="board", choices=[m for m in ALL_METHODS if m not in BUNDLE_METHODS])
    p.add_argument("--seed", type=int, default=0, help="seed of the start and of every draw (0)")
    p.add_argument(
        "--one-core", action="store_true", help="pin to one CPU, OpenCV on one thread (default: as dock-sim)"
    )
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    args = p.parse_args(argv)
    if args.repeats < 1:
        p.error(f"--repeats must be at least 1, got {args.repeats}")
    pinned = pin_one_cpu() if args.one_core else "no"
    imports_cpu, imports_wall = time.process_time(), time.perf_counter() - _T0_WALL

    config = DockSimConfig(cases=(args.case,), trials=1, methods=(args.method,), seed=args.seed, jobs=1)
    runs: list[TrialResult] = []
    for i in range(args.repeats + 1):
        print(f"run {i + 1}/{args.repeats + 1}{' (cold)' if i == 0 else ''} ...", file=sys.stderr)
        (r,) = run_dock_sim(config, progress=False)
        runs.append(r)
    cold, warm = runs[0], runs[1:]
    changed = [i + 1 for i, r in enumerate(warm) if _figures(r) != _figures(cold)]

    def median(key: str) -> float:
        return statistics.median(float(getattr(r, key)) for r in warm)

    wall, cpu = median("wall_s"), median("cpu_s")
    header = ["run", "frames", "wall s", "render", "estimate", "other", "CPU s", "render", "estimate", "other"]
    rows = [_row("cold (first in the process)", cold)] + [_row(f"warm {i + 1}", r) for i, r in enumerate(warm)]
    table = markdown_table(header, rows)
    verdict = "met" if wall <= TARGET_S else "not met"
    lines = [
        f"`python bench/dock_sim_speed.py --repeats {args.repeats} --case {args.case} --method {args.method} "
        f"--seed {args.seed}{' --one-core' if args.one_core else ''}` — pinned: {pinned}; one docking run "
        f"({cold.time_s:.1f} s simulated, {cold.state}, final lateral {cold.lateral_cm:+.3f} cm, gap "
        f"{cold.longitudinal_cm:+.3f} cm, heading {cold.heading_deg:+.3f} deg):",
        "",
        table,
        "",
        f"One-off costs of a fresh process: imports {imports_cpu:.2f} s CPU ({imports_wall:.2f} s wall, interpreter "
        f"start included); the cold run's extra over a warm one {cold.cpu_s - cpu:.2f} s CPU (numba's cached "
        "kernels, the camera's rays).",
        "",
        f"| one run, warm (median of {len(warm)}) | value |",
        "| --- | ---: |",
        f"| wall s (target ≤ {TARGET_S:g} on a quiet 2-core machine) | {wall:.2f} ({verdict}) |",
        f"| CPU s | {cpu:.2f} |",
        f"| CPU: rendering / estimation / other s | {median('render_cpu_s'):.2f} / {median('perceive_cpu_s'):.2f} / "
        f"{cpu - median('render_cpu_s') - median('perceive_cpu_s'):.2f} |",
        f"| CPU ms per frame | {1000 * cpu / max(1, cold.frames):.1f} |",
        "",
        "Same figures every run: " + ("yes" if not changed else f"NO (warm runs {changed} differ from the cold one)"),
        "",
        "environment: " + ", ".join(f"{k} {v}" for k, v in environment().items()),
    ]
    raw = {
        "args": vars(args),
        "target_s": TARGET_S,
        "imports_cpu_s": imports_cpu,
        "imports_wall_s": imports_wall,
        "runs": [
            {
                "cold": i == 0,
                "frames": r.frames,
                "wall_s": r.wall_s,
                "render_s": r.render_s,
                "perceive_s": r.perceive_s,
                "cpu_s": r.cpu_s,
                "render_cpu_s": r.render_cpu_s,
                "perceive_cpu_s": r.perceive_cpu_s,
                "figures": list(_figures(r)),
            }
            for i, r in enumerate(runs)
        ],
        "environment": environment(),
    }
    emit("\n".join(lines), raw, args.out)
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
