"""The papers' headline comparison, end to end through the command line, at the papers' data size.

1. ``monodock simulate --format rosbag2``: a ``--train-stops`` data-collection drive (default 20,000, about the
   papers' N; rendered with 4x4 edge samples, which moves corners by < 0.01 px on average), PNG-compressed;
2. a held-out drive of ``--test-stops`` stops (default 2,000) with another seed and the default nuisances;
3. ``monodock label`` on both (the label error against truth is printed);
4. ``monodock train`` (the papers' selection, ``--trials`` draws per model);
5. ``monodock evaluate`` on the held-out drive: regression, single-marker and board PnP, and the fused method,
   against the simulator's truth and the LiDAR labels, by 25 cm band, against the Cramér–Rao bound, and the
   SolvePnP-failure study.

``--layout``, ``--camera`` and ``--robot`` run it all on another set-up (dictionary, ids, sizes, spacing, lens,
resolution, mounts).

Every step's command and wall time are printed; the report lands in ``--out``/eval/report.html. Run from the
repo root (about 20 minutes on 2 cores at the default sizes):

    python bench/regression_accuracy.py [--train-stops 20000] [--test-stops 2000] [--out bench_out/accuracy]
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from monodock.cli.main import main as monodock
from monodock.core.layout import DockLayout


def _run(args: list[str]) -> float:
    print(f"$ monodock {shlex.join(args)}", flush=True)
    t = time.perf_counter()
    code = monodock(args)
    if code != 0:
        raise SystemExit(f"monodock {args[0]} failed with exit code {code}")
    dt = time.perf_counter() - t
    print(f"  ({dt:.0f} s)", flush=True)
    return dt


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--train-stops", type=int, default=20000)
    p.add_argument("--test-stops", type=int, default=2000)
    p.add_argument("--trials", type=int, default=10)
    p.add_argument("--seed", type=int, default=100)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default="bench_out/accuracy")
    p.add_argument("--keep-going", action="store_true", help="reuse the outputs of steps already done")
    p.add_argument("--layout", help="dock layout YAML (default: the papers' layout)")
    p.add_argument("--camera", help="camera file for the simulated robot (default: the built-in 640x480 camera)")
    p.add_argument("--robot", help="robot YAML for the simulated robot (default: the built-in mounts)")
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "layout.yaml").exists():
        (DockLayout.load(args.layout) if args.layout else DockLayout.default()).save(out / "layout.yaml")
    jobs = ["--jobs", str(args.jobs)]
    # The recordings carry CameraInfo and /tf_static, so label and train read the set-up from them.
    setup = ["--layout", str(out / "layout.yaml")]
    setup += ["--camera", args.camera] if args.camera else []
    setup += ["--robot", args.robot] if args.robot else []
    times: dict[str, float] = {}
    steps = [
        (
            "simulate train",
            out / "train_rec",
            ["simulate", "--format", "rosbag2", "--out", str(out / "train_rec"), "--frames", str(args.train_stops),
             "--seed", str(args.seed), "--supersample", "4", "--encoding", "png", *setup, *jobs],
        ),
        (
            "simulate test",
            out / "test_rec",
            ["simulate", "--format", "rosbag2", "--out", str(out / "test_rec"), "--frames", str(args.test_stops),
             "--seed", str(args.seed + 1), "--encoding", "png", *setup, *jobs],
        ),
        ("label train", out / "train.parquet",
         ["label", str(out / "train_rec"), "--layout", str(out / "layout.yaml"), "--out", str(out / "train.parquet")]),
        ("label test", out / "test.parquet",
         ["label", str(out / "test_rec"), "--layout", str(out / "layout.yaml"), "--out", str(out / "test.parquet")]),
        ("train", out / "bundle",
         ["train", str(out / "train.parquet"), "--out", str(out / "bundle"), "--trials", str(args.trials), *jobs]),
        ("evaluate", out / "eval",
         ["evaluate", str(out / "test.parquet"), "--model", str(out / "bundle"), "--out", str(out / "eval"),
          "--force"]),
    ]  # fmt: skip
    for name, target, cmd in steps:
        if args.keep_going and target.exists() and name != "evaluate":
            print(f"(reusing {target})")
            continue
        times[name] = _run(cmd)
    summary = json.loads((out / "eval" / "summary.json").read_text())
    summary["step_seconds"] = times
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({"step_seconds": times, "against_truth": summary.get("against_truth")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
