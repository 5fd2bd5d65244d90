"""The ``monodock`` command line: sub-commands that mirror the pipeline (DESIGN.md), one module each."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from monodock.cli import calibrate, dock_sim, estimate, evaluate, label, run, show, simulate, train
from monodock.cli.demo import DemoConfig, run_demo
from monodock.cli.options import Parser, SubParsers, jobs
from monodock.core.atomic import check_writable
from monodock.errors import MonodockError

__all__ = ["main", "parser"]


def _cmd_demo(args: argparse.Namespace) -> int:
    for flag, value in (
        ("--train-stops", args.train_stops),
        ("--test-stops", args.test_stops),
        ("--trials", args.trials),
        ("--dock-trials", args.dock_trials),
    ):
        if value < 1:
            raise MonodockError(f"{flag} must be at least 1")
    check_writable(args.out, force=args.force)
    config = DemoConfig(
        train_stops=args.train_stops,
        test_stops=args.test_stops,
        trials=args.trials,
        seed=args.seed,
        jobs=jobs(args.jobs),
        dock_trials=args.dock_trials,
    )
    summary = run_demo(args.out, config, force=args.force)
    for method, r in summary.get("against_truth", summary.get("against_lidar", {})).items():
        print(
            f"{method:10s} valid {r['valid']}/{r['frames']}  depth MAE {r['depth_mae_cm']:.2f} cm  lateral MAE "
            f"{r['lateral_mae_cm']:.2f} cm  yaw MAE {r['yaw_mae_deg']:.2f} deg  (against the simulator's truth)"
        )
    for method, g in summary.get("docking", {}).items():
        print(
            f"docking {method:10s} {g['successes']}/{g['runs']} docked; median final lateral "
            f"{g['final_lateral_cm']['median']:.2f} cm, heading {g['final_heading_deg']['median']:.2f} deg"
        )
    print(f"report: {Path(args.out) / 'report.html'}  ({summary['seconds']:.0f} s)")
    return 0


def _add_demo(subparsers: SubParsers) -> None:
    d = subparsers.add_parser("demo", help="simulate, label, train, evaluate every method, and write the report")
    d.add_argument("--out", default="demo_report", help="report folder (default: demo_report)")
    d.add_argument("--train-stops", type=int, default=3000, help="stops of the data-collection drive (3000)")
    d.add_argument("--test-stops", type=int, default=500, help="stops of the held-out drive (500)")
    d.add_argument("--trials", type=int, default=4, help="hyperparameter draws per model (4)")
    d.add_argument("--dock-trials", type=int, default=1, help="closed-loop docking starts per case and method (1)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--jobs", type=int)
    d.add_argument("--force", action="store_true", help="replace an existing report folder")
    d.set_defaults(func=_cmd_demo)


def parser() -> argparse.ArgumentParser:
    """The whole command line: one sub-parser per command, each built by its own module."""
    p = Parser(
        prog="monodock",
        description="Dock a robot onto its charger with one camera and three ArUco markers.",
        epilog="Every command prints one line and exits 2 on bad input; outputs are never overwritten without --force.",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in (simulate, estimate, show, label, train, evaluate, calibrate, run, dock_sim):
        command.add_parser(sub)
    _add_demo(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; user errors print one line on stderr and return a non-zero code."""
    args = parser().parse_args(argv)
    try:
        return int(args.func(args))
    except MonodockError as exc:
        print(f"monodock {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        # A file the user named could not be read or written (permissions, disk full, a folder in the way).
        where = f" {exc.filename}" if exc.filename else ""
        print(f"monodock {args.command}: error:{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("monodock: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        print(
            f"monodock {args.command}: internal error: {type(exc).__name__}: {exc} (rerun with --debug)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
