"""The ``monodock`` command line: sub-commands that mirror the pipeline (DESIGN.md), one module each."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Iterable, Sequence
from typing import NoReturn

from monodock.core.interrupt import Terminated, exit_on_signal, install_signal_handlers
from monodock.errors import MonodockError

__all__ = ["COMMANDS", "main", "parser"]

# Each command's module (with its ``add_parser`` and ``run``), in the order of ``monodock --help``. A module is
# loaded only when its command runs, so that a command starts without the libraries of the others (the report's
# matplotlib, the trainer's scikit-learn).
COMMANDS = {
    "simulate": "monodock.cli.simulate",
    "estimate": "monodock.cli.estimate",
    "show": "monodock.cli.show",
    "label": "monodock.cli.label",
    "train": "monodock.cli.train",
    "evaluate": "monodock.cli.evaluate",
    "calibrate": "monodock.cli.calibrate",
    "run": "monodock.cli.run",
    "dock-sim": "monodock.cli.dock_sim",
    "demo": "monodock.cli.demo",
}


class Parser(argparse.ArgumentParser):
    """argparse with the usage error on one line, like every other monodock error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _command(argv: Sequence[str]) -> str | None:
    """The command named on a command line: its first word that is not an option."""
    return next((a for a in argv if not a.startswith("-")), None)


def parser(commands: Iterable[str] = COMMANDS) -> argparse.ArgumentParser:
    """The command line with the sub-parsers of ``commands`` (default: all), each built by its own module."""
    p = Parser(
        prog="monodock",
        description="Dock a robot onto its charger with one camera and three ArUco markers.",
        epilog="Every command prints one line and exits 2 on bad input; outputs are never overwritten without --force.",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in commands:
        importlib.import_module(COMMANDS[name]).add_parser(sub)
    return p


def _interrupted(exc: KeyboardInterrupt, command: str | None) -> int:
    """One line for SIGINT (exit 130) or SIGTERM (exit 143), the shells' 128 + signal number."""
    who = f"monodock {command}" if command else "monodock"
    if isinstance(exc, Terminated):
        print(f"{who}: terminated (SIGTERM)", file=sys.stderr)
        return 143
    print(f"{who}: interrupted", file=sys.stderr)
    return 130


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; user errors print one line on stderr and return a non-zero code."""
    words = list(sys.argv[1:] if argv is None else argv)
    name = _command(words)
    if argv is None:
        # The console script: SIGTERM stops it like Ctrl-C (an exception, so that temp folders and worker pools
        # are cleaned up), one line, exit 143; not when called as a library (the caller owns the handlers).
        install_signal_handlers()
        try:
            return _run(words, name)
        finally:
            who = f"monodock {name}" if name in COMMANDS else "monodock"
            exit_on_signal(f"{who}: stopped by {{signal}} while exiting")
    return _run(words, name)


def _run(words: list[str], name: str | None) -> int:
    try:
        args = parser([name] if name in COMMANDS else COMMANDS).parse_args(words)
    except KeyboardInterrupt as exc:
        return _interrupted(exc, name if name in COMMANDS else None)
    try:
        return int(args.func(args))
    except MonodockError as exc:
        print(f"monodock {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        # A file the user named could not be read or written (permissions, disk full, a folder in the way).
        where = f" {exc.filename}:" if exc.filename else ""
        print(f"monodock {args.command}: error:{where} {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated)
        return _interrupted(exc, args.command)
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
