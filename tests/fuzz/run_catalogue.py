"""Run the hostile-input catalogue and print the outcomes per family (issue 18's figures).

    PYTHONPATH=src python tests/fuzz/run_catalogue.py [--slow] [--family TEXT] [--details FILE.jsonl]

Every case runs in this process (interruption cases, with --slow, in subprocesses) in a temporary folder; the
table counts, per family, the cases, the clean refusals, the successes that held the contract, and the cases that
broke it by kind (a case can break it in more than one way). Exit status 1 when any case broke the contract.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests folder: `fuzz` and `shared`

from fuzz.catalogue import CASES, FAMILIES, run_case
from fuzz.harness import KINDS, outcome
from fuzz.world import build_world

COLUMNS = ("cases", "clean refusal", "ok", *KINDS)


def table(counts: dict[str, dict[str, int]]) -> str:
    head = "| family | " + " | ".join(COLUMNS) + " |\n|---|" + "---:|" * len(COLUMNS) + "\n"
    total = dict.fromkeys(COLUMNS, 0)
    body = ""
    for fam, row in counts.items():
        if not row["cases"]:
            continue
        body += f"| {fam} | " + " | ".join(str(row[c]) for c in COLUMNS) + " |\n"
        for c in COLUMNS:
            total[c] += row[c]
    return head + body + "| **all** | " + " | ".join(f"**{total[c]}**" for c in COLUMNS) + " |\n"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--slow", action="store_true", help="also the interruption cases (subprocesses, ~1 min)")
    p.add_argument("--family", help="only families whose name contains this")
    p.add_argument("--details", help="write one JSON line per case (argv, code, stderr, findings) to this file")
    args = p.parse_args()
    root = Path(tempfile.mkdtemp(prefix="monodock-catalogue-"))
    details = open(args.details, "w", encoding="utf-8") if args.details else None  # noqa: SIM115
    try:
        t0 = time.perf_counter()
        world = build_world(root / "world")
        counts = {f: dict.fromkeys(COLUMNS, 0) for f in FAMILIES}
        cases = [c for c in CASES if (args.slow or not c.slow) and (not args.family or args.family in c.family)]
        for i, c in enumerate(cases):
            folder = root / "case"
            run, expect = run_case(c, world, folder)
            verdict, found = outcome(run, expect)
            row = counts[c.family]
            row["cases"] += 1
            if verdict != "failed":
                row[verdict] += 1
            for kind, _ in found:
                row[kind] += 1
            if details:
                details.write(
                    json.dumps(
                        {
                            "family": c.family,
                            "case": c.name,
                            "argv": run.argv,
                            "code": run.code,
                            "seconds": round(run.seconds, 2),
                            "stderr": run.err[-600:],
                            "escaped": run.escaped[-600:],
                            "verdict": verdict,
                            "findings": found,
                        }
                    )
                    + "\n"
                )
                details.flush()
            shutil.rmtree(folder, ignore_errors=True)
            print(f"\r{i + 1}/{len(cases)} {c.id[:60]:60s}", end="", file=sys.stderr, flush=True)
        print(file=sys.stderr)
        print(table(counts))
        print(f"{len(cases)} cases in {time.perf_counter() - t0:.0f} s")
        return 1 if any(counts[f][k] for f in counts for k in KINDS) else 0
    finally:
        if details:
            details.close()
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    sys.exit(main())
