"""The argument parser of every monodock command line (``monodock``, ``monodock-ros``, ``monodock-dock-ros``,
``monodock-record-ros``): argparse, with the usage error on one line."""

from __future__ import annotations

import argparse
from typing import NoReturn

__all__ = ["Parser"]


class Parser(argparse.ArgumentParser):
    """argparse with the usage error on one line, like every other monodock error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
