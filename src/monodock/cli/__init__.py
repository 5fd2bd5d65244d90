"""The ``monodock`` command line: one module per command; argparse lives only here. Nothing imports it: its face
is empty."""

from __future__ import annotations

__all__: list[str] = []
