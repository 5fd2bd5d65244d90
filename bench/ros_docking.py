"""Docking over a real ROS 2 graph against dock-sim, from the same starts.

dock-sim (``monodock.evaluation.dock_sim``) draws starts in each of the papers' eight cases and docks the simulated
robot in-process. The same starts then run on a ROS 2 graph: ``monodock-sim-ros`` (the same simulated robot,
in real time) and ``monodock-dock-ros`` (board PnP, the camera from camera_info), the mission called through its
``~/dock`` service, every packet over Fast DDS inside a private network namespace (loopback only, its own
``ROS_DOMAIN_ID``). Both are judged by the simulator's truth: the final lateral offset, the gap at the front edge's
centre and the heading, and whether the charger charges.

Run from the repo root (needs the ROS 2 wheels: ``pip install -e ".[ros]"``, and ``unshare``):

    python bench/ros_docking.py [--cases all] [--trials 1] [--jobs 2] [--setup bench/setups/wide] [--out FILE.md]
    python bench/ros_docking.py --faults [--out FILE.md]

``--faults`` runs the faults on the graph instead, each once from one start, and prints the fault table: the camera
silent for 3 s in Moving₃, odometry stopping in Moving₁, malformed images flooding the camera topic, a cancel, a
second ~/dock call, the node shut down (SIGINT) or killed (SIGKILL) mid-approach. Judged by the sim's truth too.
"""

from __future__ import annotations

import argparse
import dataclasses
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
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.evaluation.dock_results import TrialResult
from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from private_graph import can_isolate, run_private_graph

DRIVER = Path(__file__).resolve().parents[1] / "tests" / "ros" / "graph_dock.py"


def over_ros(start: tuple[float, float, float], setup: str | None = None) -> dict[str, Any]:
    """One docking over the graph from ``start``: the step record of graph_dock.py (or why there is none)."""
    t0 = time.perf_counter()
    spec: dict[str, Any] = {"start": list(start), "steps": ["dock"]}
    if setup:
        spec["setup"] = str(Path(setup).resolve())
    run = run_private_graph(DRIVER, json.dumps(spec), timeout=300)
    steps = [r for r in run.records if r["kind"] == "step"]
    if not steps:
        return {"message": f"no result (exit {run.returncode}): {run.stderr.strip().splitlines()[-1:]}", "wall": 0}
    return {**steps[0], "wall": time.perf_counter() - t0}


FAULTS = {
    "camera silent 3 s in Moving₃": {"fault": {"kind": "camera", "state": "moving3", "for": 3.0}},
    "odometry stops in Moving₁": {"fault": {"kind": "odometry", "state": "moving1-drive"}},
    "malformed images from Moving₁ on": {"fault": {"kind": "garbage", "state": "moving1-turn"}},
    "~/cancel in Moving₁": {"fault": {"kind": "cancel", "state": "moving1-drive"}},
    "second ~/dock call in Moving₁": {"fault": {"kind": "again", "state": "moving1-drive"}},
    "SIGINT to the node in Moving₃": {"fault": {"kind": "sigint", "state": "moving3"}, "sim": {"cmd_vel_timeout": 5.0}},
    "SIGKILL to the node in Moving₃": {"fault": {"kind": "kill", "state": "moving3"}},
}


def fault_row(name: str, spec: dict[str, Any]) -> list[str]:
    """One fault from one start: what the node reported, where the robot truly ended, whether it stopped."""
    run = run_private_graph(DRIVER, json.dumps({"start": [-1.7, 0.15, 0.1], "steps": ["dock"], **spec}), timeout=300)
    step = next((r for r in run.records if r["kind"] == "step"), None)
    fault = next((r for r in run.records if r["kind"] == "fault"), {})
    if "track" in fault:  # the node is gone: how far the robot went on after 0.5 s, and after 1 s
        track = fault["track"]
        moved = [p for p in track if p[0] > 0.5]
        still = math.dist(moved[0][1:], moved[-1][1:]) * 100 if len(moved) > 1 else math.nan
        return [name, f"node exited ({fault.get('returncode')})", "—", f"moved {fmt(still)} cm after 0.5 s", "—"]
    if step is None:
        return [name, f"no result (exit {run.returncode})", "—", "—", "—"]
    t = step["truth"]
    values = step["values"]
    recovered = values.get("recoveries", "0")
    return [
        name,
        step["message"].split(":")[0] + (" (charging)" if step.get("charging") else ""),
        f"{fmt(t['lateral_cm'])} / {fmt(t['gap_cm'])} / {fmt(t['heading_deg'])}",
        f"{recovered} recoveries",
        str(values.get("nav2_error_code", "—")),
    ]


def faults_report(jobs: int) -> str:
    with ThreadPoolExecutor(jobs) as pool:
        rows = list(pool.map(lambda item: fault_row(*item), FAULTS.items()))
    header = ["fault", "outcome", "final lateral / gap / heading (truth)", "", "Nav2 code"]
    return "\n\n".join(["# Faults on the ROS 2 graph (board PnP, one start)", markdown_table(header, rows)])


