"""Nav2's default goals over a real ROS 2 graph: monodock-dock-ros as Nav2's docking server, one start per case.

From each start (dock-sim's draw of one start in each of the papers' eight cases), the simulated robot on the graph
(``monodock-sim-ros``) gets what Nav2's DockRobot behaviour tree node sends by default (``dock_id: home_dock``,
``navigate_to_staging_pose: true``; no Nav2 navigation here, so monodock approaches from where the robot stands),
then the same goal again while docked, then UndockRobot's default goal: an action client written from the upstream
nav2_msgs definitions (tests/ros/graph_dock_action.py), every packet over Fast DDS in a private network namespace.
Judged by the simulator's truth: the final lateral offset, gap and heading, the charger charging, how far the robot
moved on the second goal, and where the undock left it.

    python bench/nav2_docking.py [--cases all] [--jobs 2] [--seed 0] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from _common import emit, environment, fmt, markdown_table
from monodock.cli.dock_sim import _cases as case_list
from monodock.evaluation.dock_sim import DockSimConfig, sample_start

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from private_graph import can_isolate, run_private_graph

DRIVER = Path(__file__).resolve().parents[1] / "tests" / "ros" / "graph_dock_action.py"
BT_DEFAULT = {"action": "dock", "goal": {"dock_id": "home_dock", "navigate_to_staging_pose": True}}


def run_start(start: tuple[float, float, float]) -> dict[str, Any]:
    """The three goals from one start: the driver's goal records (or why there are none)."""
    t0 = time.perf_counter()
    goals = [BT_DEFAULT, BT_DEFAULT, {"action": "undock", "goal": {}}]
    run = run_private_graph(DRIVER, json.dumps({"start": list(start), "goals": goals}), timeout=400)
    records = [r for r in run.records if r["kind"] == "goal"]
    if len(records) != len(goals):
        return {"error": f"exit {run.returncode}: {run.stderr.strip().splitlines()[-1:]}", "wall": 0.0}
    return {"dock": records[0], "again": records[1], "undock": records[2], "wall": time.perf_counter() - t0}


def worst(values: list[float]) -> str:
    return fmt(float(np.max(np.abs(values)))) if values else "—"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--cases", type=case_list, default=case_list("all"), help="papers' cases, e.g. 1,4,7 (all)")
    p.add_argument("--jobs", type=int, default=2, help="graphs at a time (2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    args = p.parse_args(argv)
    if not can_isolate():
        p.error("this machine cannot make a private network namespace (unshare --net); no ROS graph may run")
    config = DockSimConfig(cases=tuple(args.cases), trials=1, methods=("board",), seed=args.seed)
    sim = config.simulator(config.seed)
    # dock-sim's starts (its draw for trial 0 of each case, as bench/ros_docking.py and dock-sim use them).
    starts = [
        (
            case,
            tuple(
                sample_start(case, sim, config.mission.planner, np.random.default_rng([config.seed, case, 5]), config)
            ),
        )
        for case in config.cases
    ]
    t0 = time.perf_counter()
    with ThreadPoolExecutor(args.jobs) as pool:
        runs = list(pool.map(lambda item: run_start(item[1]), starts))
    wall = time.perf_counter() - t0

    rows, docked = [], []
    for (case, start), r in zip(starts, runs, strict=True):
        where = f"({start[0]:.2f}, {start[1]:.2f}, {math.degrees(start[2]):.0f}°)"
        if "error" in r:
            rows.append([str(case), where, r["error"], "—", "—", "—", "—"])
            continue
        d, a, u = r["dock"], r["again"], r["undock"]
        ok = d["succeeded"] and d["charging"]
        if ok:
            docked.append(r)
        t = d["truth"]
        rows.append(
            [
                str(case),
                where,
                ("docked, charging" if ok else f"status {d['status']}, code {d['error_code']}")
                + f" ({d['docking_time']:.1f} s)",
                f"{fmt(t['lateral_cm'])} / {fmt(t['gap_cm'])} / {fmt(t['heading_deg'])}",
                ("succeeded" if a["succeeded"] else f"status {a['status']}")
                + f", moved {fmt(a['moved_cm'])} cm, {fmt(a['turned_deg'])}°",
                ("undocked" if u["succeeded"] and not u["charging"] else f"status {u['status']}")
                + f", gap {fmt(u['truth']['gap_cm'])} cm",
                f"{r['wall']:.0f}",
            ]
        )
    summary = [
        [
            f"{len(docked)}/{len(runs)}",
            worst([r["dock"]["truth"]["lateral_cm"] for r in docked]),
            worst([r["dock"]["truth"]["gap_cm"] for r in docked]),
            worst([r["dock"]["truth"]["heading_deg"] for r in docked]),
            f"{sum(r['again']['succeeded'] for r in docked)}/{len(docked)}",
            f"{worst([r['again']['moved_cm'] for r in docked])} cm, "
            f"{worst([r['again']['turned_deg'] for r in docked])}°",
            f"{sum(r['undock']['succeeded'] and not r['undock']['charging'] for r in docked)}/{len(docked)}",
            f"{wall:.0f}",
        ]
    ]  # fmt: skip
    header = ["docked and charging", "worst lateral cm", "worst gap cm", "worst heading °", "second goal at once",
              "second goal: worst motion", "undocked", "wall s"]  # fmt: skip
    runs_header = ["case", "start (x, y, heading)", "DockRobot (Nav2's default goal)", "lateral / gap / heading cm, °",
                   "the same goal while docked", "UndockRobot", "wall s"]  # fmt: skip
    report = "\n\n".join(
        [
            f"# Nav2's default goals over ROS 2 ({len(runs)} starts, board PnP, monodock-dock-ros as docking_server)",
            markdown_table(header, summary),
            "By the simulator's truth. The papers' tolerance: 2 cm lateral and gap, 3.07° heading; the second goal "
            "must succeed at once with the robot still (≤ 1 cm, ≤ 2°).",
            markdown_table(runs_header, rows),
            "environment: " + ", ".join(f"{k} {v}" for k, v in environment().items()),
        ]
    )
    emit(report, {"starts": [s for _, s in starts], "runs": runs}, args.out)
    return 0 if len(docked) == len(runs) else 1


if __name__ == "__main__":
    sys.exit(main())
