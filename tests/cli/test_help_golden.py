"""Every ``monodock`` sub-command's ``--help``, byte for byte as pinned: a command's words now live in its run
function's docstring (cli.options.add_command), where an edit would otherwise change the help without a word.

Regenerate after a deliberate change: ``python tests/cli/test_help_golden.py > tests/data/cli/help.txt``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import pytest

GOLDEN = Path(__file__).parents[1] / "data" / "cli" / "help.txt"


def help_texts() -> str:
    """Each parser's ``--help`` (argparse's wrapping at 120 columns), sub-commands walked, under a ``=====`` line."""
    from monodock.cli.main import parser

    def walk(p: argparse.ArgumentParser, path: list[str]) -> list[str]:
        out = [f"===== {' '.join(path)}", p.format_help()]
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    out += walk(sub, [*path, name])
        return out

    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "120"
    try:
        return "\n".join(walk(parser(), ["monodock"])) + "\n"
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="argparse's layout is the pinned Python's (3.11)")
def test_every_commands_help_is_as_pinned() -> None:
    assert help_texts() == GOLDEN.read_text(encoding="utf-8")


if __name__ == "__main__":
    sys.stdout.write(help_texts())
