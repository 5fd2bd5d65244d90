"""The ``monodock`` command line: sub-commands that mirror the pipeline (docs/architecture.md), one module each."""

from __future__ import annotations

import argparse
import codecs
import importlib
import io
import logging
import os
import re
import sys
from collections.abc import Iterable, Sequence

from monodock.cli.parser import Parser
from monodock.compute import cluster_session
from monodock.core.images import printable
from monodock.core.interrupt import Terminated, exit_on_signal, install_signal_handlers, received
from monodock.core.quiet import command_session
from monodock.errors import MonodockError

__all__ = ["COMMANDS", "main", "parser"]

# The commands in the order of ``monodock --help``, each with its module (its ``add_parser`` and ``run``), named
# after it. A module is loaded only when its command runs, so that a command starts without the libraries of the
# others (the report's matplotlib, the trainer's scikit-learn).
_NAMES = "simulate estimate show label train evaluate calibrate dock-kit design teach commission run dock-sim demo"
COMMANDS = {name: "monodock.cli." + name.replace("-", "_") for name in _NAMES.split()}


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
    p.add_argument(
        "--debug",
        action="store_true",
        help="show tracebacks of internal errors, and the libraries' own messages (OpenCV, FFmpeg, libpng, libjpeg)",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in commands:
        importlib.import_module(COMMANDS[name]).add_parser(sub)
    return p


class _Warnings(logging.Handler):
    """monodock's warnings as ``monodock CMD: warning: ...`` lines on stderr.

    Warnings about the input files (an unknown key, logger ``monodock.config``; a recording cut short,
    ``monodock.input``) are held until the command ends and shown only if it did not refuse its input, so that a
    refusal stays one line.
    """

    def __init__(self, command: str) -> None:
        super().__init__(logging.WARNING)
        self.command = command
        self.held: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        line = f"monodock {self.command}: warning: {record.getMessage()}"
        if record.name in ("monodock.config", "monodock.input"):
            if line not in self.held:
                self.held.append(line)
        else:
            print(line, file=sys.stderr)

    def show_held(self) -> None:
        for line in self.held:
            print(line, file=sys.stderr)
        self.held.clear()


# The temp names of core.atomic (".NAME.XXXXXXXX" beside NAME, ".NAME.old.XXXXXXXX" for a replaced folder):
# an OSError on one is told with the user's NAME.
_TEMP_NAME = re.compile(r"^\.(?P<name>.+?)\.(?:old\.)?[A-Za-z0-9_]{8}$")


def _shown(filename: object) -> str:
    """How an OSError's file is named: the user's path for an atomic write's temp file, \\xNN for non-UTF-8."""
    path = os.fsdecode(filename) if isinstance(filename, str | bytes) else str(filename)
    head, tail = os.path.split(path)
    temp = _TEMP_NAME.match(tail)
    return printable(os.path.join(head, temp["name"]) if temp else path)


def _escape_names(err: UnicodeError) -> tuple[str, int]:
    """A codec error handler: the bytes of a file name that are not UTF-8 (surrogates) as \\xNN, others as
    backslashreplace does."""
    if not isinstance(err, UnicodeEncodeError):
        raise err
    bad = err.object[err.start : err.end]
    text = "".join(
        f"\\x{ord(c) - 0xDC00:02x}" if 0xDC80 <= ord(c) <= 0xDCFF else c.encode("ascii", "backslashreplace").decode()
        for c in bad
    )
    return text, err.end


def _one_line(text: object) -> str:
    """A message on one line (OpenCV's errors and some libraries' span several)."""
    return " ".join(str(text).split())


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
    logger = logging.getLogger("monodock")
    warnings = _Warnings(args.command)
    logger.addHandler(warnings)
    logger.propagate = False
    # A file name that is not UTF-8 prints as \xNN (as core.images.printable) rather than failing the print.
    codecs.register_error("monodock-names", _escape_names)
    for stream in (sys.stdout, sys.stderr):
        if isinstance(stream, io.TextIOWrapper):
            stream.reconfigure(errors="monodock-names")
    try:
        # --cluster (the commands with parallel stages): those stages run on Dask for the whole command.
        cluster = getattr(args, "cluster", None)
        with command_session(debug=args.debug), cluster_session(cluster, workers=getattr(args, "jobs", None)):
            code = int(args.func(args))
        warnings.show_held()
        return code
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated)
        return _interrupted(exc, args.command)
    except Exception:
        # A signal came, and a library turned its KeyboardInterrupt into an error of its own: interrupted.
        signalled = received()
        if signalled is not None:
            return _interrupted(signalled, args.command)
        return _failed(args)
    finally:
        logger.removeHandler(warnings)
        logger.propagate = True


def _failed(args: argparse.Namespace) -> int:
    """The one line of the exception being handled: exit 2 for bad input (a MonodockError, an OSError on a file
    the user named), 1 for an internal error (a traceback with --debug)."""
    exc = sys.exc_info()[1]
    if isinstance(exc, MonodockError):
        print(f"monodock {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    if isinstance(exc, OSError):
        # A file the user named could not be read or written (permissions, disk full, a folder in the way).
        where = f"{_shown(exc.filename)}: " if exc.filename else ""
        print(f"monodock {args.command}: error: {where}{_one_line(exc.strerror or exc)}", file=sys.stderr)
        return 2
    if args.debug:
        raise  # noqa: PLE0704 - called from an except block: the exception being handled
    print(
        f"monodock {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} (rerun with --debug)",
        file=sys.stderr,
    )
    return 1


if __name__ == "__main__":
    sys.exit(main())
