"""The ``monodock`` command line: sub-commands that mirror the pipeline (DESIGN.md), one module each."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from monodock.cli import calibrate, demo, dock_sim, estimate, evaluate, label, run, show, simulate, train
from monodock.cli.options import Parser
from monodock.errors import MonodockError

__all__ = ["main", "parser"]


def parser() -> argparse.ArgumentParser:
    """The whole command line: one sub-parser per command, each built by its own module."""
    p = Parser(
        prog="monodock",
        description="Dock a robot onto its charger with one camera and three ArUco markers.",
        epilog="Every command prints one line and exits 2 on bad input; outputs are never overwritten without --force.",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in (simulate, estimate, show, label, train, evaluate, calibrate, run, dock_sim, demo):
        command.add_parser(sub)
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