def stats(values: list[float]) -> str:
    a = np.abs(np.asarray(values, dtype=float))
    return f"{fmt(float(np.median(a)))} / {fmt(float(np.percentile(a, 95)))}" if a.size else "—"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--cases", type=case_list, default=case_list("all"), help="papers' cases, e.g. 1,4,7 (all)")
    p.add_argument("--trials", type=int, default=1, help="starts per case (1)")
    p.add_argument("--jobs", type=int, default=2, help="graphs (and dock-sim workers) at a time (2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--faults", action="store_true", help="the fault table instead of the comparison")
    p.add_argument("--setup", help="a folder with layout.yaml, robot.yaml, camera.yaml (e.g. bench/setups/wide)")
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    args = p.parse_args(argv)
    if not can_isolate():
        p.error("this machine cannot make a private network namespace (unshare --net); no ROS graph may run")
    if args.faults:
        emit(faults_report(args.jobs), {}, args.out)
        return 0
    config = DockSimConfig(
        cases=tuple(args.cases), trials=args.trials, methods=("board",), jobs=args.jobs, seed=args.seed
    )
    if args.setup:
        folder = Path(args.setup)
        config = dataclasses.replace(
            config,
            layout=DockLayout.load(folder / "layout.yaml"),
            robot=RobotConfig.load(folder / "robot.yaml"),
            camera=CameraModel.load(folder / "camera.yaml"),
        )
    t0 = time.perf_counter()
    sim_runs: list[TrialResult] = run_dock_sim(config, progress=False)
    sim_wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    with ThreadPoolExecutor(args.jobs) as pool:
        ros_runs = list(pool.map(lambda r: over_ros(r.start, args.setup), sim_runs))
    ros_wall = time.perf_counter() - t0

    rows = []
    for s, r in zip(sim_runs, ros_runs, strict=True):
        truth = r.get("truth", {})
        rows.append(
            [
                str(s.case),
                f"({s.start[0]:.2f}, {s.start[1]:.2f}, {math.degrees(s.start[2]):.0f}°)",
                "docked" if s.success else s.state,
                f"{fmt(s.lateral_cm)} / {fmt(s.longitudinal_cm)} / {fmt(s.heading_deg)}",
                f"{s.time_s:.1f}",
                r["message"] + (" (charging)" if r.get("charging") else ""),
                f"{fmt(truth.get('lateral_cm', math.nan))} / {fmt(truth.get('gap_cm', math.nan))} / "
                f"{fmt(truth.get('heading_deg', math.nan))}",
                f"{float(r.get('values', {}).get('duration_s', 'nan')):.1f}",
            ]
        )
    ok = [r for r in ros_runs if r["message"] == "docked" and r.get("charging")]
    summary = [
        ["dock-sim (in-process)", f"{sum(s.success for s in sim_runs)}/{len(sim_runs)}",
         stats([s.lateral_cm for s in sim_runs]), stats([s.longitudinal_cm for s in sim_runs]),
         stats([s.heading_deg for s in sim_runs]), f"{np.median([s.time_s for s in sim_runs]):.1f}", f"{sim_wall:.0f}"],
        ["ROS 2 graph (Fast DDS)", f"{len(ok)}/{len(ros_runs)}",
         stats([r["truth"]["lateral_cm"] for r in ok]), stats([r["truth"]["gap_cm"] for r in ok]),
         stats([r["truth"]["heading_deg"] for r in ok]),
         f"{np.median([float(r['values']['duration_s']) for r in ok]):.1f}" if ok else "—", f"{ros_wall:.0f}"],
    ]  # fmt: skip
    summary_header = ["", "docked", "lateral cm median / p95", "gap cm median / p95", "heading ° median / p95",
                      "mission s median", "wall s"]  # fmt: skip
    runs_header = ["case", "start (x, y, heading)", "dock-sim", "lateral / gap / heading", "s", "ROS 2 graph",
                   "lateral / gap / heading", "s"]  # fmt: skip
    report = "\n\n".join(
        [
            f"# Docking over ROS 2 against dock-sim ({len(sim_runs)} starts, board PnP)",
            markdown_table(summary_header, summary),
            "dock-sim's gap is the nearest front corner's; the graph's, the front edge's centre (the heading "
            "moves them apart by well under a millimetre here). Docked over ROS means the node said docked and "
            "the simulated charger charges.",
            markdown_table(runs_header, rows),
            "environment: " + ", ".join(f"{k} {v}" for k, v in environment().items()),
        ]
    )
    emit(report, {"dock_sim": [s.start for s in sim_runs], "ros": ros_runs}, args.out)
    return 0 if len(ok) == len(ros_runs) else 1


if __name__ == "__main__":
    sys.exit(main())
