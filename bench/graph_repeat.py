"""The ROS 2 graph docking tests, repeated with CI's concurrency: how often they pass, how many recoveries each
docking needed, and how far below real time the simulation ran.

Runs ``pytest -m slow -n 2`` on the tests (by default the graph docking test with four starts, two graphs at a time)
``--runs`` times, each with ``MONODOCK_ROS_RECORDINGS`` set to a folder of its own, optionally beside one CPU-bound
process per core (``--hogs``, as a busy machine), then reads every recording (rosbag2, MCAP): the docking node's
results on ``/monodock_dock/result`` (the recoveries, the failure) and the simulator's real-time factor on
``/diagnostics``.

    python bench/graph_repeat.py [--runs 5] [--hogs] [--tests TEST ...] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from _common import _positive, emit, environment, fmt, markdown_table

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TESTS = ["tests/ros/test_dock_graph.py::test_docking_over_dds_from_starts_in_several_cases"]
HOG = "while True: pass"


def read_recording(folder: Path) -> dict[str, Any]:
    """A recording's docking results (state, failure, recoveries) and the sim's worst real-time factor."""
    from rosbags.highlevel import AnyReader

    results: list[dict[str, str]] = []
    factors: list[float] = []
    with AnyReader([folder]) as reader:
        wanted = [c for c in reader.connections if c.topic in ("/monodock_dock/result", "/diagnostics")]
        for connection, _, raw in reader.messages(wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic == "/monodock_dock/result":
                results.append({v.key: v.value for v in msg.values})
                continue
            for status in msg.status:
                values = {v.key: v.value for v in status.values}
                if status.name.endswith("monodock_sim: real time"):
                    factors.append(float(values["real_time_factor"]))
    return {"results": results, "worst_factor": min(factors) if factors else float("nan")}


def one_run(index: int, tests: list[str], hogs: bool, folder: Path) -> dict[str, Any]:
    """One pytest run of the tests: its verdicts and what its recordings say."""
    recordings = folder / f"run_{index}"
    junit = folder / f"run_{index}.xml"
    env = {**os.environ, "MONODOCK_ROS_RECORDINGS": str(recordings), "MONODOCK_REQUIRE_ROS_GRAPH": "1"}
    hog_processes = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(os.cpu_count() or 2)] if hogs else []
    t0 = time.perf_counter()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-m", "slow", "-n", "2", "-p", "no:cacheprovider",
             f"--junitxml={junit}", *tests],
            cwd=ROOT, env=env, capture_output=True, text=True, check=False,
        )  # fmt: skip
    finally:
        for hog in hog_processes:
            hog.kill()
            hog.wait()
    wall = time.perf_counter() - t0
    cases = ET.parse(junit).getroot().iter("testcase") if junit.is_file() else iter(())
    verdicts = {c.get("name", "?"): not any(c.find(k) is not None for k in ("failure", "error")) for c in cases}
    bags = sorted(p.parent for p in recordings.rglob("metadata.yaml")) if recordings.is_dir() else []
    return {
        "returncode": done.returncode,
        "verdicts": verdicts,
        "recordings": {str(b.relative_to(recordings)): read_recording(b) for b in bags},
        "wall": wall,
        "tail": done.stdout[-2000:],
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--runs", type=_positive, default=5, help="pytest runs (5)")
    p.add_argument("--hogs", action="store_true", help="one CPU-bound process per core beside each run")
    p.add_argument(
        "--tests", nargs="+", default=DEFAULT_TESTS, help="the tests (node ids); default: " + DEFAULT_TESTS[0]
    )
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="graph-repeat-") as tmp:
        runs = [one_run(i, args.tests, args.hogs, Path(tmp)) for i in range(args.runs)]
    rows, passed, recoveries, factors = [], 0, [], []
    for i, run in enumerate(runs):
        ok = bool(run["verdicts"]) and all(run["verdicts"].values()) and run["returncode"] == 0
        passed += ok
        per_start = []
        for name, recording in sorted(run["recordings"].items()):
            docks = [r for r in recording["results"] if r.get("task") == "dock"]
            count = sum(int(r.get("recoveries", "0") or 0) for r in docks)
            failed = [r.get("failure", "") for r in docks if r.get("state") != "docked"]
            recoveries.append(count)
            factors.append(recording["worst_factor"])
            shown = name.split("/", 1)[-1] if len(args.tests) == 1 else name  # one test: its starts are enough
            per_start.append(f"{shown}: {count}" + (f" ({', '.join(failed)})" if failed else ""))
        worst = min((f for f in factors[-len(per_start) :] if not math.isnan(f)), default=math.nan)
        rows.append(
            [str(i + 1), "passed" if ok else "FAILED", "; ".join(per_start) or "—", fmt(worst), f"{run['wall']:.0f}"]
        )
    starts = len(recoveries)
    summary = [[
        f"{passed}/{len(runs)}",
        f"{sum(recoveries)} in {starts} dockings ({sum(recoveries) / max(starts, 1):.2f} a docking)",
        f"{max(recoveries, default=0)}",
        fmt(min((f for f in factors if not math.isnan(f)), default=math.nan)),
    ]]  # fmt: skip
    report = "\n\n".join(
        [
            f"# The graph docking tests, {len(runs)} runs" + (" beside one CPU hog per core" if args.hogs else ""),
            "tests: " + ", ".join(args.tests),
            markdown_table(["runs passed", "recoveries", "most in one docking", "worst real-time factor"], summary),
            markdown_table(
                ["run", "verdict", "recoveries per start (failures)", "worst real-time factor", "wall s"], rows
            ),
            "environment: " + ", ".join(f"{k} {v}" for k, v in environment().items()),
        ]
    )
    emit(report, {"runs": runs}, args.out)
    return 0 if passed == len(runs) else 1


if __name__ == "__main__":
    sys.exit(main())
