"""Wall time of ``monodock demo`` by stage, beside the 120 s target (issue 24).

Runs ``monodock demo`` (the command, in a fresh process, as a user would) into a temporary folder with its
default sizes (3,000-stop training drive, 500-stop held-out drive, 4 hyperparameter draws, one docking start
per case and method) and prints each stage's wall time as the demo logs it ("stage NAME done in S s"), the
total, and the CPU time of the run and its worker processes (wall time depends on what else runs on the
machine; CPU time much less). ``--cold`` gives numba an empty cache directory, so the run pays the kernels'
compilation as a fresh clone's first run does; by default the cache beside the sources is used, as on every
later run.

Run from the repo root:

    python bench/demo_speed.py [--jobs 2] [--cold] [--keep DIR] [--out FILE.md]

(``--train-stops``, ``--test-stops`` and ``--trials`` pass other sizes to the demo; the target is for its defaults.)
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import emit, environment, fmt, markdown_table

TARGET_S = 120.0
_STAGE = re.compile(r"^stage (.+) done in ([0-9.]+) s$")


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_demo(out: Path, args: argparse.Namespace, env: dict[str, str]) -> tuple[list[tuple[str, float]], float, float]:
    """Run the demo into ``out``; its stderr passes through. Returns the stages' wall times, wall and CPU s."""
    cmd = [sys.executable, "-m", "monodock.cli.main", "demo", "--out", str(out), "--seed", str(args.seed)]
    if args.jobs:
        cmd += ["--jobs", str(args.jobs)]
    for flag in ("train_stops", "test_stops", "trials"):
        if getattr(args, flag):
            cmd += [f"--{flag.replace('_', '-')}", str(getattr(args, flag))]
    stages: list[tuple[str, float]] = []
    cpu0, t0 = _children_cpu(), time.perf_counter()
    with subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env) as proc:
        assert proc.stderr is not None
        for line in proc.stderr:
            sys.stderr.write(line)
            m = _STAGE.match(line.strip())
            if m:
                stages.append((m.group(1), float(m.group(2))))
        stdout = proc.stdout.read() if proc.stdout else ""
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    sys.stderr.write(stdout)
    if proc.returncode != 0:
        raise SystemExit(f"monodock demo failed (exit {proc.returncode})")
    return stages, wall, cpu


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--jobs", type=int, default=0, help="the demo's --jobs (default: its own, the cores up to 4)")
    p.add_argument("--seed", type=int, default=0, help="the demo's --seed (default 0)")
    p.add_argument("--train-stops", type=int, help="the demo's --train-stops (default: its own, 3000)")
    p.add_argument("--test-stops", type=int, help="the demo's --test-stops (default: its own, 500)")
    p.add_argument("--trials", type=int, help="the demo's --trials (default: its own, 4)")
    p.add_argument("--cold", action="store_true", help="an empty numba cache: count the kernels' compilation")
    p.add_argument("--keep", help="write the demo's report here instead of a temporary folder")
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    args = p.parse_args()
    env = dict(os.environ)
    # The demo runs from the same monodock as this script (an installed one, or src/ of this checkout).
    import monodock

    src = str(Path(monodock.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([src, *filter(None, [env.get("PYTHONPATH")])])
    with tempfile.TemporaryDirectory(prefix="demo-speed-") as tmp:
        if args.cold:
            env["NUMBA_CACHE_DIR"] = str(Path(tmp) / "numba")
        out = Path(args.keep) if args.keep else Path(tmp) / "report"
        stages, wall, cpu = run_demo(out, args, env)
    rows = [[name, fmt(s, 1), fmt(100 * s / wall, 0)] for name, s in stages]
    rows.append(["**total**", f"**{fmt(wall, 1)}**", "100"])
    verdict = "meets" if wall <= TARGET_S else "misses"
    env_facts = environment()
    report = "\n".join(
        [
            f"`python bench/{' '.join(['demo_speed.py', *sys.argv[1:]])}` — {env_facts['date_utc']} UTC, "
            f"{os.cpu_count()} cores, numba cache {'empty (cold)' if args.cold else 'warm'}",
            "",
            markdown_table(["stage", "wall s", "% of total"], rows),
            "",
            f"Total {wall:.1f} s against the target of {TARGET_S:.0f} s: {verdict} it ({wall / TARGET_S:.2f}x). "
            f"CPU time of the demo and its workers: {cpu:.1f} s ({cpu / wall:.2f} cores busy on average).",
        ]
    )
    raw = {"stages": dict(stages), "wall_s": wall, "cpu_s": cpu, "target_s": TARGET_S, "cold": args.cold, **env_facts}
    emit(report, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
